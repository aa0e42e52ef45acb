"""Mitsuba 3 as an independent reference for raytrax's ``physical`` shading.

This module converts a built ``physical`` :class:`raytrax.Scene` into a Mitsuba 3
scene and renders it with a small Whitted integrator written against Mitsuba's
own API, so that geometry (ray/shape intersection), the BSDFs (``diffuse``,
``conductor``, ``dielectric`` with Mitsuba's Fresnel and refraction), the point
emitters and the camera all come from Mitsuba; the integrator only decides
*which* light paths are followed, exactly the ones raytrax follows:

* a camera or specular ray that escapes takes the background colour;
* at every hit, direct light from every point light (Mitsuba's
  ``Emitter.sample_direction``, shadow test with ``Scene.ray_test``, the BSDF's
  ``eval``, which is zero for delta lobes);
* the delta lobes are followed *deterministically and both at once*: the
  reflection branch (``BSDFContext`` restricted to ``DeltaReflection``) and the
  transmission branch (``DeltaTransmission``), each weighted by what Mitsuba's
  BSDF returns for that lobe alone (Fresnel ``F`` / ``(1 - F) eta^2``), up to
  ``max_depth`` specular interactions; the children of the last one take the
  background;
* diffuse (smooth) lobes are never sampled: a diffuse hit ends the path after
  its direct light (no indirect diffuse light, which Mitsuba's ``path`` would add).

Mapping of raytrax's physical material ``(C, R, T, ior)`` to Mitsuba BSDFs:

* ``T == 0, R == 0``: ``twosided(diffuse(reflectance=C))``;
* ``T == 0, C * (1 - R) == 0``: ``twosided(conductor(material="none", specular_reflectance=R))``;
* ``T == 0`` otherwise: ``twosided(blendbsdf(0.5, diffuse(2 (1 - R) C), conductor(R)))``;
  the integrator evaluates the blend for direct light, ``0.5 * 2 (1 - R) C / pi``,
  and samples the delta lobe with ``sample1 = 0``, which always picks the
  conductor (so its weight is ``R``, not halved);
* ``T == 1``: ``dielectric(int_ior=ior, ext_ior=1)`` (not two-sided: Mitsuba, like
  raytrax, tells inside from outside by the face normal, so meshes must be wound
  outwards);
* ``0 < T < 1``: not supported (raises).

Geometry: spheres are Mitsuba ``sphere``; infinite planes are a Mitsuba
``rectangle`` of half-size ``plane_extent`` (default ``1e3`` times the camera's
distance to the plane's point); quads, triangles, tetrahedra, boxes and meshes
are ``mi.Mesh`` objects with flat face normals (triangles from raytrax's own
definitions, so a regular tetrahedron or a rotated box is the same solid).

Integrators (``scene_dict(..., integrator=...)``):

* ``"whitted"`` (the default): the deterministic full tree above, run as a Python
  wavefront (``dr.compress`` and ``dr.eval`` at every depth, so Dr.Jit launches
  many small kernels). It is the *image reference* (PSNR against raytrax), not
  a measure of Mitsuba's speed;
* ``"whitted_kernel"``: the same Whitted paths as a Monte Carlo renderer traces
  them, a plain ``mi.SamplingIntegrator`` whose ``sample`` is one symbolic
  ``dr.while_loop`` over the depth with masks, so ``mi.render`` records the whole
  render into one LLVM kernel; at a dielectric it follows the reflected ray with
  probability ``F``, else the refracted one. Its expectation is the deterministic
  tree (``benchmarks/bench_speed.py`` checks the PSNR at high spp). This is the
  Whitted integrator to time;
* ``"path"``: Mitsuba's built-in path tracer (it also gathers indirect diffuse
  light, so more work and a different image).

Two ways to render:

* :func:`render_native`: ``mi.render`` with Mitsuba's film and sampler: ``hdrfilm``
  (linear RGB float32), ``box`` reconstruction filter, ``stratified`` sampler
  (jittered inside each of the ``n x n`` strata) or ``independent``;
* :func:`render_grid`: the same integrator driven at exactly raytrax's sample
  positions (cell centres of an ``n x n`` grid per pixel, box-averaged), through
  Mitsuba's sensor ``sample_ray``. No sampling noise at all differs then, so
  what remains is the difference between the two renderers' models. It is
  plain Dr.Jit code and so differentiable with ``dr.backward`` (used for the
  gradient benchmark).

Needs the optional ``bench`` extra (``pip install mitsuba``) and, on Debian 12,
``apt-get install libllvm19`` for the LLVM variant (LLVM 15 crashes in Mitsuba's
kernels); :func:`ensure_mitsuba` says so instead of failing obscurely.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_VARIANT = "llvm_ad_rgb"

HOW_THEY_DIFFER = """\
How the raytrax and Mitsuba configurations differ:
- Both: pinhole camera with the same vertical fov, box pixel filter, direct light
  from point lights at every diffuse hit (hard shadows, every object occludes),
  ideal mirror / smooth dielectric chains up to max_depth specular interactions,
  black background, no indirect diffuse light.
- Mitsuba uses its own intersection (Embree BVH, analytic spheres), its own
  BSDFs (twosided diffuse, conductor 'none', dielectric) and point emitters; the
  Whitted path logic is a ~70-line Python integrator in
  benchmarks/mitsuba_scene.py (a subclass of Mitsuba's ADIntegrator, so
  sampler, camera rays and film splatting are Mitsuba's code), run as a
  wavefront that compacts live rays at each depth and follows *every* delta
  branch (full tree). This wavefront is the image reference, not a speed
  figure: benchmarks/bench_speed.py times Mitsuba's `path` and a one-kernel
  Whitted integrator instead. raytrax tests every ray against every primitive,
  except triangle lists of more than 64 (a BVH).
- raytrax keeps at most `branches` (= 2 with glass) specular rays per camera
  sample per depth, dropping the lightest; the reference wavefront keeps all of
  them (the one-kernel integrator samples one per vertex, F-weighted at glass).
- Sampling: raytrax uses the cell centres of an n x n grid per pixel; Mitsuba's
  'native' mode uses its stratified sampler (jittered within each cell) and the
  hdrfilm box filter; 'grid' mode feeds Mitsuba exactly raytrax's positions.
- Infinite planes become a Mitsuba rectangle of half-size 1e3 x the camera
  distance; shadow-ray offsets differ (raytrax 1e-4 relative along the normal,
  Mitsuba its own ray epsilon).
- Mitsuba runs in float32 with its LLVM JIT on all cores; raytrax in float32 on
  XLA:CPU. Mitsuba's timed gradients are Dr.Jit reverse mode (mi.render +
  dr.backward) through the one-kernel integrator or `path`, w.r.t. the light
  positions only (its dielectric IOR is not differentiable); raytrax's also
  covers the IORs."""


class MitsubaUnavailable(RuntimeError):
    pass


_MI = None


def ensure_mitsuba(variant: str = DEFAULT_VARIANT, *, probe: bool = True):
    """Import mitsuba, set ``variant`` and check that its JIT backend runs.

    Raises :class:`MitsubaUnavailable` with a hint when it cannot start.
    ``probe=False`` skips the test render in a subprocess (for a process whose
    parent has already run it).
    """
    global _MI
    if _MI is not None:
        return _MI
    try:
        import drjit as dr
        import mitsuba as mi
    except Exception as e:  # noqa: BLE001
        raise MitsubaUnavailable(
            f"Mitsuba 3 is not installed ({e}). Install the benchmark extra: "
            "pip install -e '.[bench]'  (or pip install mitsuba)"
        ) from e
    failure = _probe(variant) if probe else ""
    if failure:
        hint = ""
        if variant.startswith("llvm"):
            hint = (
                " Mitsuba's LLVM variants need a working libLLVM: on Debian 12 run "
                "`apt-get install libllvm19` (the LLVM 15 that is installed crashes in "
                "Mitsuba's kernels), or point DRJIT_LIBLLVM_PATH at a newer libLLVM.so; "
                "or use the variant 'scalar_rgb'."
            )
        raise MitsubaUnavailable(f"Mitsuba variant {variant!r} cannot start: {failure}.{hint}")
    mi.set_variant(variant)
    _register_integrator(mi, dr)
    _MI = mi
    return mi


# ----------------------------------------------------------------------------
# The Whitted integrator (Mitsuba API only)
# ----------------------------------------------------------------------------

_WHITTED_CLS = None

_PROBE = """
import sys, mitsuba as mi, drjit as dr
mi.set_variant(sys.argv[1])
s = mi.load_dict({"type": "scene", "integrator": {"type": "direct"},
                  "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
                  "e": {"type": "point", "position": [0, 0, 2]}, "b": {"type": "sphere", "center": [0, 0, -3]}})
img = mi.render(s, spp=1)
assert img.numpy().shape == (8, 8, 3)
"""


def _probe(variant):
    """Render a tiny scene in a subprocess (a broken libLLVM crashes the process,
    not just raise). Returns an error string, or '' when fine."""
    import subprocess
    import sys

    try:
        r = subprocess.run([sys.executable, "-c", _PROBE, variant], capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        return "a test render did not finish in 300 s"
    if r.returncode == 0:
        return ""
    tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
    how = f"killed by signal {-r.returncode}" if r.returncode < 0 else f"exit status {r.returncode}"
    return f"a test render in a subprocess failed ({how}): " + " | ".join(tail)


def _register_integrator(mi, dr):
    global _WHITTED_CLS
    if _WHITTED_CLS is not None:
        return
    from mitsuba.ad.integrators.common import ADIntegrator  # pyright: ignore[reportMissingImports]

    class Whitted(ADIntegrator):
        """Whitted paths: direct light at every hit, both delta lobes followed.

        Wavefront form: depth by depth, the live rays (non-zero weight) are
        compacted (``dr.compress``) so the full tree costs only the rays that
        exist; each ray carries the index of its camera sample, and radiance
        is scatter-added there. Subclassing Mitsuba's ``ADIntegrator`` reuses its
        ``render``: sampler, sensor rays and box-filtered film splatting are
        Mitsuba's own code.
        """

        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", 5))
            bg = props.get("background", mi.ScalarColor3f(0.0))
            self.background = [float(bg[0]), float(bg[1]), float(bg[2])]
            self.counts = None  # dict of ray counts when counting is on

        def trace(self, scene, ray, counts=None):
            """Radiance ``mi.Color3f`` of the rays ``ray`` (one per lane)."""
            N = dr.width(ray.d)
            bg = mi.Color3f(*self.background)
            acc = dr.zeros(mi.Color3f, N)
            sid = dr.arange(mi.UInt32, N)
            w = dr.full(mi.Color3f, 1.0, N)
            o, d = mi.Point3f(ray.o), mi.Vector3f(ray.d)
            emitters = scene.emitters()
            for depth in range(self.max_depth + 1):
                n = dr.width(d)
                if n == 0:
                    break
                if counts is not None:
                    counts["specular" if depth else "camera"] = counts.get("specular" if depth else "camera", 0) + n
                si = scene.ray_intersect(mi.Ray3f(o, d), +mi.RayFlags.All, mi.Bool(depth == 0))
                hit = si.is_valid()
                L = dr.select(hit, mi.Color3f(0.0), w * bg)
                bsdf = si.bsdf()
                ctx = mi.BSDFContext()
                for em in emitters:
                    ds, spec = em.sample_direction(si, mi.Point2f(0.5, 0.5), hit)
                    f = bsdf.eval(ctx, si, si.to_local(ds.d), hit)  # BSDF value times cosine
                    need = hit & (dr.max(f) > 0.0) & (dr.max(spec) > 0.0)
                    if counts is not None:
                        counts["shadow"] = counts.get("shadow", 0) + int(dr.count(need)[0])
                    blocked = scene.ray_test(si.spawn_ray_to(ds.p), need)
                    L += dr.select(need & ~blocked, w * f * spec, mi.Color3f(0.0))
                kids = []
                for lobe in (mi.BSDFFlags.DeltaReflection, mi.BSDFFlags.DeltaTransmission):
                    cx = mi.BSDFContext(mi.TransportMode.Radiance, int(lobe))
                    # sample1 = 0: a blendbsdf(diffuse, conductor) picks its conductor.
                    bs, wk = bsdf.sample(cx, si, 0.0, mi.Point2f(0.5, 0.5), hit)
                    wc = w * wk
                    go = hit & (bs.pdf > 0.0) & (dr.max(wc) > 0.0)
                    if depth == self.max_depth:
                        L += dr.select(go, wc * bg, mi.Color3f(0.0))
                    else:
                        kids.append((si.spawn_ray(si.to_world(bs.wo)), wc, go))
                dr.scatter_reduce(dr.ReduceOp.Add, acc, L, sid)
                if not kids:
                    break
                # Compact the live children of both lobes into the next wavefront.
                kids = [(r, wc, dr.compress(go)) for r, wc, go in kids]
                kids = [k for k in kids if dr.width(k[2]) > 0]
                if not kids:
                    break
                sel = [s for _, _, s in kids]
                o = _cat(mi.Point3f, [dr.gather(mi.Point3f, r.o, s) for (r, _, _), s in zip(kids, sel)])
                d = _cat(mi.Vector3f, [dr.gather(mi.Vector3f, r.d, s) for (r, _, _), s in zip(kids, sel)])
                w = _cat(mi.Color3f, [dr.gather(mi.Color3f, wc, s) for (_, wc, _), s in zip(kids, sel)])
                sids = [dr.gather(mi.UInt32, sid, s) for s in sel]
                sid = sids[0] if len(sids) == 1 else dr.concat(sids)
                dr.eval(o, d, w, sid, acc)
            dr.eval(acc)
            return acc

        def sample(
            self, mode, scene, sampler, ray, depth=None, δL=None, δaovs=None, state_in=None, active=True, **kwargs
        ):
            if mode != dr.ADMode.Primal:
                raise NotImplementedError(
                    "the Whitted reference integrator renders in primal mode only "
                    "(differentiate render_grid with dr.backward instead)"
                )
            L = self.trace(scene, ray, self.counts)
            return L, dr.full(mi.Bool, True, dr.width(L)), [], None

        def aov_names(self):
            return []

        def to_string(self):
            return f"RaytraxWhitted[max_depth={self.max_depth}]"

    def _cat(T, parts):
        if len(parts) == 1:
            return parts[0]
        return T(*(dr.concat([p[c] for p in parts]) for c in range(3)))

    class WhittedKernel(mi.SamplingIntegrator):
        """Whitted paths as Monte Carlo renderers trace them, in one kernel.

        ``sample`` is one symbolic ``dr.while_loop`` over the depth with masks (no
        ``dr.eval``, no compaction), so ``mi.render`` records the whole render into a
        single LLVM kernel. Per vertex: direct light from every point light (shadow
        test), as :class:`Whitted`; then *one* delta lobe is followed: at a dielectric
        the reflected ray with probability ``F`` and the refracted one otherwise
        (Mitsuba's ``dielectric.sample`` with a uniform ``sample1``), at a mirror the
        reflection; a diffuse-and-mirror ``blendbsdf`` picks its mirror with
        ``sample1 = 0`` as :class:`Whitted` does. Its expectation is
        :class:`Whitted`'s deterministic tree; it converges to it as spp grows.
        ``max_iterations`` is set, so Dr.Jit can differentiate the loop in reverse mode.
        """

        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", 5))
            bg = props.get("background", mi.ScalarColor3f(0.0))
            self.background = [float(bg[0]), float(bg[1]), float(bg[2])]

        def sample(self, scene, sampler, ray, medium=None, active=True):
            bg = mi.Color3f(*self.background)
            emitters = scene.emitters()
            max_depth = self.max_depth
            delta = mi.BSDFContext(mi.TransportMode.Radiance, int(mi.BSDFFlags.Delta))
            ctx = mi.BSDFContext()

            def cond(sampler, ray, w, L, depth, active):
                return active

            def body(sampler, ray, w, L, depth, active):
                si = scene.ray_intersect(ray, active)
                hit = active & si.is_valid()
                L += dr.select(active & ~hit, w * bg, mi.Color3f(0.0))
                bsdf = si.bsdf()
                for em in emitters:
                    ds, spec = em.sample_direction(si, mi.Point2f(0.5, 0.5), hit)
                    f = bsdf.eval(ctx, si, si.to_local(ds.d), hit)
                    need = hit & (dr.max(f) > 0.0) & (dr.max(spec) > 0.0)
                    blocked = scene.ray_test(si.spawn_ray_to(ds.p), need)
                    L += dr.select(need & ~blocked, w * f * spec, mi.Color3f(0.0))
                flags = bsdf.flags()
                mixture = mi.has_flag(flags, mi.BSDFFlags.Smooth) & mi.has_flag(flags, mi.BSDFFlags.Delta)
                u = dr.select(mixture, 0.0, sampler.next_1d(hit))
                bs, wk = bsdf.sample(delta, si, u, mi.Point2f(0.5, 0.5), hit)
                w = w * wk
                go = hit & (bs.pdf > 0.0) & (dr.max(w) > 0.0)
                last = depth >= max_depth
                L += dr.select(go & last, w * bg, mi.Color3f(0.0))
                ray = si.spawn_ray(si.to_world(bs.wo))
                return sampler, ray, w, L, depth + 1, go & ~last

            state = (
                sampler,
                mi.Ray3f(ray),
                mi.Color3f(1.0),
                mi.Color3f(0.0),
                mi.UInt32(0),
                mi.Bool(active),
            )
            _, _, _, L, _, _ = dr.while_loop(state, cond, body, label="whitted_kernel", max_iterations=max_depth + 1)
            return L, mi.Bool(True), []

        def aov_names(self):
            return []

        def to_string(self):
            return f"WhittedKernel[max_depth={self.max_depth}]"

    mi.register_integrator("raytrax_whitted", lambda props: Whitted(props))
    mi.register_integrator("raytrax_whitted_kernel", lambda props: WhittedKernel(props))
    _WHITTED_CLS = Whitted


# ----------------------------------------------------------------------------
# Scene conversion
# ----------------------------------------------------------------------------


def _np(x):
    return np.asarray(x, dtype=np.float64)


def material_bsdf(color, reflectivity, transparency, ior):
    """Mitsuba BSDF dict for one raytrax physical material (see module docstring)."""
    C, R, T = _np(color), _np(reflectivity), float(transparency)
    rgb = lambda c: {"type": "rgb", "value": [float(v) for v in c]}  # noqa: E731
    if T >= 1.0:
        return {"type": "dielectric", "int_ior": float(ior), "ext_ior": 1.0}
    if T > 0.0:
        raise NotImplementedError(
            f"partially transparent physical material (transparency={T}) has no Mitsuba mapping here"
        )
    kd = (1.0 - R) * C
    if not np.any(R > 0):
        inner = {"type": "diffuse", "reflectance": rgb(C)}
    elif not np.any(kd > 0):
        inner = {"type": "conductor", "material": "none", "specular_reflectance": rgb(R)}
    else:
        inner = {
            "type": "blendbsdf",
            "weight": 0.5,
            "bsdf_0": {"type": "diffuse", "reflectance": rgb(2.0 * kd)},
            "bsdf_1": {"type": "conductor", "material": "none", "specular_reflectance": rgb(R)},
        }
    return {"type": "twosided", "bsdf": inner}


def _euler_matrix(deg):
    rx, ry, rz = np.deg2rad(_np(deg))
    cx, cy, cz, sx, sy, sz = np.cos(rx), np.cos(ry), np.cos(rz), np.sin(rx), np.sin(ry), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def box_triangles(lo, hi, rotation):
    """12 outward-wound triangles ``(12, 3, 3)`` of a box rotated about its centre
    (Euler degrees, x then y then z, as raytrax's :class:`~raytrax.Boxes`)."""
    lo, hi = _np(lo), _np(hi)
    c, h = 0.5 * (lo + hi), 0.5 * np.abs(hi - lo)
    R = _euler_matrix(rotation)
    tris = []
    for ax in range(3):
        u, v = (ax + 1) % 3, (ax + 2) % 3
        for s in (-1.0, 1.0):

            def P(a, b):
                p = np.zeros(3)
                p[ax], p[u], p[v] = s * h[ax], a * h[u], b * h[v]
                return c + R @ p

            q = [P(-1, -1), P(1, -1), P(1, 1), P(-1, 1)]  # counter-clockwise about +ax
            if s < 0:
                q = q[::-1]
            tris += [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
    return np.array(tris)


def scene_triangles(scene):
    """All flat-shaded triangles of the scene, with material ids: quads, triangles,
    tetrahedra, boxes, meshes (planes and spheres excluded). Returns a list of
    ``(name, (T, 3, 3) vertices, material id)`` per object."""
    out = []
    q = scene.quads
    for i in range(q.corners.shape[0]):
        c = _np(q.corners[i])
        out.append((f"quad{i}", np.array([(c[0], c[1], c[2]), (c[0], c[2], c[3])]), int(q.material[i])))
    t = scene.triangles
    for i in range(t.vertices.shape[0]):
        out.append((f"triangle{i}", _np(t.vertices[i])[None], int(t.material[i])))
    te = scene.tetrahedra
    if te.center.shape[0]:
        tris, mats = te.triangles()
        tris, mats = _np(tris), np.asarray(mats)
        for i in range(te.center.shape[0]):
            out.append((f"tetrahedron{i}", tris[4 * i : 4 * i + 4], int(mats[4 * i])))
    b = scene.boxes
    for i in range(b.lo.shape[0]):
        out.append((f"box{i}", box_triangles(b.lo[i], b.hi[i], b.rotation[i]), int(b.material[i])))
    for i, m in enumerate(scene.meshes):
        v, f = _np(m.vertices), np.asarray(m.faces)
        out.append((f"mesh{i}", v[f], int(m.material)))
    return out


def _mi_mesh(mi, name, tris, bsdf):
    import drjit as dr

    tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
    nf = tris.shape[0]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    props["face_normals"] = True
    mesh = mi.Mesh(name, 3 * nf, nf, props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(tris.reshape(-1).astype(np.float32))
    params["faces"] = mi.UInt32(np.arange(3 * nf, dtype=np.uint32))
    params.update()
    dr.eval()
    return mesh


def _look_at(mi, origin, target, up):
    T = mi.ScalarTransform4f
    o, t, u = ([float(x) for x in _np(a)] for a in (origin, target, up))
    try:
        return T().look_at(origin=o, target=t, up=u)
    except TypeError:  # Mitsuba < 3.5
        return T.look_at(origin=o, target=t, up=u)


def _plane_to_world(mi, point, normal, extent):
    n = _np(normal)
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    t1 = a - np.dot(a, n) * n
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = t1 * extent, t2 * extent, n, _np(point)
    return mi.ScalarTransform4f(M.tolist())


def scene_dict(
    scene,
    *,
    width=None,
    height=None,
    spp=None,
    max_depth=None,
    sampler="stratified",
    plane_extent=None,
    variant=DEFAULT_VARIANT,
    seed=0,
    integrator="whitted",
):
    """A Mitsuba scene dict for a built ``physical`` raytrax ``scene``.

    ``width``/``height``/``spp``/``max_depth`` override the scene's settings.
    ``sampler`` is ``"stratified"`` (jittered ``n x n`` grid) or ``"independent"``.
    ``integrator``: ``"whitted"`` (the deterministic full-tree wavefront, the image
    reference), ``"whitted_kernel"`` (Whitted paths sampled in one kernel) or
    ``"path"`` (Mitsuba's built-in path tracer; ``max_depth`` is then Mitsuba's
    own, which counts path segments: 2 is direct light only).
    """
    kinds = {"whitted": "raytrax_whitted", "whitted_kernel": "raytrax_whitted_kernel", "path": "path"}
    if integrator not in kinds:
        raise ValueError(f"integrator: expected one of {sorted(kinds)}, got {integrator!r}")
    mi = ensure_mitsuba(variant)
    st = scene.settings
    if st.shading != "physical":
        raise ValueError(f"only physical scenes have a Mitsuba counterpart (got {st.shading!r})")
    W = width or st.width
    H = height or st.height
    spp = spp or st.spp
    depth = st.max_depth if max_depth is None else max_depth
    cam = scene.camera
    d = {
        "type": "scene",
        "integrator": {
            "type": kinds[integrator],
            "max_depth": int(depth),
            "background": mi.ScalarColor3f(*[float(x) for x in _np(scene.environment.background)]),
        },
        "sensor": {
            "type": "perspective",
            "fov_axis": "y",
            "fov": float(cam.fov),
            "near_clip": 1e-4,
            "far_clip": 1e7,
            "to_world": _look_at(mi, cam.position, cam.look_at, cam.up),
            "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)},
            "film": {
                "type": "hdrfilm",
                "width": int(W),
                "height": int(H),
                "pixel_format": "rgb",
                "component_format": "float32",
                "rfilter": {"type": "box"},
            },
        },
    }
    if integrator == "path":
        if np.any(_np(scene.environment.background) != 0.0):
            raise NotImplementedError(
                "integrator 'path': only a black background is converted (no environment emitter)"
            )
        del d["integrator"]["background"]
    mats = scene.materials
    bsdfs = [
        material_bsdf(mats.color[k], mats.reflectivity[k], mats.transparency[k], mats.ior[k])
        for k in range(mats.color.shape[0])
    ]
    for i in range(scene.lights.position.shape[0]):
        d[f"light{i}"] = {
            "type": "point",
            "position": [float(x) for x in _np(scene.lights.position[i])],
            "intensity": {"type": "rgb", "value": [float(x) for x in _np(scene.lights.intensity[i])]},
        }
    sp = scene.spheres
    for i in range(sp.center.shape[0]):
        d[f"sphere{i}"] = {
            "type": "sphere",
            "center": [float(x) for x in _np(sp.center[i])],
            "radius": float(sp.radius[i]),
            "bsdf": bsdfs[int(sp.material[i])],
        }
    pl = scene.planes
    for i in range(pl.point.shape[0]):
        ext = plane_extent or 1e3 * max(1.0, float(np.linalg.norm(_np(cam.position) - _np(pl.point[i]))))
        d[f"plane{i}"] = {
            "type": "rectangle",
            "to_world": _plane_to_world(mi, pl.point[i], pl.normal[i], ext),
            "bsdf": bsdfs[int(pl.material[i])],
        }
    for name, tris, m in scene_triangles(scene):
        d[name] = _mi_mesh(mi, name, tris, bsdfs[m])
    if int(np.asarray(scene.materials.tex_kind).max(initial=0)) != 0:
        raise NotImplementedError("textured materials are not converted to Mitsuba")
    return d


def load(scene, **kw):
    """``mi.load_dict(scene_dict(scene, **kw))``."""
    mi = ensure_mitsuba(kw.get("variant", DEFAULT_VARIANT))
    return mi.load_dict(scene_dict(scene, **kw))


def render_native(mscene, spp=None, seed=0):
    """``mi.render`` with the scene's own sampler and box-filtered film: ``(H, W, 3)`` float32."""
    mi = ensure_mitsuba()
    img = mi.render(mscene, spp=spp or 0, seed=seed)  # pyright: ignore[reportArgumentType]
    return np.array(img, dtype=np.float32)


def grid_rays(mscene, width, height, spp):
    """Camera rays through Mitsuba's sensor at raytrax's sample positions (``n x n``
    cell centres per pixel), pixel-major: sample ``k`` of pixel ``p`` is lane ``p * spp + k``."""
    import drjit as dr

    mi = ensure_mitsuba()
    n = math.isqrt(spp)
    if n * n != spp:
        raise ValueError("spp must be a square number")
    sensor = mscene.sensors()[0]
    N = width * height * spp
    idx = dr.arange(mi.UInt32, N)
    pix = idx // spp
    s = idx - pix * spp
    row = pix // width
    col = pix - row * width
    sx = (mi.Float(s % n) + 0.5) / n
    sy = (mi.Float(s // n) + 0.5) / n
    pos = mi.Point2f((mi.Float(col) + sx) / width, (mi.Float(row) + sy) / height)
    ray, _ = sensor.sample_ray(mi.Float(0.0), mi.Float(0.5), pos, mi.Point2f(0.5, 0.5))
    return ray


def grid_radiance(mscene, width, height, spp, counts=None, rays=None):
    """Dr.Jit image ``mi.TensorXf (H, W, 3)``: the Whitted integrator at raytrax's
    sample positions, box-averaged per pixel (differentiable with ``dr.backward``)."""
    import drjit as dr

    mi = ensure_mitsuba()
    ray = grid_rays(mscene, width, height, spp) if rays is None else rays
    L = mscene.integrator().trace(mscene, ray, counts)
    img = mi.Color3f(*(dr.block_sum(L[c], spp) / spp for c in range(3)))  # pyright: ignore[reportArgumentType]
    return mi.TensorXf(dr.ravel(img), shape=(height, width, 3))  # pyright: ignore[reportArgumentType]


def render_grid(mscene, width, height, spp):
    """:func:`grid_radiance` as a numpy ``(H, W, 3)`` float32 image."""
    return np.array(grid_radiance(mscene, width, height, spp), dtype=np.float32)


def count_rays(mscene, width, height, spp):
    """Rays the Whitted paths need at raytrax's sample positions: a dict with
    ``camera``, ``specular`` and ``shadow`` counts (full specular tree)."""
    counts = {}
    img = grid_radiance(mscene, width, height, spp, counts=counts)
    np.array(img)
    return counts


def psnr(a, b, peak=1.0):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def srgb(x):
    """Linear [0, 1] -> sRGB-encoded [0, 1] (clipped)."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
