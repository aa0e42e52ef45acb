"""The stop-gradient sample records: what each camera ray's specular chain meets
(primitive, branch, the first and last occluder towards each light, the hard pattern
cell), level by level."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import textures as tx
from .. import vec as V
from ..camera import rays_through
from ..chunks import equal_chunks, map_chunks
from ..intersect import hit_args, nearest_kind, no_hit, offset_scale
from ..masks import any_true, count_true, true_indices
from ..materials import refracts_dominantly
from ..textures import pattern_cell
from .prims import Prims, kind_ids, specular_step

SUB_MIN = 1024  # the least rays per sub-batch of a records level
RECORD_TILE = 1 << 18  # the most rays recorded at once
TILES_PER_DEVICE = 4  # the fewest tiles per device when the records are split over devices


def search(scene, kinds, off, o, d, tmax=None):
    """Global id (-1: none) and distance of the first primitive along rays ``o, d``
    (closer than ``tmax`` when given)."""
    n = o.shape[1]
    best_id = jnp.full((n,), -1, jnp.int32)
    if not kinds:
        return best_id, jnp.full((n,), jnp.inf, o.dtype)
    which, best_t, ids = nearest_kind(kinds, (o[0], o[1], o[2], d[0], d[1], d[2]))
    hit = jnp.isfinite(best_t)
    for j, k in enumerate(kinds):
        start, _, per = kind_ids(off, k)
        gid = start + per * ids[j]
        if per > 1:  # which face of the primitive (a box's)
            group = scene.prims[k.spec.field]
            gid = gid + k.spec.edge_face(group, ids[j], o, d, jnp.where(hit, best_t, 0.0))
        best_id = jnp.where(hit & (which == j), gid, best_id)
    if tmax is not None:
        best_id = jnp.where(best_t < tmax, best_id, -1)
    return best_id, best_t


class Records(NamedTuple):
    """What the specular chain of each camera ray meets (no gradient), ``D`` levels."""

    hit: jax.Array  # (D, M) primitive at each level; -1 background, -2 the chain has ended
    refr: jax.Array  # (D, M) the chain refracts (else reflects) at that hit
    first: jax.Array  # (D, L, M) first occluder between the hit and each light (-1: none; see object_key)
    last: jax.Array  # (D, L, M) last occluder
    cell: jax.Array  # (D, M) the hard procedural pattern at the hit (0 / 1; see textures.pattern_cell)


def object_key(P: Prims, ns, g):
    """The object of global primitive ids ``g`` (-1 stays -1): the first face of a
    convex solid for each of its faces, else the primitive itself."""
    if not P.solid.shape[0]:  # no convex solid in the scene
        return g
    pi = jnp.clip(g - ns, 0, P.solid.shape[0] - 1)
    solid = (g >= ns) & (P.solid[pi] >= 0)
    return jnp.where(solid, ns + P.solid[pi], g)


def face_group(off, g):
    """The object of global primitive ids ``g`` among the kinds whose faces occlude
    as one (a mesh; ``KindSpec.face_groups``): ``(key, grouped)``, the first face of
    its object for each grouped face (any other id stays as it is), and whether the
    id is such a face. One object for the shadow edges of a mesh, whose faces record
    as occluders one by one. ``off``: :func:`build_prims`' offsets."""
    group = off.get("group")
    if group is None or not np.any(group >= 0):
        return g, jnp.zeros(jnp.shape(g), bool)
    ns = off["ns"]
    gk = jnp.asarray(group)[jnp.clip(g - ns, 0, group.shape[0] - 1)]
    grouped = (g >= ns) & (gk >= 0)
    return jnp.where(grouped, ns + gk, g), grouped


def occluders(scene, kinds, off, P: Prims, p, hit):
    """First and last occluder ``(L, M)`` on the segments from points ``p (3, M)``
    to each light (-1: none, or ``~hit``); a directional light's segment runs to
    beyond every finite primitive."""
    eps = offset_scale(p)

    def one(args):
        Lpos, isd = args
        Lp = Lpos[:, None]
        Lv = Lp - p
        ld = V.vsel(jnp.broadcast_to(isd, p.shape[1:]), V.normalize(jnp.broadcast_to(-Lp, p.shape)), V.normalize(Lv))
        dist = jnp.where(isd, P.far + V.norm(p), V.norm(Lv))
        end = V.vsel(jnp.broadcast_to(isd, p.shape[1:]), p + dist[None] * ld, jnp.broadcast_to(Lp, p.shape))
        # Both ends of the segment in one search (one compiled search, not two).
        tmax = dist - 2 * eps
        both, _ = search(
            scene,
            kinds,
            off,
            jnp.concatenate([p + eps[None] * ld, end], 1),
            jnp.concatenate([ld, -ld], 1),
            jnp.concatenate([tmax, tmax]),
        )
        f, la = both[: p.shape[1]], both[p.shape[1] :]
        return jnp.where(hit, f, -1), jnp.where(hit, la, -1)

    return jax.lax.map(one, (P.light.T, P.ldir))


def hit_cell(scene, kinds, off, gid, o, d, t, mat):
    """The hard pattern colour (0 / 1) at the hits ``gid`` of rays ``o, d`` at distance
    ``t``; all 0 when no material has a checker or stripes."""
    mats = scene.materials
    if tx.CHECKER not in mats.kinds_present and tx.STRIPES not in mats.kinds_present:
        return jnp.zeros(gid.shape, jnp.int32)
    uv = jnp.zeros((2,) + gid.shape, o.dtype)
    for k in kinds:
        start, end, per = kind_ids(off, k)
        sel = (gid >= start) & (gid < end)
        idx = jnp.where(sel, (gid - start) // per, 0)
        _, _, uvk, _ = jax.lax.cond(any_true(sel), k.hit, no_hit, hit_args(k, idx), o, d, jnp.where(sel, t, 0.0))
        uv = jnp.where(sel[None], uvk, uv)
    return jnp.where(gid >= 0, pattern_cell(mats, mat, uv), 0)


def records(scene, kinds, off, P: Prims, xy, width, height, depth, devices: int = 1, compact: bool = False) -> Records:
    """:class:`Records` of the camera rays through image positions ``xy (2, M)``;
    ``scene`` and ``P`` without gradient, ``kinds = prepare(scene)``. More than
    ``RECORD_TILE`` rays are recorded in equal tiles of at most that many
    (``lax.map``), so that memory holds one tile's rays, not every sample's;
    ``devices > 1``: at least :data:`TILES_PER_DEVICE` tiles per device, dealt to
    the devices in turn, so that a costly image region (a glass ball's long
    chains) is shared between them. ``compact``: the fields in the smallest dtypes
    that hold them (:func:`compact_records`; a whole grid's records are large, and
    sharded, every device holds them all); :func:`widen` restores int32."""
    M = xy.shape[1]
    n, c = equal_chunks(M, RECORD_TILE, devices * TILES_PER_DEVICE if devices > 1 else 1)
    ids = P.mat.shape[0]

    def one(x):
        r = _records(scene, kinds, off, P, x, width, height, depth)
        return compact_records(r, ids) if compact else r

    return map_chunks(one, xy, M, n, c, devices=devices, deal=True)


def _id_dtype(ids: int):
    return jnp.int16 if ids < jnp.iinfo(jnp.int16).max else jnp.int32


def compact_bytes(lights: int, ids: int) -> int:
    """Bytes per sample and chain level of :func:`compact_records` (``lights`` lights,
    ``ids`` global primitive ids)."""
    w = jnp.dtype(_id_dtype(ids)).itemsize
    return w * (1 + 2 * lights) + 2  # hit, first and last per light; refr and cell a byte each


def compact_records(r: Records, ids: int) -> Records:
    """Records ``r`` of a scene of ``ids`` global primitive ids with its primitive
    fields (``hit``, ``first``, ``last``) as int16 where ``ids`` fit (else int32) and
    ``cell`` as int8: a third to a half of the int32 records' bytes. Comparing
    compact records with each other is comparing the records."""
    small = _id_dtype(ids)
    return Records(r.hit.astype(small), r.refr, r.first.astype(small), r.last.astype(small), r.cell.astype(jnp.int8))


def widen(x):
    """An integer array of (compact) records as int32; a boolean one as it is."""
    return x if x.dtype == jnp.bool_ else x.astype(jnp.int32)


def _records(scene, kinds, off, P: Prims, xy, width, height, depth) -> Records:
    o, d = rays_through(scene.camera, xy, width, height)
    M = xy.shape[1]
    ns = off["ns"]
    L = scene.n_lights

    def live(o, d, alive):
        gid, t = search(scene, kinds, off, o, d)
        gid = jnp.where(alive, gid, -2)
        hit = gid >= 0
        p = o + jnp.where(hit, t, 0.0)[None] * d
        if L:
            # Occluders as objects: a convex solid is its first face, whichever faces
            # the shadow segment crosses.
            first, last = (object_key(P, ns, x) for x in occluders(scene, kinds, off, P, p, hit))
        else:
            first = last = jnp.zeros((0, o.shape[1]), jnp.int32)
        mat = P.mat[jnp.clip(gid, 0, P.mat.shape[0] - 1)]
        T, R = P.trans[mat], P.refl[mat]
        cont = hit & ((T > 0) | (R > 0))
        o2, d2, refr = specular_step(P, ns, gid, refracts_dominantly(T, R), o, d)
        cell = hit_cell(scene, kinds, off, gid, o, d, jnp.where(hit, t, 0.0), mat)
        return (o2, d2, cont), (gid, cont & refr, first, last, cell)

    def dead(o, d, alive):  # no chain continues: skip the searches
        none = jnp.full((L, M), -1, jnp.int32)
        return (o, d, alive), (
            jnp.full((M,), -2, jnp.int32),
            jnp.zeros((M,), bool),
            none,
            none,
            jnp.zeros((M,), jnp.int32),
        )

    # Per level, the rays whose chain goes on are packed at the front and searched in
    # sub-batches of ``sb``; the sub-batches past the last of them are skipped (most
    # chains end at the first diffuse hit).
    sb = max(1, min(M, max(SUB_MIN, M // 8)))
    nsb = -(-M // sb)

    def level(carry, _):
        o, d, alive = carry
        cnt = count_true(alive)
        order = true_indices(alive, nsb * sb, M)
        init = ((o, d, jnp.zeros_like(alive)), dead(o, d, alive)[1])

        def sub(j, acc):
            pos = j * sb + jnp.arange(sb)
            idx = jnp.minimum(order[pos], M - 1)
            wi = jnp.where(pos < cnt, order[pos], M)  # past the live rays: dropped

            def run(acc):
                (o2, d2, c2), res = live(o[:, idx], d[:, idx], pos < cnt)
                return jax.tree_util.tree_map(lambda a, v: a.at[..., wi].set(v, mode="drop"), acc, ((o2, d2, c2), res))

            return jax.lax.cond(j * sb < cnt, run, lambda acc: acc, acc)

        return jax.lax.fori_loop(0, nsb, sub, init)

    # One compiled level, scanned over the chain. The barrier keeps XLA from unrolling
    # the first level with a constant mask and constant-folding its bookkeeping (a prefix
    # sum over every sample: seconds of compilation per million samples).
    alive0 = jax.lax.optimization_barrier(jnp.ones((M,), bool))
    _, out = jax.lax.scan(level, (o, d, alive0), None, length=depth)
    return Records(*out)


def packed_rows(depth: int, lights: int) -> int:
    """Rows of the array :func:`pack_records` makes of records of ``depth`` levels and
    ``lights`` lights."""
    return depth * (3 + 2 * lights)


def pack_records(r: Records):
    """The fields of records ``(.., M)`` as one ``(D (3 + 2 L), M)`` int32 array (hit,
    refr, cell, then first and last), so that they are gathered, compared and written
    as one array; :func:`unpack_records` inverts it."""
    D, L, M = r.first.shape
    return jnp.concatenate(
        [r.hit, r.refr.astype(jnp.int32), r.cell, r.first.reshape(D * L, M), r.last.reshape(D * L, M)]
    )


def unpack_records(a, depth: int, lights: int) -> Records:
    """The :class:`Records` of ``depth`` levels and ``lights`` lights packed in ``a`` by
    :func:`pack_records`."""
    D, L, M = depth, lights, a.shape[1]
    if a.shape[0] != packed_rows(D, L):
        raise ValueError(f"unpack_records: {a.shape[0]} rows, expected {packed_rows(D, L)} for depth {D}, {L} lights")
    return Records(
        a[:D],
        a[D : 2 * D] != 0,
        a[3 * D : 3 * D + D * L].reshape(D, L, M),
        a[3 * D + D * L :].reshape(D, L, M),
        a[2 * D : 3 * D],
    )
