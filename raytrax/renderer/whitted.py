"""The Whitted integrator: a fixed-depth unroll of reflection and refraction.

The shading itself (the classic and physical models, Fresnel, the children's
weights) is :mod:`raytrax.materials`'; light geometry is :mod:`raytrax.lights`'.

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

import functools

import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from .. import vec as V
from ..intersect import closest_hit, occluder_counts, offset_scale
from ..lights import LIGHTS
from ..materials import SHADING_MODELS, facing, interface, material_rows, refract
from ..scene import Scene
from ..textures import footprint_widths, hit_with_uv_shifts, needs_footprint, surface_color
from .compaction import compact_map
from .options import RenderOptions

# Reverse mode keeps only the inputs of each sub-tile's shading (and the values
# named here) and recomputes the rest: storing every intermediate of every
# bounce costs more in memory traffic than recomputing it.
SHADE_POLICY = jax.checkpoint_policies.save_only_these_names("raytrax_search", "raytrax_shadow")


def shade(scene: Scene, kinds, o, d, w, cw, spread, opts: RenderOptions, last: bool, sel=None):
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
    # The hit and (filtered procedural textures) how its uv moves as the ray shifts: the footprints' ray differentials.
    hit, uv_shifts = hit_with_uv_shifts(
        lambda o_: closest_hit(kinds, o_, d), o, d, needs_footprint(mats, st.filter_textures)
    )
    valid = hit.valid
    t = hit.t
    p = o + t[None] * d
    mat = hit.material

    model = SHADING_MODELS[st.shading]
    face = facing(d, hit.normal)
    n_s = face.n_s  # faces the incoming ray
    eps = offset_scale(p)
    p_out = p + eps[None] * n_s
    p_in = p - eps[None] * n_s

    cw_hit = cw + spread * t
    # Anisotropic box-filter widths in uv: the cone's ellipse on the surface (long along the view at grazing angles).
    wuv = jnp.zeros_like(hit.uv) if uv_shifts is None else footprint_widths(uv_shifts, d, hit.normal, cw_hit)
    names = ("color", "transparency", "reflectivity", "ior") + model.fields
    if mats.kinds_present:
        names += ("tex_scale", "tex_color2", "tex_direction")
    rows = material_rows(mats, mat, names)
    color = surface_color(mats, mat, hit.uv, wuv, st.filter_textures, rows)

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

        def shadow(p0, dirn, tmax):
            return model.shadow(occluder_counts(kinds, p0, dirn, tmax, M))  # from (n, M) counts

        def no_shadow(p0, dirn, tmax):
            return model.no_shadow(n, M, dt)

        acc = jnp.zeros_like(o)
        for l in range(L):
            # Shadow rays of one light, under a cond: skipped when no ray faces the
            # light, and the result is materialised once (XLA:CPU would otherwise
            # fuse the occlusion tests into each colour channel's shading).
            sh = jax.lax.cond(jnp.any(lit[l]), shadow, no_shadow, p_out, ldir[l], dist[l] * (1.0 - 1e-6))
            sh = checkpoint_name(sh, "raytrax_shadow")
            smp = samples[l]
            acc = model.add_light(
                acc, rows, color, mats.transparency, sh, smp.strength, smp.falloff, cosl[l], ldir[l], n_s, d, lit[l]
            )
        local = model.finish(acc, rows, color)
    amb, bg = env.ambient[:, None], env.background[:, None]
    if sel is not None:  # lit[l] above leaves out the lights a ray does not carry
        env_on = carries(L).astype(dt)[None]  # pyright: ignore
        amb, bg = amb * env_on, bg * env_on
    local = model.ambient(local, amb, rows, color)

    # --- specular children -------------------------------------------------
    itf = interface(face, rows["ior"])
    tdir = refract(d, n_s, itf.eta, itf.cos_t)
    rdir = V.reflect(d, n_s)
    wr, wt = model.specular_weights(rows, itf)
    vm = valid[None]
    wr = jnp.where(vm, w * wr, 0.0)
    wt = jnp.where(vm, w * wt, 0.0)
    contrib = jnp.where(vm, w * local, w * bg)
    # After the last allowed specular interaction, specular children see the background.
    contrib = contrib + jnp.where(last, 1.0, 0.0).astype(dt) * (wr + wt) * bg
    return contrib, (p_out, rdir, wr, p_in, tdir, wt, cw_hit)


def top_branches(kids, B, n):
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


def trace(scene: Scene, kinds, o, d, spread, opts: RenderOptions, sel=None):
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

        @functools.partial(jax.checkpoint, policy=SHADE_POLICY)
        def fn(a, b, c, e, *f):
            return shade(scene, kinds, a, b, c, e, spread, opts, last, *f)

        active = jnp.any(w_ > 0, 0)
        args = (o_, d_, w_, cw_) + (() if sel is None else (sel_b,))
        contrib, kids = compact_map(fn, args, active, opts.subtile)
        radiance = radiance + contrib.reshape(3, B, n).sum(1)
        return (top_branches(kids, B, n), radiance), None

    (_, radiance), _ = jax.lax.scan(body, (state, jnp.zeros_like(o)), jnp.arange(st.max_depth + 1))
    return radiance
