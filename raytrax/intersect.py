"""Closest-hit and shadow queries over all primitive kinds of a scene.

See :mod:`raytrax.shapes` for the two-pass design: a stop-gradient search over
blocks of primitives (struct-of-arrays, ``(rays, block)`` tiles, a
``lax.scan`` over blocks when a kind has more than :data:`BLOCK` primitives),
then a differentiable recomputation against the one primitive each ray hit.
The merged triangle list of a scene with a BVH (``scene.bvh``, more than
``bvh.MIN_TRIANGLES`` triangles) is searched through it instead (:mod:`raytrax.bvh`),
with the same results. A kind of more than :data:`CULL_MIN` spheres, boxes, quads or
disks is searched in groups of :data:`GROUP` primitives, compact in space (a Morton
order of their bounding boxes' centres, computed in the traced function, so that it
follows primitives that move during a fit): each batch of rays tests every group's
box first and skips the groups none of its rays meets (past :data:`SUPER_MIN` groups,
runs of :data:`SUPER` groups are tested and skipped the same way first). Same primitive and, on ties,
the same lower index as the brute-force search (distances may differ by rounding,
about 1e-5 relative for spheres; the differentiable recomputation is the same).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from . import bvh as B
from . import shapes as S
from . import vec as V
from .branching import any_in_batch
from .shapes.triangles import tri_crossings, tri_hit, tri_soa, tri_t
from .tracing import KEPT, kept_rows

BLOCK = 128
# Kinds of more than CULL_MIN primitives with world bounds (spheres, boxes, quads, disks)
# are searched in groups of GROUP, compact in space; a batch of rays skips every group
# whose bounding box none of its rays meets (crossover: benchmarks/README.md).
CULL_MIN = 64
GROUP = 16
# Kinds of more than SUPER_MIN groups are culled on two levels: runs of SUPER consecutive
# groups first, then the groups of the runs that a batch meets (benchmarks/README.md).
SUPER_MIN = 64
SUPER = 16
# Shadow rays test kinds of at most this many primitives one primitive at a time
# (unrolled rows of rays, or'ed) rather than as a (rays, N) tile reduced over its
# short minor axis, which XLA:CPU runs slowly; the compile cost grows with the count.
UNROLL_SHADOW = 16
EPS_REL = 1e-4  # offset of spawned rays from their surface, relative to 1 + max |coordinate|


def offset_scale(p):
    """How far rays spawned at points ``p (3, n)`` start from their surface (shadow
    rays, reflected and refracted children): ``EPS_REL (1 + max_i |p_i|)``, ``(n,)``."""
    return EPS_REL * (1.0 + jnp.maximum(jnp.maximum(jnp.abs(p[0]), jnp.abs(p[1])), jnp.abs(p[2])))


INF = float("inf")
# Crossing counts are summed by matrix products: at full precision, so that no
# accelerator rounds them through a lower-precision format.
_EXACT = jax.lax.Precision.HIGHEST


class Kind(NamedTuple):
    name: str  # the kind's name; "triangle" for the merged triangle list
    soa: dict  # stop-gradient (N,) component arrays
    material: jax.Array  # (N,) int
    tfun: Callable
    hit: Callable  # (idx (n,), o, d, t0) -> (t, n, uv, rate); with rows: (rows gathered for the rays, o, d, t0)
    crossings: Callable | None = None  # (ray, P, tmax) -> (n, B) surface crossings; None: one per hit
    accel: B.Accel | None = None  # triangle BVH search arrays (see raytrax.bvh); None: brute force
    spec: S.KindSpec | None = None  # the registry entry; None for the merged triangle list
    curvature: jax.Array | None = None  # (N,) 1 / radius (differentiable); None: flat
    groups: Groups | None = None  # spatial groups of the search (see _groups); None: no culling
    # Per-primitive arrays (leading axis N) that hit reads; hit also takes them gathered
    # for the rays' primitives, which hit_args does for large tables (see there).
    rows: Any = None


class Hit(NamedTuple):
    valid: jax.Array  # (n,) bool
    t: jax.Array  # (n,)  0 where not valid
    normal: jax.Array  # (3, n) outward geometric normal
    uv: jax.Array  # (2, n)
    rate: jax.Array  # (2, n) d(uv)/d(world length)
    material: jax.Array  # (n,) int, 0 where not valid
    curvature: jax.Array  # (n,) 1 / radius of the surface hit (0: flat or not valid)


def _ng(tree):
    return jax.tree_util.tree_map(jax.lax.stop_gradient, tree)


def prepare(scene, cull: bool = True) -> list[Kind]:
    """The kinds present in ``scene`` with their search arrays and hit functions, in
    registry order (:data:`raytrax.shapes.KINDS`). Called inside the traced render:
    triangle-family kinds (triangles, tetrahedra, meshes) are merged into one
    triangle list, searched at the place of the first of them. ``cull=False``: no
    kind is searched in culled groups (brute force, as a reference)."""
    kinds = []
    merged = False
    for spec in S.KINDS:
        group = getattr(scene, spec.field)
        if spec.triangle_family:
            if not merged:
                merged = True
                tri = _triangle_kind(scene)
                if tri is not None:
                    kinds.append(tri)
            continue
        if spec.count(group):
            part = spec.search(group)
            assert part is not None, f"kind {spec.name!r} has no search"
            kinds.append(
                Kind(
                    spec.name,
                    _ng(part.soa),
                    part.material,
                    part.tfun,
                    part.hit,
                    part.crossings,
                    spec=spec,
                    curvature=part.curvature,
                    groups=_groups(_ng(part.soa), _ng(part.bounds)) if cull and _cull(part) else None,
                )
            )
    return kinds


def _triangle_kind(scene) -> Kind | None:
    T, M = scene.merged_triangles()
    if not T.shape[0]:
        return None

    def thit(a, o, d, t0):  # a: the rays' triangle indices (n,), or their triangles (n, 3, 3) (hit_args)
        v = T[a] if a.ndim == 1 else a
        return tri_hit(v[:, 0].T, v[:, 1].T, v[:, 2].T, o, d, t0)

    soa = _ng(tri_soa(T[:, 0], T[:, 1], T[:, 2]))
    bvh = getattr(scene, "bvh", None)
    acc = None
    if bvh is not None and T.shape[0] > B.MIN_TRIANGLES and bvh.n_triangles == T.shape[0]:
        acc = B.prepare(bvh, jax.lax.stop_gradient(T))
    return Kind("triangle", soa, M, tri_t, thit, tri_crossings, acc, rows=T)


def _kept(k: Kind, rows, n: int):
    """``rows`` gathered from ``k``'s tables for a batch of ``n`` rays
    (:func:`raytrax.tracing.kept_rows`)."""
    return kept_rows(rows, k.material.shape[0], n)


def hit_args(k: Kind, idx):
    """The first argument of ``k.hit`` for the rays' primitives ``idx (n,)``: ``idx``
    itself, or, where the kind has ``rows`` and more primitives than there are rays,
    its rows gathered at ``idx`` (see :func:`_kept`)."""
    if k.rows is None or k.material.shape[0] <= idx.shape[0]:
        return idx
    return _kept(k, jax.tree_util.tree_map(lambda a: a[idx], k.rows), idx.shape[0])


def _blocks(soa, extra=None):
    """Pad (N,) arrays to whole blocks and reshape to (nb, BLOCK); plus a validity mask."""
    N = next(iter(soa.values())).shape[0]
    nb = math.ceil(N / BLOCK)
    pad = nb * BLOCK - N
    out = {k: jnp.pad(v, (0, pad), mode="edge").reshape(nb, BLOCK) for k, v in soa.items()}
    valid = (jnp.arange(nb * BLOCK) < N).reshape(nb, BLOCK)
    base = jnp.arange(nb, dtype=jnp.int32) * BLOCK
    return out, valid, base


def _prim(soa, j: int):
    """Primitive ``j``'s search parameters as scalars."""
    return {nm: v[j] for nm, v in soa.items()}


class Groups(NamedTuple):
    """A kind's primitives in groups of :data:`GROUP`, compact in space (Morton order of
    their box centres; by index within a group), for the culled search: the search
    arrays ``P (ng, fields, GROUP)`` (the fields in the order of the kind's ``soa``),
    ``valid (ng, GROUP)`` (False: padding), the
    primitive index of each slot ``members (ng, GROUP)`` and each group's world box
    ``box`` (``(ng,)`` arrays ``lox ... hiz`` as :func:`raytrax.bvh.slab` takes them;
    slightly enlarged, so that rounding never drops a group). With more than
    :data:`SUPER_MIN` groups, every array has a leading axis of runs of :data:`SUPER`
    consecutive groups (``P (ns, SUPER, fields, GROUP)``, ``box`` of ``(ns, SUPER)``
    arrays, the last run padded with empty groups) and ``top`` holds each run's box
    (``(ns,)`` arrays); else ``top`` is None."""

    P: jax.Array
    valid: jax.Array
    members: jax.Array
    box: dict
    top: dict | None = None


def _cull(part) -> bool:
    return part.bounds is not None and part.material.shape[0] > CULL_MIN


def _groups(soa, bounds) -> Groups:
    N = bounds.shape[2]
    ng = math.ceil(N / GROUP)
    two = ng > SUPER_MIN
    if two:
        ng = math.ceil(ng / SUPER) * SUPER
    pad = ng * GROUP - N
    perm = jnp.pad(_spatial_order(bounds), (0, pad), mode="edge")
    P = jnp.stack([v[perm].reshape(ng, GROUP) for v in soa.values()], 1)  # (ng, fields, GROUP), soa's order
    valid = (jnp.arange(ng * GROUP) < N).reshape(ng, GROUP)
    bd = bounds[:, :, perm].reshape(2, 3, ng, GROUP)
    lo, hi = jnp.min(bd[0], -1), jnp.max(bd[1], -1)  # (3, ng)
    scale = 1e-5 * (1.0 + jnp.max(jnp.abs(bd)))
    box = {f"lo{c}": lo[i] - scale for i, c in enumerate("xyz")} | {
        f"hi{c}": hi[i] + scale for i, c in enumerate("xyz")
    }
    members = perm.reshape(ng, GROUP)
    if not two:
        return Groups(P, valid, members, box)
    ns = ng // SUPER

    def runs(x):
        return x.reshape((ns, SUPER) + x.shape[1:])

    box = {c: runs(v) for c, v in box.items()}
    top = B.merge_boxes(box)
    return Groups(runs(P), runs(valid), runs(members), box, top)


def _over_groups(g: Groups, ray2, meets, step, carry, extra=None):
    """``carry`` after ``step(carry, P, valid, members, extra)`` for every group
    (its rows of ``g``'s arrays and of ``extra``, an array with the groups' leading axes,
    or None) that some ray of ``ray2`` meets, in group order: a ``lax.scan`` over the
    groups, each step under a ``lax.cond`` on whether any ray meets its box (with two
    levels, a scan over the runs of groups first, skipping the runs none meets).
    ``meets(tn, tf) -> (n, m)``: which rays meet boxes, from their entry and exit distances."""

    def level(carry, P, valid, members, box, extra):
        tn, tf = B.slab(ray2, {c: v[None, :] for c, v in box.items()})
        m = meets(tn, tf).T  # (groups, n)

        def body(c, blk):
            *rows, mb = blk
            return jax.lax.cond(any_in_batch(mb), lambda c: step(c, *rows), lambda c: c, c), None

        return jax.lax.scan(body, carry, (P, valid, members, extra, m))[0]

    if g.top is None:
        return level(carry, g.P, g.valid, g.members, g.box, extra)
    tn, tf = B.slab(ray2, {c: v[None, :] for c, v in g.top.items()})
    m2 = meets(tn, tf).T  # (runs, n)

    def outer(c, blk):
        *rows, mb = blk
        return jax.lax.cond(any_in_batch(mb), lambda c: level(c, *rows), lambda c: c, c), None

    return jax.lax.scan(outer, carry, (g.P, g.valid, g.members, g.box, extra, m2))[0]


def _fields(k: Kind, Pb):
    """One group's search arrays ``Pb (fields, GROUP)`` as the kind's ``soa`` dict of
    ``(1, GROUP)`` rows, as its distance and crossing kernels take them."""
    return {name: Pb[f][None, :] for f, name in enumerate(k.soa)}


def _spread_bits(x):
    """The low 10 bits of ``x`` (int32) spread to every third bit (a Morton code's axis)."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    return (x | (x << 2)) & 0x09249249


def _spatial_order(bounds):
    """Primitive indices ``(N,)`` ordered along a Morton curve of their box centres, so
    that each run of :data:`GROUP` is compact in space; within each run, by index."""
    c = 0.5 * (bounds[0] + bounds[1])  # (3, N)
    lo, hi = jnp.min(c, 1, keepdims=True), jnp.max(c, 1, keepdims=True)
    q = jnp.clip(jnp.floor((c - lo) / jnp.maximum(hi - lo, 1e-30) * 1023.0), 0, 1023).astype(jnp.int32)
    code = _spread_bits(q[0]) | (_spread_bits(q[1]) << 1) | (_spread_bits(q[2]) << 2)
    order = jnp.argsort(code, stable=True).astype(jnp.int32)
    N = order.shape[0]
    group = jnp.zeros((N,), jnp.int32).at[order].set(jnp.arange(N, dtype=jnp.int32) // GROUP)
    return jnp.argsort(group, stable=True).astype(jnp.int32)  # by group, then by index


def _closest_culled(k: Kind, g: Groups, ray, tmin):
    """:func:`closest_kind` over the groups ``g`` of kind ``k``: a ``lax.scan`` over the
    groups, each tested (a ``(rays, GROUP)`` tile) only if some ray meets its box."""
    ray2 = tuple(r[:, None] for r in ray)
    n = ray[0].shape[0]

    def test(carry, Pb, vb, b0, _):
        tb, ib = carry
        T = k.tfun(ray2, _fields(k, Pb), tmin)
        T = jax.lax.optimization_barrier(jnp.where(vb[None, :], T, INF).T)  # (GROUP, n), materialised
        # Ties go to the lower index, as the brute-force argmin has it.
        for j in range(GROUP):
            tj = T[j]
            better = (tj < tb) | ((tj == tb) & (b0[j] < ib))
            tb, ib = jnp.where(better, tj, tb), jnp.where(better, b0[j], ib)
        return tb, ib

    init = (jnp.full((n,), INF, ray[0].dtype), jnp.zeros((n,), jnp.int32))
    return _over_groups(g, ray2, lambda tn, tf: (tn <= tf) & (tf > tmin), test, init)


def closest_kind(k: Kind, ray, tmin):
    """Per ray: nearest distance (inf on a miss) and primitive index of one kind."""
    if k.accel is not None:
        return B.closest(k.accel, ray, tmin)
    if k.groups is not None:
        return _closest_culled(k, k.groups, ray, tmin)
    ray2 = tuple(r[:, None] for r in ray)
    N = k.material.shape[0]
    if N <= BLOCK:
        T = k.tfun(ray2, {n: v[None, :] for n, v in k.soa.items()}, tmin)
        return V.min_argmin(T)
    P, valid, base = _blocks(k.soa)
    n = ray[0].shape[0]

    def body(carry, blk):
        tb, ib = carry
        Pb, vb, b0 = blk
        T = k.tfun(ray2, {name: v[None, :] for name, v in Pb.items()}, tmin)
        T = jnp.where(vb[None, :], T, INF)
        tj, j = V.min_argmin(T)
        better = tj < tb
        return (jnp.where(better, tj, tb), jnp.where(better, b0 + j, ib)), None

    init = (jnp.full((n,), INF, ray[0].dtype), jnp.zeros((n,), jnp.int32))
    (tb, ib), _ = jax.lax.scan(body, init, (P, valid, base))
    return tb, ib


def no_hit(_, o, d, t0):
    z = jnp.zeros_like(t0)
    return z, jnp.zeros_like(o), jnp.zeros((2,) + z.shape, z.dtype), jnp.zeros((2,) + z.shape, z.dtype)


def nearest_kind(kinds: list[Kind], ray, tmin=0.0):
    """The nearest hit over ``kinds`` of the rays ``ray`` (the six component rows
    ``ox, oy, oz, dx, dy, dz``, each ``(n,)``): per ray, the position in ``kinds`` of
    the kind hit first (ties: the earlier kind), its distance (``inf``: no hit), and
    each kind's nearest primitive index (a tuple of ``(n,)``)."""
    ts, ids = zip(*[closest_kind(k, ray, tmin) for k in kinds])
    # A chain over the kinds (strictly nearer replaces: ties keep the earlier kind),
    # elementwise, where a stacked (kinds, n) argmin is a slow reduction on XLA:CPU.
    tb, which = ts[0], jnp.zeros(ts[0].shape, jnp.int32)
    for j in range(1, len(ts)):
        nearer = ts[j] < tb
        tb = jnp.where(nearer, ts[j], tb)
        which = jnp.where(nearer, j, which)
    return which, tb, ids


def _no_hits(o) -> Hit:
    """The :class:`Hit` of rays from ``o (3, n)`` that hit nothing."""
    n = o.shape[1]
    z = jnp.zeros((n,), o.dtype)
    return Hit(
        jnp.zeros((n,), bool),
        z,
        jnp.zeros_like(o),
        jnp.zeros((2, n), o.dtype),
        jnp.zeros((2, n), o.dtype),
        jnp.zeros((n,), jnp.int32),
        z,
    )


def closest_hit(kinds: list[Kind], o, d) -> Hit:
    """Nearest hit of rays ``o, d (3, n)`` (``d`` unit) over all kinds; differentiable
    in the hit quantities (see module docstring)."""
    n = o.shape[1]
    if not kinds:
        return _no_hits(o)
    ray = tuple(jax.lax.stop_gradient(x) for x in (o[0], o[1], o[2], d[0], d[1], d[2]))
    which, t0, ids = nearest_kind(kinds, ray)
    # Reverse mode (integrator's shading checkpoint) keeps these instead of searching again.
    which, t0, ids = checkpoint_name((which, t0, ids), KEPT)

    def combine(which, t0, ids, o, d):
        valid = t0 < INF
        t = jnp.zeros((n,), o.dtype)
        nrm = jnp.zeros_like(o)
        uv = jnp.zeros((2, n), o.dtype)
        rate = jnp.zeros((2, n), o.dtype)
        mat = jnp.zeros((n,), jnp.int32)
        curv = jnp.zeros((n,), o.dtype)
        for j, k in enumerate(kinds):
            sel = valid & (which == j)
            idx = jnp.where(sel, ids[j], 0)
            # Under a cond: skipped when no ray hit this kind, and its inputs and outputs
            # are materialised (XLA:CPU would otherwise fuse the search into every
            # consumer of the recomputation and repeat it per output component).
            tk, nk, uvk, rk = jax.lax.cond(
                any_in_batch(sel), k.hit, no_hit, hit_args(k, idx), o, d, jnp.where(sel, t0, 0.0)
            )
            t = jnp.where(sel, tk, t)
            nrm = jnp.where(sel[None], nk, nrm)
            uv = jnp.where(sel[None], uvk, uv)
            rate = jnp.where(sel[None], rk, rate)
            mat = jnp.where(sel, _kept(k, V.take_rows(k.material, idx), n), mat)
            if k.curvature is not None:
                curv = jnp.where(sel, _kept(k, V.take_rows(k.curvature, idx), n).astype(o.dtype), curv)
        return Hit(valid, t, nrm, uv, rate, mat, curv)

    def no_ray(which, t0, ids, o, d):
        return _no_hits(o)

    # Also under a cond, so that every field of the hit (validity included) is read
    # from materialised search results rather than re-searched inside its consumers.
    return jax.lax.cond(any_in_batch(t0 < INF), combine, no_ray, which, t0, ids, o, d)


def _crossings(k: Kind, ray2, P, tmax):
    if k.crossings is not None:
        return k.crossings(ray2, P, tmax)
    return (k.tfun(ray2, P, 0.0) < tmax).astype(ray2[0].dtype)


def _add_block(k: Kind, ray2, P, valid, onehot, tmax, counts):
    """``counts (n, M)`` plus the surface crossings of the rays ``ray2`` (``(n, 1)``
    rows) with a block of primitives ``P`` (``(1, B)`` rows; ``valid (B,)``: False for
    padding, ``None``: all real), counted per material by ``onehot (B, M)``."""
    hit = _crossings(k, ray2, P, tmax)
    if valid is not None:
        hit = jnp.where(valid[None, :], hit, 0.0)
    return counts + jnp.dot(hit, onehot, precision=_EXACT)


def occluder_counts(kinds: list[Kind], o, d, tmax, n_materials: int):
    """For shadow rays ``o, d (3, n)`` and segment lengths ``tmax (n,)``: how many
    surfaces of each material the open segment ``(0, tmax)`` crosses, ``(n, M)``
    float (no gradient: visibility is piecewise constant)."""
    n = o.shape[1]
    ray = tuple(jax.lax.stop_gradient(x) for x in (o[0], o[1], o[2], d[0], d[1], d[2]))
    tmax1 = jax.lax.stop_gradient(tmax)
    tmax = tmax1[:, None]
    ray2 = tuple(r[:, None] for r in ray)
    counts = jnp.zeros((n, n_materials), o.dtype)
    for k in kinds:
        if k.accel is not None:
            counts = counts + B.crossings(k.accel, k.material, ray, tmax, n_materials)
            continue
        onehot = jax.nn.one_hot(k.material, n_materials, dtype=o.dtype)
        N = k.material.shape[0]
        if k.groups is not None:
            g = k.groups

            def add(c, Pb, vb, _, ohb, k=k):
                return _add_block(k, ray2, _fields(k, Pb), vb, ohb, tmax, c)

            def meets(tn, tf):  # the segment (0, tmax) overlaps the box
                return (tn <= tf) & (tf > 0) & (tn < tmax)

            counts = _over_groups(g, ray2, meets, add, counts, onehot[g.members])
        elif N <= UNROLL_SHADOW:  # one row per primitive, added into its material's column
            for j in range(N):
                hit = _crossings(k, ray, _prim(k.soa, j), tmax1)
                counts = counts + hit[:, None] * onehot[j][None, :]
        elif N <= BLOCK:
            # Summed by a matrix product: XLA:CPU runs a reduction of this (rays, N)
            # tile (a max or a sum over N) 5-7x slower than the product.
            counts = _add_block(k, ray2, {nm: v[None, :] for nm, v in k.soa.items()}, None, onehot, tmax, counts)
        else:
            P, valid, _ = _blocks(k.soa)
            nb = valid.shape[0]
            oh = jnp.pad(onehot, ((0, nb * BLOCK - N), (0, 0))).reshape(nb, BLOCK, n_materials)

            def body(c, blk):
                Pb, vb, ohb = blk
                return _add_block(k, ray2, {nm: v[None, :] for nm, v in Pb.items()}, vb, ohb, tmax, c), None

            counts, _ = jax.lax.scan(body, counts, (P, valid, oh))
    return jax.lax.stop_gradient(counts)


def occluded(kinds: list[Kind], o, d, tmax):
    """For shadow rays ``o, d (3, n)`` and segment lengths ``tmax (n,)``: whether any
    surface crosses the open segment ``(0, tmax)``, ``(n,)`` bool: the crossings of
    :func:`occluder_counts` with every primitive counted as one material."""
    one = [k._replace(material=jnp.zeros_like(k.material)) for k in kinds]
    return occluder_counts(one, o, d, tmax, 1)[:, 0] > 0
