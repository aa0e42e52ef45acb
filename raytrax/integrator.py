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
import math
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from . import _vec as V
from . import textures as tx
from .camera import primary_rays
from .intersect import closest_hit, occluder_counts, prepare
from .materials import fresnel_dielectric, refract
from .scene import Scene, Settings

RAYS_PER_TILE = 16384
SUBTILE = 4096
EPS_REL = 1e-4


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """Static options of one compiled render (see :class:`~raytrax.scene.Settings`)."""

    settings: Settings
    tile_rays: int = RAYS_PER_TILE
    subtile: int = SUBTILE
    jitter: bool = False
    devices: int = 1


def _gather_rows(table, idx):
    """``table (M, k)`` rows at ``idx (n,)`` as ``(k, n)``."""
    return table[idx].T


def _surface_color(mats, mat, uv, rate, width, filtered):
    base = _gather_rows(mats.color, mat)
    kinds = mats.kinds_present
    if not kinds:
        return base
    k = mats.tex_kind[mat]
    scale = mats.tex_scale[mat]
    wuv = rate * width[None]
    frac = jnp.zeros_like(base[0])
    if tx.CHECKER in kinds:
        frac = jnp.where(k == tx.CHECKER, tx.checker(uv, wuv, scale, filtered), frac)
    if tx.STRIPES in kinds:
        dirn = _gather_rows(mats.tex_direction, mat)
        frac = jnp.where(k == tx.STRIPES, tx.stripes(uv, wuv, scale, dirn, filtered), frac)
    c2 = _gather_rows(mats.tex_color2, mat)
    color = base + (c2 - base) * frac[None]
    if tx.IMAGE in kinds:
        img_id = mats.tex_image[mat]
        for j, img in enumerate(mats.images):
            sel = (k == tx.IMAGE) & (img_id == j)
            color = jnp.where(sel[None], base * tx.bilinear(img, uv), color)
    return color


def _shade(scene: Scene, kinds, o, d, w, cw, spread, opts: RenderOptions, last: bool):
    """Intersect and shade rays ``o, d (3, n)`` with throughput ``w (3, n)``.

    Returns the radiance they contribute ``(3, n)`` and their reflected and
    refracted children (origin, direction, throughput) plus the cone width at
    the hit (for the children's texture footprints).
    """
    st = opts.settings
    mats = scene.materials
    env = scene.environment
    dt = o.dtype
    hit = closest_hit(kinds, o, d)
    valid = hit.valid
    t = hit.t
    p = o + t[None] * d
    mat = hit.material

    cos_d = V.dot(d, hit.normal)
    front = cos_d < 0
    n_s = V.vsel(front, hit.normal, -hit.normal)  # faces the incoming ray
    cos_i = jnp.abs(cos_d)
    eps = EPS_REL * (1.0 + jnp.max(jnp.abs(p), 0))
    p_out = p + eps[None] * n_s
    p_in = p - eps[None] * n_s

    cw_hit = cw + spread * t
    footprint = V.safe_div(cw_hit, jnp.maximum(cos_i, 0.25))
    color = _surface_color(mats, mat, hit.uv, hit.rate, footprint, st.filter_textures)
    T = mats.transparency[mat]
    R = _gather_rows(mats.reflectivity, mat)
    ior = mats.ior[mat]

    # --- direct light -----------------------------------------------------
    L = scene.lights.position.shape[0]
    n = o.shape[1]
    local = jnp.zeros_like(o)
    if L:
        lp = scene.lights.position.T[:, :, None]  # (3, L, 1)
        Lv = lp - p_out[:, None, :]  # (3, L, n)
        dist = V.norm(Lv)  # (L, n)
        ldir = V.normalize(Lv)
        cosl = V.dot(n_s[:, None, :], ldir)  # (L, n)
        lit = (cosl > 0) & valid[None]
        counts = occluder_counts(kinds, jnp.broadcast_to(p_out[:, None, :], Lv.shape).reshape(3, L * n),
                                 ldir.reshape(3, L * n), (dist * (1.0 - 1e-6)).reshape(L * n),
                                 mats.color.shape[0]).reshape(L, n, -1)
        I = scene.lights.intensity.T[:, :, None]  # (3, L, 1)
        if st.shading == "classic":
            has = counts > 0
            tr = mats.transparency[None, None, :]
            base = jnp.where(has, tr, 1.0)
            trans = jnp.prod(jnp.where(has, base ** jnp.where(has, counts, 1.0), 1.0), -1)  # (L, n)
            diff = (mats.diffuse[mat] * (1.0 - T))[None] * jnp.maximum(cosl, 0.0)
            rv = V.dot(V.reflect(-ldir, n_s[:, None, :]), -d[:, None, :])
            spec = mats.specular[mat][None] * V.safe_pow(rv, mats.shininess[mat][None])
            spec = jnp.where(lit, spec, 0.0)
            per = I * (trans * jnp.where(lit, 1.0, 0.0))[None] * (diff[None] * color[:, None, :] + spec[None])
            local = jnp.sum(per, 1)
        else:
            vis = (jnp.sum(counts, -1) == 0) & lit
            E = jnp.sum(I * jnp.where(vis, jnp.maximum(cosl, 0.0) * V.safe_div(1.0, dist * dist), 0.0)[None], 1)
            local = ((1.0 - T)[None] * (1.0 - R) * color * (1.0 / math.pi)) * E
    if st.shading == "classic":
        local = local + env.ambient[:, None] * (mats.ambient[mat] * (1.0 - T))[None] * color

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
    bg = env.background[:, None]
    contrib = jnp.where(vm, w * local, w * bg)
    # After the last allowed specular interaction, specular children see the background.
    contrib = contrib + jnp.where(last, 1.0, 0.0).astype(dt) * (wr + wt) * bg
    return contrib, (p_out, rdir, wr, p_in, tdir, wt, cw_hit)


def _compact_map(fn, args, active, sub):
    """Apply ``fn`` to the rays of ``args`` (arrays with the ray axis last) but skip
    sub-tiles of ``sub`` rays that hold no ``active`` ray: live rays are moved to
    the front first. Returns ``fn``'s outputs in the original ray order."""
    n = active.shape[0]
    shapes = jax.eval_shape(fn, *args)
    if n <= sub:
        zeros = lambda *a: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return jax.lax.cond(jnp.any(active), fn, zeros, *args)
    S = math.ceil(n / sub)
    pad = S * sub - n
    order = jnp.argsort(jnp.logical_not(active), stable=True)
    order = jnp.concatenate([order, jnp.full((pad,), n - 1, order.dtype)]) if pad else order
    act = jnp.concatenate([active, jnp.zeros((pad,), bool)]) if pad else active
    act = act[order] if not pad else jnp.concatenate([active[order[:n]], jnp.zeros((pad,), bool)])

    def split(a):
        a = jnp.take(a, order, axis=-1)
        a = a.reshape(a.shape[:-1] + (S, sub))
        return jnp.moveaxis(a, -2, 0)

    sub_args = jax.tree_util.tree_map(split, args)
    sub_act = act.reshape(S, sub)
    sub_shapes = jax.eval_shape(fn, *jax.tree_util.tree_map(lambda a: a[0], sub_args))

    def zeros(*a):
        return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), sub_shapes)

    def one(x):
        a, live = x
        return jax.lax.cond(jnp.any(live), fn, zeros, *a)

    outs = jax.lax.map(one, (sub_args, sub_act))
    inv = jnp.argsort(order[:n]) if not pad else jnp.argsort(order[:n])

    def merge(a):
        a = jnp.moveaxis(a, 0, -2)
        a = a.reshape(a.shape[:-2] + (S * sub,))[..., :n]
        return jnp.take(a, inv, axis=-1)

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
    score = jax.lax.stop_gradient(jnp.max(cwt, 0)).T  # (n, 2B)
    _, top = jax.lax.top_k(score, B)  # (n, B)
    top = top.T  # (B, n)

    def g(a):
        return jnp.take_along_axis(a, jnp.broadcast_to(top[None], (a.shape[0],) + top.shape), 1).reshape(a.shape[0], -1)

    return g(co), g(cd), g(cwt), jnp.take_along_axis(ccw, top, 0).reshape(-1)


def _trace(scene: Scene, kinds, o, d, spread, opts: RenderOptions):
    """Radiance ``(3, n)`` of camera rays ``o, d (3, n)``.

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

    def body(carry, depth):
        (o_, d_, w_, cw_), radiance = carry
        last = depth == st.max_depth

        def fn(a, b, c, e):
            return _shade(scene, kinds, a, b, c, e, spread, opts, last)

        active = jnp.any(w_ > 0, 0)
        contrib, kids = _compact_map(fn, (o_, d_, w_, cw_), active, opts.subtile)
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

        mesh = jax.make_mesh((n_dev,), ("tiles",), devices=jax.devices()[:n_dev],
                             axis_types=(jax.sharding.AxisType.Auto,))
        run = jax.shard_map(run, mesh=mesh, in_specs=(Spec(), Spec("tiles"), Spec("tiles"), Spec()),
                            out_specs=Spec("tiles"), check_vma=False)
    out = run(scene, pix, ids, key)
    return out.reshape(n_tiles * tile, 3)[:P].reshape(H, W, 3)


_render_jit = eqx.filter_jit(_render)


def render(scene: Scene, *, width: Optional[int] = None, height: Optional[int] = None,
           spp: Optional[int] = None, max_depth: Optional[int] = None, key=None,
           filter_textures: Optional[bool] = None, branches: Optional[int] = None,
           tile_rays: int = RAYS_PER_TILE, devices=None) -> jax.Array:
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

    Compiled once per scene structure and option set (``eqx.filter_jit``);
    differentiable with respect to every float leaf of ``scene``.
    """
    over = {k: v for k, v in dict(width=width, height=height, spp=spp, max_depth=max_depth,
                                   filter_textures=filter_textures, branches=branches).items() if v is not None}
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
    return _render_jit(scene, opts, key)
