"""The Whitted integrator: a fixed-depth unroll of reflection and refraction.

``render(scene)`` splits the image into tiles of pixels (``lax.map`` over tiles,
each under ``jax.checkpoint`` so reverse mode holds one tile's rays at a time).
Inside a tile, each camera sample carries up to ``branches`` specular branches:

* depth 0: camera rays are intersected and shaded (direct light at the hit);
  each hit spawns a reflected and a refracted child weighted by the material
  (Fresnel for dielectrics);
* the ``2 * b`` children of a sample are cut back to its ``branches`` heaviest
  (``lax.top_k`` on the channel-max throughput), so the work per depth is
  bounded by ``branches`` rays per sample and never grows as ``2^depth``;
* at depth >= 1 the live rays (non-zero throughput) are compacted to the front
  and processed in sub-tiles, and a sub-tile with no live ray is skipped
  (``lax.cond``): paths that ended at a diffuse surface cost nothing more;
* at depth ``max_depth`` the specular children take the background instead.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from . import vec as V
from .camera import primary_rays, rays_through
from .edges import EdgeOptions, edge_term
from .intersect import EPS_REL, closest_hit, occluder_counts, prepare
from .lights import LIGHTS
from .materials import fresnel_dielectric, material_rows, refract
from .scene import Scene, Settings
from .textures import footprint_widths, linearized_hit, needs_footprint, surface_color

RAYS_PER_TILE = 16384
SUBTILE = 4096
# Reverse mode keeps only the inputs of each sub-tile's shading (and the values
# named here) and recomputes the rest: storing every intermediate of every
# bounce costs more in memory traffic than recomputing it.
_SHADE_POLICY = jax.checkpoint_policies.save_only_these_names("raytrax_search", "raytrax_shadow")


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """Static options of one compiled render (see :class:`~raytrax.scene.Settings`)."""

    settings: Settings
    tile_rays: int = RAYS_PER_TILE
    subtile: int = SUBTILE
    jitter: bool = False
    devices: int = 1


def _shade(scene: Scene, kinds, o, d, w, cw, spread, opts: RenderOptions, last: bool, sel=None):
    """Intersect and shade rays ``o, d (3, n)`` with throughput ``w (3, n)``.

    Returns the radiance they contribute ``(3, n)`` and their reflected and
    refracted children (origin, direction, throughput) plus the cone width at
    the hit (for the children's texture footprints). ``sel (n,)`` (optional, no
    gradient): per ray, the one light whose contribution it carries (``l`` below
    the number of lights; no ambient, no background), or everything (``>= L``).
    """
    st = opts.settings
    mats = scene.materials
    env = scene.environment
    dt = o.dtype
    # The hit, and (filtered procedural textures) how its uv moves with the ray: the footprints' uv Jacobian.
    hit, uv_shift = linearized_hit(lambda o_: closest_hit(kinds, o_, d), o, needs_footprint(mats, st.filter_textures))
    valid = hit.valid
    t = hit.t
    p = o + t[None] * d
    mat = hit.material

    cos_d = V.dot(d, hit.normal)
    front = cos_d < 0
    n_s = V.vsel(front, hit.normal, -hit.normal)  # faces the incoming ray
    cos_i = jnp.abs(cos_d)
    eps = EPS_REL * (1.0 + jnp.maximum(jnp.maximum(jnp.abs(p[0]), jnp.abs(p[1])), jnp.abs(p[2])))
    p_out = p + eps[None] * n_s
    p_in = p - eps[None] * n_s

    cw_hit = cw + spread * t
    # Anisotropic box-filter widths in uv: the cone's ellipse on the surface (long along the view at grazing angles).
    wuv = jnp.zeros_like(hit.uv) if uv_shift is None else footprint_widths(uv_shift, d, hit.normal, cw_hit)
    names = ("color", "transparency", "reflectivity", "ior")
    if st.shading == "classic":
        names += ("diffuse", "specular", "shininess", "ambient")
    if mats.kinds_present:
        names += ("tex_scale", "tex_color2", "tex_direction")
    rows = material_rows(mats, mat, names)
    color = surface_color(mats, mat, hit.uv, wuv, st.filter_textures, rows)
    T = rows["transparency"]
    R = rows["reflectivity"]
    ior = rows["ior"]

    # --- direct light -----------------------------------------------------
    # Every light of every type, in registry order (raytrax.lights.LIGHTS).
    samples = [
        spec.sample(scene.light_sets[spec.field], j, p_out)
        for spec in LIGHTS
        for j in range(spec.count(scene.light_sets[spec.field]))
    ]
    L = len(samples)
    n = o.shape[1]
    local = jnp.zeros_like(o)

    def carries(l):  # (n,) rays that carry light l (l = L: ambient and background), or None: all
        return None if sel is None else (sel == l) | (sel >= L)

    if L:
        # One light at a time on (n,) / (3, n) arrays: no (3, L, n) broadcasts and no
        # reductions over short axes (XLA:CPU runs those, and their transposes, slowly).
        dist, ldir, cosl, lit = [], [], [], []
        for l, smp in enumerate(samples):
            dist.append(smp.distance)
            ldir.append(smp.direction)
            cosl.append(V.dot(n_s, ldir[l]))
            lit.append((cosl[l] > 0) & valid & (True if sel is None else carries(l)))
        M = mats.color.shape[0]
        I = [smp.strength for smp in samples]
        classic = st.shading == "classic"

        def shadow(p0, dirn, tmax):
            c = occluder_counts(kinds, p0, dirn, tmax, M)  # (n, M)
            if classic:
                return c
            blocked = c[:, 0] != 0
            for m in range(1, M):
                blocked = blocked | (c[:, m] != 0)
            return blocked

        def no_shadow(p0, dirn, tmax):
            return jnp.zeros((n, M), dt) if classic else jnp.zeros((n,), bool)

        if classic:
            diffuse = rows["diffuse"] * (1.0 - T)
            specular = rows["specular"]
            shininess = rows["shininess"]
        else:
            E = jnp.zeros_like(o)
        for l in range(L):
            # Shadow rays of one light, under a cond: skipped when no ray faces the
            # light, and the result is materialised once (XLA:CPU would otherwise
            # fuse the occlusion tests into each colour channel's shading).
            sh = jax.lax.cond(jnp.any(lit[l]), shadow, no_shadow, p_out, ldir[l], dist[l] * (1.0 - 1e-6))
            sh = checkpoint_name(sh, "raytrax_shadow")
            if classic:
                trans = jnp.ones_like(t)
                for m in range(M):  # shadow transmission: each crossing multiplies by the occluder's transparency
                    has = sh[:, m] > 0
                    trans = trans * jnp.where(
                        has, jnp.where(has, mats.transparency[m], 1.0) ** jnp.where(has, sh[:, m], 1.0), 1.0
                    )
                diff = diffuse * jnp.maximum(cosl[l], 0.0)
                rv = V.dot(V.reflect(-ldir[l], n_s), -d)
                spec = jnp.where(lit[l], specular * V.safe_pow(rv, shininess), 0.0)
                s = trans * jnp.where(lit[l], 1.0, 0.0)
                local = local + I[l][:, None] * s[None] * (diff[None] * color + spec[None])
            else:
                vis = jnp.logical_not(sh) & lit[l]
                g = jnp.where(vis, jnp.maximum(cosl[l], 0.0) * samples[l].falloff, 0.0)
                E = E + I[l][:, None] * g[None]
        if not classic:
            local = ((1.0 - T)[None] * (1.0 - R) * color * (1.0 / math.pi)) * E
    amb, bg = env.ambient[:, None], env.background[:, None]
    if sel is not None:  # lit[l] above leaves out the lights a ray does not carry
        env_on = carries(L).astype(dt)[None]  # pyright: ignore
        amb, bg = amb * env_on, bg * env_on
    if st.shading == "classic":
        local = local + amb * (rows["ambient"] * (1.0 - T))[None] * color

    # --- specular children -------------------------------------------------
    eta = jnp.where(front, V.safe_div(1.0, ior), ior)
    F, cos_t, tir = fresnel_dielectric(cos_i, eta)
    tdir = refract(d, n_s, eta, cos_t)
    rdir = V.reflect(d, n_s)
    if st.shading == "classic":
        tirf = tir.astype(dt)
        wr = R + (T * tirf)[None]
        wt = jnp.broadcast_to((T * (1.0 - tirf))[None], wr.shape)
    else:
        wr = (T * F)[None] + (1.0 - T)[None] * R
        wt = jnp.broadcast_to((T * (1.0 - F) * eta * eta)[None], wr.shape)
    vm = valid[None]
    wr = jnp.where(vm, w * wr, 0.0)
    wt = jnp.where(vm, w * wt, 0.0)
    contrib = jnp.where(vm, w * local, w * bg)
    # After the last allowed specular interaction, specular children see the background.
    contrib = contrib + jnp.where(last, 1.0, 0.0).astype(dt) * (wr + wt) * bg
    return contrib, (p_out, rdir, wr, p_in, tdir, wt, cw_hit)


def _permutation(active):
    """Stable partition of ``active (n,)``: ``order (n,)`` lists the live rays first
    (each group in its original order), ``dest (n,)`` is its inverse (the slot of
    each ray). Two cumulative sums and one scatter: no sort."""
    n = active.shape[0]
    live = jnp.cumsum(active, dtype=jnp.int32)
    dest = jnp.where(active, live - 1, live[-1] + jnp.arange(n, dtype=jnp.int32) - live)
    order = jnp.zeros((n,), jnp.int32).at[dest].set(jnp.arange(n, dtype=jnp.int32), unique_indices=True)
    return order, dest


def _take_unique(a, idx):
    """``a[..., idx]`` for indices without repeats: the transpose is then a scatter
    with ``unique_indices`` (no collisions to combine)."""
    return a.at[..., idx].get(unique_indices=True, mode="promise_in_bounds")


def _compact_map(fn, args, active, sub):
    """Apply ``fn`` to the rays of ``args`` (arrays with the ray axis last) but skip
    sub-tiles of ``sub`` rays that hold no ``active`` ray: live rays are moved to
    the front first (a stable partition, no sort). Returns ``fn``'s outputs in the
    original ray order."""
    n = active.shape[0]
    shapes = jax.eval_shape(fn, *args)
    if n <= sub:
        zeros = lambda *a: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return jax.lax.cond(jnp.any(active), fn, zeros, *args)
    S = math.ceil(n / sub)
    pad = S * sub - n
    if pad:  # padding rays: inactive, so they sort to the end
        active = jnp.concatenate([active, jnp.zeros((pad,), bool)])
        args = jax.tree_util.tree_map(lambda a: jnp.pad(a, [(0, 0)] * (a.ndim - 1) + [(0, pad)]), args)
    order, dest = _permutation(active)
    act = jnp.arange(S * sub, dtype=jnp.int32) < jnp.sum(active, dtype=jnp.int32)

    def split(a):
        a = _take_unique(a, order)
        a = a.reshape(a.shape[:-1] + (S, sub))
        return jnp.moveaxis(a, -2, 0)

    sub_args = jax.tree_util.tree_map(split, args)
    sub_act = act.reshape(S, sub)
    sub_shapes = jax.eval_shape(fn, *jax.tree_util.tree_map(lambda a: a[0], sub_args))

    def zeros(*a):
        return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), sub_shapes)

    def one(x):
        a, live = x
        return jax.lax.cond(live[0], fn, zeros, *a)

    outs = jax.lax.map(one, (sub_args, sub_act))
    dest_n = dest[:n]

    def merge(a):
        a = jnp.moveaxis(a, 0, -2)
        a = a.reshape(a.shape[:-2] + (S * sub,))
        return _take_unique(a, dest_n)

    return jax.tree_util.tree_map(merge, outs)


def _top_branches(kids, B, n):
    """From ``2 B`` candidate children per sample keep the ``B`` heaviest.

    ``kids`` holds (origin, direction, throughput) of the reflected and the
    refracted children and the cone width, each with ray axis ``B * n``
    (slot-major). Selection uses the channel-max throughput (no gradient).
    """
    po, rd, wr, pi, td, wt, cwh = kids

    def two(a_r, a_t):
        k = a_r.shape[0]
        return jnp.concatenate([a_r.reshape(k, B, n), a_t.reshape(k, B, n)], 1)

    co, cd, cwt = two(po, pi), two(rd, td), two(wr, wt)
    ccw = jnp.concatenate([cwh.reshape(B, n), cwh.reshape(B, n)], 0)
    score = jax.lax.stop_gradient(jnp.maximum(jnp.maximum(cwt[0], cwt[1]), cwt[2]))  # (2B, n)
    # The B best of 2B by rank counting (lax.top_k's order: descending, ties to the
    # lower index), elementwise: for small B cheaper on CPU than a top_k call.
    rank = []
    for j in range(2 * B):
        r = jnp.zeros((n,), jnp.int32)
        for k in range(2 * B):
            if k != j:
                r = r + (score[k] >= score[j] if k < j else score[k] > score[j]).astype(jnp.int32)
        rank.append(r)
    top = []
    for r in range(B):
        pick = jnp.zeros((n,), jnp.int32)
        for j in range(2 * B):
            pick = jnp.where(rank[j] == r, j, pick)
        top.append(pick)
    top = jnp.stack(top)  # (B, n)

    def g(a):  # a (k, 2B, n) -> (k, B n): a select chain (elementwise, also in reverse mode)
        out = jnp.broadcast_to(a[:, :1], (a.shape[0], B, n))
        for j in range(1, 2 * B):
            out = jnp.where(top[None] == j, a[:, j : j + 1], out)
        return out.reshape(a.shape[0], -1)

    return g(co), g(cd), g(cwt), g(ccw[None])[0]


def _trace(scene: Scene, kinds, o, d, spread, opts: RenderOptions, sel=None):
    """Radiance ``(3, n)`` of camera rays ``o, d (3, n)`` (``sel (n,)``: see :func:`_shade`).

    Every depth runs the same compiled body (a ``lax.scan`` over depth) on a
    fixed buffer of ``branches`` rays per camera sample; slots without weight
    are compacted away by :func:`_compact_map`.
    """
    st = opts.settings
    B = st.branches
    n = o.shape[1]
    dt = o.dtype
    pad = lambda a, fill: jnp.concatenate([a] + [jnp.full_like(a, fill)] * (B - 1), -1)
    w = pad(jnp.ones_like(o), 0.0)
    state = (pad(o, 0.0), pad(d, 0.0), w, jnp.zeros((B * n,), dt))
    # A ray's children stay in its sample's column of the (B, n) slots: ``sel`` is
    # the same for all of them.
    sel_b = None if sel is None else jnp.tile(sel, B)

    def body(carry, depth):
        (o_, d_, w_, cw_), radiance = carry
        last = depth == st.max_depth

        @functools.partial(jax.checkpoint, policy=_SHADE_POLICY)
        def fn(a, b, c, e, *f):
            return _shade(scene, kinds, a, b, c, e, spread, opts, last, *f)

        active = jnp.any(w_ > 0, 0)
        args = (o_, d_, w_, cw_) + (() if sel is None else (sel_b,))
        contrib, kids = _compact_map(fn, args, active, opts.subtile)
        radiance = radiance + contrib.reshape(3, B, n).sum(1)
        return (_top_branches(kids, B, n), radiance), None

    (_, radiance), _ = jax.lax.scan(body, (state, jnp.zeros_like(o)), jnp.arange(st.max_depth + 1))
    return radiance


def _render(scene: Scene, opts: RenderOptions, key):
    st = opts.settings
    W, H, spp = st.width, st.height, st.spp
    P = W * H
    tile = max(1, min(P, opts.tile_rays // spp))
    n_dev = opts.devices
    n_tiles = math.ceil(P / tile / n_dev) * n_dev
    pix = jnp.minimum(jnp.arange(n_tiles * tile, dtype=jnp.int32), P - 1).reshape(n_tiles, tile)
    ids = jnp.arange(n_tiles, dtype=jnp.int32)

    def run(scene, pix, ids, key):
        kinds = prepare(scene)

        def tile_fn(args):
            pix_t, i = args
            k = None if key is None else jax.random.fold_in(key, i)
            o, d, spread = primary_rays(scene.camera, pix_t, W, H, spp, k)
            rad = _trace(scene, kinds, o, d, spread, opts)
            return rad.reshape(3, spp, tile).mean(1).T  # (tile, 3)

        return jax.lax.map(jax.checkpoint(tile_fn), (pix, ids))

    if n_dev > 1:
        from jax.sharding import PartitionSpec as Spec

        mesh = jax.make_mesh(
            (n_dev,), ("tiles",), devices=jax.devices()[:n_dev], axis_types=(jax.sharding.AxisType.Auto,)
        )
        run = jax.shard_map(
            run,
            mesh=mesh,
            in_specs=(Spec(), Spec("tiles"), Spec("tiles"), Spec()),
            out_specs=Spec("tiles"),
            check_vma=False,
        )
    out = run(scene, pix, ids, key)
    return out.reshape(n_tiles * tile, 3)[:P].reshape(H, W, 3)


_render_jit = eqx.filter_jit(_render)


def _map_positions(fn, xy, chunk: int, sel=None):
    """``fn(xy_chunk (2, c), sel_chunk (c,) or None) -> (c, k)`` over image positions
    ``xy (2, M)`` (and per-position ``sel (M,)``) in chunks of at most ``chunk``
    (``lax.map``; the last chunk is padded); returns ``(M, k)``."""
    M = xy.shape[1]
    c = max(1, min(M, chunk))
    nc = math.ceil(M / c)
    xyc = jnp.pad(xy, ((0, 0), (0, nc * c - M)), mode="edge").reshape(2, nc, c).transpose(1, 0, 2)
    if sel is None:
        out = jax.lax.map(lambda x: fn(x, None), xyc)
    else:
        out = jax.lax.map(lambda a: fn(*a), (xyc, jnp.pad(sel, (0, nc * c - M), mode="edge").reshape(nc, c)))
    return out.reshape((nc * c,) + out.shape[2:])[:M]


def _spread(scene: Scene, opts: RenderOptions, n: int):
    """Cone spread of one sample of the ``n x n`` grid (see ``primary_rays``)."""
    return 2.0 * jnp.tan(jnp.deg2rad(scene.camera.fov) * 0.5) / opts.settings.height / n


def _radiance_at(scene: Scene, opts: RenderOptions, xy, n: int, light=None, grad=False):
    """Radiance ``(M, 3)`` of camera rays through image positions ``xy (2, M)`` (no
    gradient unless ``grad``; the jump across an edge). ``light`` (an index or ``(M,)``
    indices, may be traced): where below the number of lights, only what that light
    contributes, through every specular path (no ambient, no background, the other
    lights off); at or above it, everything. One trace of each ray whatever the indices."""
    st = opts.settings
    if not grad:
        scene = jax.lax.stop_gradient(scene)
    sel = None if light is None else jnp.broadcast_to(jnp.asarray(light, jnp.int32), xy.shape[1:])
    spread = _spread(scene, opts, n)
    kinds = prepare(scene)

    def one(x, s):
        o, d = rays_through(scene.camera, x, st.width, st.height)
        return _trace(scene, kinds, o, d, spread, opts, s).T

    return _map_positions(one, xy, opts.tile_rays // st.branches, sel)


def _render_edges(scene: Scene, opts: RenderOptions, eo):
    """The image from its ``n x n`` sample grid (``n = sqrt(spp)``), plus the boundary
    term of :mod:`raytrax.edges` (zero in value) found on the same samples."""
    st = opts.settings
    n = eo.samples
    W, H = st.width, st.height
    grid = dataclasses.replace(opts, settings=dataclasses.replace(st, width=W * n, height=H * n, spp=1), jitter=False)
    samples = _render(scene, grid, None)  # (H n, W n, 3), differentiable
    img = samples.reshape(H, n, W, n, 3).mean((1, 3))
    # Jumps are measured with the hard (unfiltered) patterns, and edge pieces are cut
    # where the pattern changes beside the edge: the derivative the estimate converges
    # to is that of the image as the samples grow, where the filter width goes to 0.
    hard = dataclasses.replace(opts, settings=dataclasses.replace(st, filter_textures=False))
    # The quadrature's rays are shaded as the grid's samples are: ``opts`` (edge mode
    # has no jitter: ``render`` refuses a key with it).
    edge, _ = edge_term(
        scene,
        W,
        H,
        eo,
        lambda xy, light=None: _radiance_at(scene, hard, xy, n, light),
        lambda xy: _radiance_at(scene, opts, xy, n, grad=True),
    )
    return img + edge


_render_edges_jit = eqx.filter_jit(_render_edges)


def render(
    scene: Scene,
    *,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    max_depth: int | None = None,
    key=None,
    filter_textures: bool | None = None,
    branches: int | None = None,
    tile_rays: int = RAYS_PER_TILE,
    devices=None,
    edge_gradients: bool = False,
    edge_budget: int | None = None,
) -> jax.Array:
    """Render ``scene`` to an ``(height, width, 3)`` linear RGB image.

    Keywords override the scene's own render settings (same names as the scene
    file's ``[render]`` keys). ``key`` (a PRNG key) jitters each sample inside
    its sub-pixel stratum; without it the ``n x n`` grid is regular. The image
    has the scene's float dtype (float32, or float64 for a float64 scene with
    x64 enabled). Row 0 is the top row.

    ``devices``: ``None`` renders on the default device; ``"all"`` or an
    integer shards the image tiles over that many of ``jax.devices()`` with
    ``jax.shard_map`` (same image, gradients summed over devices).
    ``tile_rays``: camera rays per tile (memory of reverse mode scales with it).

    ``edge_gradients=True`` adds the boundary terms of the derivative (moving
    silhouettes, surface crossings and hard-shadow edges; see
    :mod:`raytrax.edges` and ``docs/gradients.md``). The image is the same (it
    is rendered as the ``sqrt(spp) x sqrt(spp)`` grid of samples per pixel, and
    edges are found between neighbouring samples); its gradient converges to
    the derivative of the pixel-integrated image as ``spp`` grows. Needs
    ``key=None``. ``edge_budget``: the most sample pairs with an edge between
    them (default: a quarter of the samples, at least 4096; exceeding it is a runtime error).

    Compiled once per scene structure and option set (``eqx.filter_jit``);
    differentiable with respect to every float leaf of ``scene``.
    """
    over = {
        k: v
        for k, v in dict(
            width=width, height=height, spp=spp, max_depth=max_depth, filter_textures=filter_textures, branches=branches
        ).items()
        if v is not None
    }
    st = dataclasses.replace(scene.settings, **over) if over else scene.settings
    if devices is None:
        n_dev = 1
    elif devices == "all":
        n_dev = jax.device_count()
    elif isinstance(devices, int) and 1 <= devices <= jax.device_count():
        n_dev = devices
    else:
        raise ValueError(f"devices: expected None, 'all' or an integer in [1, {jax.device_count()}], got {devices!r}")
    opts = RenderOptions(settings=st, tile_rays=tile_rays, jitter=key is not None, devices=n_dev)
    if edge_gradients:
        if key is not None:
            raise ValueError(
                "edge_gradients: edges are found on the regular n x n sample grid; pass key=None (no jitter)"
            )
        if edge_budget is not None and (not isinstance(edge_budget, int) or edge_budget < 1):
            raise ValueError(f"edge_budget: expected a positive integer, got {edge_budget!r}")
        return _render_edges_jit(scene, opts, EdgeOptions(math.isqrt(st.spp), edge_budget, st.max_depth + 1))
    return _render_jit(scene, opts, key)
