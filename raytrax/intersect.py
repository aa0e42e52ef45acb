"""Closest-hit and shadow queries over all primitive kinds of a scene.

See :mod:`raytrax.shapes` for the two-pass design: a stop-gradient search over
blocks of primitives (struct-of-arrays, ``(rays, block)`` tiles, a
``lax.scan`` over blocks when a kind has more than :data:`BLOCK` primitives),
then a differentiable recomputation against the one primitive each ray hit.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from . import shapes as S

BLOCK = 32
INF = float("inf")


class Kind(NamedTuple):
    name: str
    soa: dict  # stop-gradient (N,) component arrays
    material: jax.Array  # (N,) int
    tfun: Callable
    hit: Callable  # (idx (n,), o, d, t0) -> (t, n, uv, rate)
    crossings: Callable | None = None  # (ray, P, tmax) -> (n, B) surface crossings; None: one per hit


class Hit(NamedTuple):
    valid: jax.Array  # (n,) bool
    t: jax.Array  # (n,)  0 where not valid
    normal: jax.Array  # (3, n) outward geometric normal
    uv: jax.Array  # (2, n)
    rate: jax.Array  # (2, n) d(uv)/d(world length)
    material: jax.Array  # (n,) int, 0 where not valid


def _ng(tree):
    return jax.tree_util.tree_map(jax.lax.stop_gradient, tree)


def prepare(scene) -> list[Kind]:
    """The kinds present in ``scene`` with their search arrays and hit functions.
    Called inside the traced render: triangle-based kinds (triangles,
    tetrahedra, meshes) are merged into one triangle list here."""
    kinds = []
    sp = scene.spheres
    if sp.center.shape[0]:
        kinds.append(Kind("sphere", _ng(S.sphere_soa(sp)), sp.material, S.sphere_t,
                          lambda i, o, d, t0: S.sphere_hit(sp.center[i].T, sp.radius[i], o, d, t0),
                          S.sphere_crossings))
    pl = scene.planes
    if pl.point.shape[0]:
        kinds.append(Kind("plane", _ng(S.plane_soa(pl)), pl.material, S.plane_t,
                          lambda i, o, d, t0: S.plane_hit(pl.point[i].T, pl.normal[i].T, o, d, t0)))
    qd = scene.quads
    if qd.corners.shape[0]:
        def qhit(i, o, d, t0):
            c = qd.corners[i]
            return S.quad_hit(c[:, 0].T, c[:, 1].T, c[:, 2].T, c[:, 3].T, o, d, t0)

        kinds.append(Kind("quad", _ng(S.quad_soa(qd)), qd.material, S.quad_t, qhit))
    tris, mats = [], []
    if scene.triangles.vertices.shape[0]:
        tris.append(scene.triangles.vertices)
        mats.append(scene.triangles.material)
    if scene.tetrahedra.center.shape[0]:
        t, m = scene.tetrahedra.triangles()
        tris.append(t)
        mats.append(m)
    for mesh in scene.meshes:
        t, m = mesh.triangles()
        tris.append(t)
        mats.append(m)
    if tris:
        T = jnp.concatenate(tris, 0)
        M = jnp.concatenate(mats, 0)

        def thit(i, o, d, t0):
            v = T[i]
            return S.tri_hit(v[:, 0].T, v[:, 1].T, v[:, 2].T, o, d, t0)

        kinds.append(Kind("triangle", _ng(S.tri_soa(T[:, 0], T[:, 1], T[:, 2])), M, S.tri_t, thit))
    bx = scene.boxes
    if bx.lo.shape[0]:
        Rb = S.euler_matrix(bx.rotation).reshape(-1, 9)  # per box, not per ray
        cb = 0.5 * (bx.lo + bx.hi)
        hb = 0.5 * jnp.abs(bx.hi - bx.lo)

        def bhit(i, o, d, t0):
            R = Rb[i].T.reshape(3, 3, -1)
            c = cb[i].T
            h = hb[i].T
            return S.box_hit(c, [h[0], h[1], h[2]], R, o, d, t0)

        kinds.append(Kind("box", _ng(S.box_soa(bx)), bx.material, S.box_t, bhit, S.box_crossings))
    return kinds


def _blocks(soa, extra=None):
    """Pad (N,) arrays to whole blocks and reshape to (nb, BLOCK); plus a validity mask."""
    N = next(iter(soa.values())).shape[0]
    nb = math.ceil(N / BLOCK)
    pad = nb * BLOCK - N
    out = {k: jnp.pad(v, (0, pad), mode="edge").reshape(nb, BLOCK) for k, v in soa.items()}
    valid = (jnp.arange(nb * BLOCK) < N).reshape(nb, BLOCK)
    base = jnp.arange(nb, dtype=jnp.int32) * BLOCK
    return out, valid, base


def _closest_kind(k: Kind, ray, tmin):
    """Per ray: nearest distance (inf on a miss) and primitive index of one kind."""
    ray2 = tuple(r[:, None] for r in ray)
    N = k.material.shape[0]
    if N <= BLOCK:
        T = k.tfun(ray2, {n: v[None, :] for n, v in k.soa.items()}, tmin)
        return jnp.min(T, 1), jnp.argmin(T, 1).astype(jnp.int32)
    P, valid, base = _blocks(k.soa)
    n = ray[0].shape[0]

    def body(carry, blk):
        tb, ib = carry
        Pb, vb, b0 = blk
        T = k.tfun(ray2, {name: v[None, :] for name, v in Pb.items()}, tmin)
        T = jnp.where(vb[None, :], T, INF)
        tj = jnp.min(T, 1)
        better = tj < tb
        return (jnp.where(better, tj, tb), jnp.where(better, b0 + jnp.argmin(T, 1).astype(jnp.int32), ib)), None

    init = (jnp.full((n,), INF, ray[0].dtype), jnp.zeros((n,), jnp.int32))
    (tb, ib), _ = jax.lax.scan(body, init, (P, valid, base))
    return tb, ib


def closest_hit(kinds: list[Kind], o, d) -> Hit:
    """Nearest hit of rays ``o, d (3, n)`` (``d`` unit) over all kinds; differentiable
    in the hit quantities (see module docstring)."""
    n = o.shape[1]
    if not kinds:
        z = jnp.zeros((n,), o.dtype)
        return Hit(jnp.zeros((n,), bool), z, jnp.zeros_like(o), jnp.zeros((2, n), o.dtype),
                   jnp.zeros((2, n), o.dtype), jnp.zeros((n,), jnp.int32))
    ray = tuple(jax.lax.stop_gradient(x) for x in (o[0], o[1], o[2], d[0], d[1], d[2]))
    ts, ids = zip(*[_closest_kind(k, ray, 0.0) for k in kinds])
    ts = jnp.stack(ts)
    which = jnp.argmin(ts, 0)
    t0 = jnp.min(ts, 0)
    valid = t0 < INF
    t = jnp.zeros((n,), o.dtype)
    nrm = jnp.zeros_like(o)
    uv = jnp.zeros((2, n), o.dtype)
    rate = jnp.zeros((2, n), o.dtype)
    mat = jnp.zeros((n,), jnp.int32)
    for j, k in enumerate(kinds):
        sel = valid & (which == j)
        idx = jnp.where(sel, ids[j], 0)
        tk, nk, uvk, rk = k.hit(idx, o, d, jnp.where(sel, t0, 0.0))
        t = jnp.where(sel, tk, t)
        nrm = jnp.where(sel[None], nk, nrm)
        uv = jnp.where(sel[None], uvk, uv)
        rate = jnp.where(sel[None], rk, rate)
        mat = jnp.where(sel, k.material[idx], mat)
    return Hit(valid, t, nrm, uv, rate, mat)


def _crossings(k: Kind, ray2, P, tmax):
    if k.crossings is not None:
        return k.crossings(ray2, P, tmax)
    return (k.tfun(ray2, P, 0.0) < tmax).astype(ray2[0].dtype)


def occluder_counts(kinds: list[Kind], o, d, tmax, n_materials: int):
    """For shadow rays ``o, d (3, n)`` and segment lengths ``tmax (n,)``: how many
    surfaces of each material the open segment ``(0, tmax)`` crosses, ``(n, M)``
    float (no gradient: visibility is piecewise constant)."""
    n = o.shape[1]
    ray = tuple(jax.lax.stop_gradient(x) for x in (o[0], o[1], o[2], d[0], d[1], d[2]))
    tmax = jax.lax.stop_gradient(tmax)[:, None]
    ray2 = tuple(r[:, None] for r in ray)
    counts = jnp.zeros((n, n_materials), o.dtype)
    for k in kinds:
        onehot = jax.nn.one_hot(k.material, n_materials, dtype=o.dtype)
        N = k.material.shape[0]
        if N <= BLOCK:
            hit = _crossings(k, ray2, {nm: v[None, :] for nm, v in k.soa.items()}, tmax)
            counts = counts + hit @ onehot
        else:
            P, valid, _ = _blocks(k.soa)
            nb = valid.shape[0]
            pad = nb * BLOCK - N
            oh = jnp.pad(onehot, ((0, pad), (0, 0))).reshape(nb, BLOCK, n_materials)

            def body(c, blk):
                Pb, vb, ohb = blk
                hit = _crossings(k, ray2, {nm: v[None, :] for nm, v in Pb.items()}, tmax)
                hit = jnp.where(vb[None, :], hit, 0.0)
                return c + hit @ ohb, None

            counts, _ = jax.lax.scan(body, counts, (P, valid, oh))
    return jax.lax.stop_gradient(counts)
