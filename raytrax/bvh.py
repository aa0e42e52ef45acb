"""A bounding volume hierarchy over the merged triangle list (triangles,
tetrahedron faces, mesh faces), for the stop-gradient searches of
:mod:`raytrax.intersect`.

Split of the work:

* **Topology, on the host, once** (:func:`build_topology`, called by
  :meth:`raytrax.SceneBuilder.build`): the triangles are ordered by a recursive
  split of their centroids along the longest axis, cut so that every leaf holds
  exactly :data:`LEAF` triangles (the last one is padded) and every aligned run
  of :data:`BRANCH` leaves (of ``BRANCH ** 2`` leaves, ...) is one subtree. The
  order is stored in the scene as an integer array (:class:`TriangleBVH`), so the
  scene stays a pytree that ``jit``, ``grad``, ``vmap`` and
  :func:`raytrax.with_parameters` handle; integer leaves are not differentiated.
* **Bounds, in the traced function, every render** (:func:`prepare`): the leaf
  boxes are refit from the current vertex positions (under ``stop_gradient``),
  and the boxes of the inner levels from them (a node bounds ``BRANCH``
  consecutive nodes of the level below; levels are added until at most
  :data:`TOP_MAX` nodes remain), so the search stays exact when vertices or
  tetrahedron centres move during a fit; only the quality of the grouping can
  degrade, never correctness.
* **Traversal** (:func:`closest`, :func:`crossings`): every ray tests the top
  level's boxes (struct-of-arrays slab test, ``(rays, nodes)``), then one
  ``lax.while_loop`` walks the tree per ray, depth first, nearest entry first
  among a node's children: in a step a ray whose open node of leaves has none
  left opens its next node (a ``(rays, BRANCH)`` slab test of the node's
  children), and a ray with a leaf to visit (one of a node of leaves opened in
  the same step included) tests it (gathering its ``LEAF`` triangles: a
  ``(rays, LEAF)`` tile of the watertight test of :func:`raytrax.shapes.tri_t`,
  whose per-ray frame is computed once per query), until no ray has
  a node left that could hold a nearer hit (closest hit) or that overlaps its
  segment (shadow crossings). Rays are masked, and compacted once few are left,
  so the few rays that take many steps do not cost a full-width step each. A
  step costs the same at 10^3 and 10^6 triangles; the number of steps grows
  with the depth of the tree and the leaves a ray must test.

The results equal the brute-force search: the same kernels (``shapes.tri_t``,
``shapes.tri_crossings``) on
the same numbers, ties between equal distances broken towards the lower
triangle index as ``argmin`` does, and leaf boxes padded so that rounding never
drops a leaf.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from . import vec as V
from .masks import count_true, true_indices
from .shapes.base import check_shape
from .shapes.triangles import ray_frame, tri_crossings, tri_soa, tri_t

LEAF = 32  # triangles per leaf
BRANCH = 16  # children of an inner node (leaves, or inner nodes of the level below)
TOP_MAX = 64  # nodes of the top level: inner levels are added until at most this many remain
MIN_TRIANGLES = 64  # the BVH is used above this many triangles, brute force below (crossover: benchmarks/README.md)
INF = float("inf")
SHRINK = (4, 4)  # compaction factors of the traversal loop (see _compacting_loop)


class TriangleBVH(eqx.Module):
    """Leaf order of the merged triangle list: ``order (L * LEAF,)`` merged-list
    indices, leaf ``l`` being ``order[l * LEAF:(l + 1) * LEAF]``; ``pad`` (same
    shape, int 0/1) marks padding slots (they repeat the first triangle of their leaf;
    the shadow crossings skip them)."""

    order: Int[Array, " P"]
    pad: Int[Array, " P"]
    n_triangles: int = eqx.field(static=True, default=-1)  # length of the merged list it was built for

    def __check_init__(self):
        check_shape("TriangleBVH.order", self.order, (None,))
        check_shape("TriangleBVH.pad", self.pad, self.order.shape)
        if self.order.shape[0] % LEAF:
            raise ValueError(f"TriangleBVH.order: length {self.order.shape[0]} is not a multiple of {LEAF}")

    @property
    def n_leaves(self) -> int:
        return self.order.shape[0] // LEAF


def build_topology(centroids, leaf: int | None = None, branch: int | None = None):
    """Host-side leaf order of triangles with ``centroids (N, 3)`` (numpy):
    ``(order, pad)`` int32 arrays of length ``ceil(N / leaf) * leaf``.

    A recursive split of the centroids along the longest axis, by count: a node of
    ``m`` leaves sends whole units of ``u`` leaves to its left half (``u`` the largest
    power of ``branch`` below ``m``; about half of them), so that every run of
    ``branch ** k`` consecutive leaves that starts at a multiple of it is one subtree,
    compact in space (the inner nodes of :func:`prepare`)."""
    leaf = LEAF if leaf is None else leaf
    branch = BRANCH if branch is None else branch
    c = np.asarray(centroids, np.float64)
    N = c.shape[0]
    leaves = []
    stack = [np.arange(N)]
    while stack:
        ids = stack.pop()
        if ids.shape[0] <= leaf:
            leaves.append(np.sort(ids))
            continue
        cc = c[ids]
        axis = int(np.argmax(np.ptp(cc, axis=0)))
        m = -(-ids.shape[0] // leaf)  # leaves of this node
        u = 1
        while u * branch < m:
            u *= branch
        left = (-(-m // u) + 1) // 2 * u * leaf  # whole units on the left
        part = np.argpartition(cc[:, axis], left - 1, kind="introselect")
        stack.append(ids[part[left:]])  # popped after the left half: leaves stay in spatial order
        stack.append(ids[part[:left]])
    order, pad = [], []
    for ids in leaves:
        k = ids.shape[0]
        order.append(np.concatenate([ids, np.full(leaf - k, ids[0])]))
        pad.append(np.arange(leaf) >= k)
    return np.concatenate(order).astype(np.int32), np.concatenate(pad).astype(np.int32)


def from_triangles(tris) -> TriangleBVH:
    """A :class:`TriangleBVH` for triangles ``(N, 3, 3)`` (host arrays)."""
    tris = np.asarray(tris, np.float64)
    order, pad = build_topology(tris.mean(1))
    return TriangleBVH(jnp.asarray(order), jnp.asarray(pad), tris.shape[0])


def for_scene(scene) -> TriangleBVH | None:
    """A :class:`TriangleBVH` over the merged triangle list of ``scene`` (triangles,
    tetrahedron faces, mesh faces: the order of :func:`raytrax.intersect.prepare`),
    whatever its size; None without triangles. Host side (concrete arrays)."""
    tris = np.asarray(scene.merged_triangles()[0], np.float64)
    return from_triangles(tris) if tris.shape[0] else None


class Accel(NamedTuple):
    """Traced search arrays: triangle SoA ``(L, LEAF)`` in leaf order, merged-list
    index ``(L, LEAF)`` of each slot, which slots are padding ``(L, LEAF)`` (they
    repeat their leaf's first triangle), leaf boxes ``(L,)`` per component, and the
    inner levels, lowest first:
    ``levels[k]`` holds the boxes of the nodes of level ``k + 1`` (``(L_k+1,)`` per
    component; node ``i`` of level ``k + 1`` bounds nodes ``i * BRANCH ...`` of level
    ``k``, level 0 being the leaves). Empty when the rays test every leaf box."""

    tri: dict
    index: jax.Array
    pad: jax.Array
    box: dict
    levels: tuple = ()


def prepare(bvh: TriangleBVH, triangles) -> Accel:
    """The search arrays of the merged triangle list ``triangles (N, 3, 3)``
    (stop-gradient) in leaf order (``tri_soa`` of the permuted triangles: one gather of
    whole triangles), with the leaf boxes refit to the current vertices."""
    nl = bvh.n_leaves
    T = triangles[bvh.order]  # padding slots repeat a triangle of their leaf
    los, his = [], []
    for c in range(3):
        los.append(jnp.min(jnp.min(T[:, :, c], 1).reshape(nl, LEAF), 1))
        his.append(jnp.max(jnp.max(T[:, :, c], 1).reshape(nl, LEAF), 1))
    # Pad by a relative margin (of the leaf's largest extent, so flat leaves get some
    # thickness, and of its distance from the origin) so that the rounding of the slab
    # test never drops a leaf whose triangle the differently rounded triangle test hits.
    ext = jnp.maximum(jnp.maximum(his[0] - los[0], his[1] - los[1]), his[2] - los[2])
    size = jnp.maximum(
        jnp.maximum(jnp.abs(los[0]), jnp.abs(his[0])),
        jnp.maximum(jnp.maximum(jnp.abs(los[1]), jnp.abs(his[1])), jnp.maximum(jnp.abs(los[2]), jnp.abs(his[2]))),
    )
    eps = 1e-4 * ext + 1e-5 * size + 1e-30
    box = {}
    for name, lo, hi in zip("xyz", los, his):
        box["lo" + name] = jax.lax.stop_gradient(lo - eps)
        box["hi" + name] = jax.lax.stop_gradient(hi + eps)
    # A padding slot is its leaf's first triangle again: the same distance and index,
    # so the closest hit is unchanged; the shadow crossings skip it (see crossings).
    tri = {k: v.reshape(nl, LEAF) for k, v in tri_soa(T[:, 0], T[:, 1], T[:, 2]).items()}
    levels = []
    cur, n = box, nl
    while n > TOP_MAX:
        cur = merge_boxes(children(cur, -(-n // BRANCH)))
        levels.append(cur)
        n = cur["lox"].shape[0]
    return Accel(tri, bvh.order.reshape(nl, LEAF), bvh.pad.reshape(nl, LEAF) != 0, box, tuple(levels))


def children(box, up: int):
    """Boxes ``(N,)`` per component as rows of ``BRANCH``, ``(up, BRANCH)`` (the
    children of each of ``up`` nodes), the last row padded by repeating its last box
    (which leaves the row's union unchanged; :func:`_traverse` masks the padding)."""
    n = box["lox"].shape[0]
    return {c: jnp.pad(v, (0, up * BRANCH - n), mode="edge").reshape(up, BRANCH) for c, v in box.items()}


def merge_boxes(rows):
    """The union of each row of boxes ``(m, k)`` per component: ``(m,)`` per component."""
    return {c: (jnp.min if c.startswith("lo") else jnp.max)(v, 1) for c, v in rows.items()}


def inverse_directions(ray2):
    """``1 / d`` per component of rays ``ray2`` (the six components), a direction
    component of magnitude below 1e-30 replaced by +-1e-30 of its sign (a huge, finite
    slope: no ``0 * inf`` in :func:`slab`)."""
    out = []
    for d in ray2[3:]:
        tiny = jnp.asarray(1e-30, d.dtype)
        out.append(1.0 / jnp.where(jnp.abs(d) < tiny, jnp.where(d < 0, -tiny, tiny), d))
    return tuple(out)


def slab(ray2, box, inv=None):
    """Entry and exit distances ``(n, L)`` of rays ``(n, 1)`` (the six components) through
    axis-aligned boxes ``(1, L)`` or ``(n, L)`` (``box["lox"] ... box["hiz"]``);
    ``inv``: the rays' :func:`inverse_directions`, computed here if None."""
    inv = inverse_directions(ray2) if inv is None else inv
    tn, tf = None, None
    for i, c in enumerate("xyz"):
        o = ray2[i]
        t1 = (box["lo" + c] - o) * inv[i]
        t2 = (box["hi" + c] - o) * inv[i]
        lo, hi = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
        tn = lo if tn is None else jnp.maximum(tn, lo)
        tf = hi if tf is None else jnp.minimum(tf, hi)
    assert tn is not None and tf is not None
    return tn, tf


def _row(x, r, idx):
    """``x[r[i], idx[i]]`` for ``x (L, K)``."""
    return x.reshape(-1)[r * x.shape[1] + idx]


def _take(tree, idx):
    return jax.tree_util.tree_map(lambda x: x[idx], tree)


def _compacting_loop(state, const, active, step, shrink=None):
    """``while any(active(state)): state = step(state, const)`` over per-ray pytrees
    ``state`` and ``const`` (leading axis ``n``; ``active -> (n,) bool``). Rays are
    masked, and compacted: once at most ``n / shrink[0]`` rays are still active, they
    are gathered into a buffer of that size and the loop goes on there (and so on for
    the next factors), so that the few rays that need many steps do not cost a
    full-width step each."""
    shrink = SHRINK if shrink is None else shrink

    def run(state, const, level):
        m = jax.tree_util.tree_leaves(state)[0].shape[0]
        small = m // shrink[level] if level < len(shrink) else 0
        if small < 64:
            small = 0
        state = jax.lax.while_loop(lambda st: count_true(active(st)) > small, lambda st: step(st, const), state)
        if not small:
            return state
        idx = true_indices(active(state), small, m)
        safe = jnp.minimum(idx, m - 1)
        sub = run(_take(state, safe), _take(const, safe), level + 1)
        return jax.tree_util.tree_map(lambda full, part: full.at[idx].set(part, mode="drop"), state, sub)

    return run(state, const, 0)


def _traverse(acc: Accel, const, state, leaf_body, more, ok):
    """Visit, per ray, the leaves whose boxes pass ``ok``, depth first down the levels
    of ``acc``, nearest entry first among the children of a node. Each ray keeps, per
    level, the entry distances of the children of the node it is in (inf: visited or
    missed). In a step a ray whose leaves (the children of its open node of leaves)
    hold none that ``more`` wants opens the next node of the lowest level that has one
    (tests its ``BRANCH`` children's boxes), then a ray with a leaf it wants (also the
    first of a node of leaves opened just now) tests the leaf of least entry. One loop
    for all levels
    (:func:`_compacting_loop`). ``const = (ray2, extra)``: rays ``(n, 1)`` and what
    ``ok(tn, tf, extra) -> bool`` and ``leaf_body`` use; ``leaf_body(leaf (n,), active
    (n,), const, state) -> state``; ``more(key (n,), state)``: whether a ray still
    wants a node of entry ``key``."""
    ray2, extra = const
    inv = inverse_directions(ray2)
    boxes = (acc.box,) + tuple(acc.levels)  # boxes[k]: the nodes of level k (0: leaves)
    top = len(boxes) - 1
    n = ray2[0].shape[0]
    tn, tf = slab(ray2, {k: v[None, :] for k, v in boxes[top].items()}, inv)
    keys_top = jnp.where(ok(tn, tf, extra), tn, INF)
    # The children of every inner node, in one table: row off[l] + i holds the boxes of
    # the children of node i of level l (l = 1 ... top).
    rows, valid, off = {c: [] for c in boxes[0]}, [], [0]
    for level in range(1, top + 1):
        nk, nup = boxes[level - 1]["lox"].shape[0], boxes[level]["lox"].shape[0]
        for c, v in children(boxes[level - 1], nup).items():
            rows[c].append(v)
        valid.append((np.arange(nup * BRANCH) < nk).reshape(nup, BRANCH))
        off.append(off[-1] + nup)
    table = {c: jnp.concatenate(v) for c, v in rows.items()} if top else {}
    table_valid = jnp.asarray(np.concatenate(valid) if top else np.zeros((0, BRANCH), bool))
    kdt = keys_top.dtype
    cols = jnp.arange(BRANCH, dtype=jnp.int32)[None, None, :]

    def least(Kc, keys_top):
        """Least key and its column per level: ``(n, top)`` of the open nodes' children, ``(n,)`` of the top."""
        return V.min_argmin(Kc) + V.min_argmin(keys_top)

    def wants(mins, st):
        """Per level (0 ... top), whether ``more`` wants the least key."""
        m, _, mt, _ = mins
        return [more(m[:, level], st) for level in range(top)] + [more(mt, st)]

    # The state of a ray: Kc (n, top, BRANCH), the keys of the children of the node open
    # at each level l + 1 (inf: visited or missed), whose ids start at base (n, top);
    # the top level's keys (n, T); their least keys (``least``); the caller's state.
    def step(carry, const2):
        const, inv = const2
        Kc, keys_top, base, mins, st = carry
        _, i, _, it = mins
        w = keys_top.shape[0]
        acts, lower = [], jnp.zeros((w,), bool)
        for x in wants(mins, st):  # each ray acts at the lowest level that has a node it wants
            acts.append(x & ~lower)
            lower = lower | x
        tcols = jnp.arange(keys_top.shape[1], dtype=jnp.int32)[None, :]
        keys_top = jnp.where(acts[top][:, None] & (tcols == it[:, None]), INF, keys_top).astype(kdt)
        if not top:
            st = leaf_body(it, acts[0], const, st)
            return Kc, keys_top, base, least(Kc, keys_top), st
        # Open a node of the lowest level that has one left: test its children's boxes,
        # into the keys of the level below (the rays that test a leaf open nothing).
        A = jnp.stack([jnp.zeros((w,), bool)] + acts[1:top], 1)  # (n, top): nodes opened from Kc
        Kc = jnp.where(A[:, :, None] & (cols == i[:, :, None]), INF, Kc).astype(kdt)
        node = [base[:, level] + i[:, level] for level in range(top)] + [it]
        row = jnp.zeros((w,), jnp.int32)
        slot = jnp.full((w,), w * top, jnp.int32)  # out of range: dropped
        for level in range(1, top + 1):
            row = jnp.where(acts[level], off[level - 1] + node[level], row)
            slot = jnp.where(acts[level], jnp.arange(w, dtype=jnp.int32) * top + (level - 1), slot)
        tn, tf = slab(const[0], {c: v[row] for c, v in table.items()}, inv)  # (n, BRANCH)
        ck = jnp.where(table_valid[row] & ok(tn, tf, const[1]), tn, INF)
        # A scatter, not a select per level: XLA would compute the slab test once per level.
        Kc = Kc.reshape(w * top, BRANCH).at[slot].set(ck, mode="drop").reshape(w, top, BRANCH)
        base = jnp.where(jnp.stack(acts[1:], 1), jnp.stack(node[1:], 1) * BRANCH, base)
        # Then the leaf of least entry, in the same step: also the first leaf of a node of
        # leaves opened just now.
        m0, i0 = V.min_argmin(Kc[:, 0])
        a0 = acts[0] | (acts[1] & more(m0, st))
        st = leaf_body(base[:, 0] + i0, a0, const, st)
        Kc = Kc.at[:, 0].set(jnp.where(a0[:, None] & (cols[:, 0] == i0[:, None]), INF, Kc[:, 0]).astype(kdt))
        return Kc, keys_top, base, least(Kc, keys_top), st

    def active(carry):
        out = jnp.zeros((carry[1].shape[0],), bool)
        for x in wants(carry[3], carry[4]):
            out = out | x
        return out

    Kc = jnp.full((n, top, BRANCH), INF, kdt)
    init = (Kc, keys_top, jnp.zeros((n, top), jnp.int32), least(Kc, keys_top), state)
    return _compacting_loop(init, (const, inv), active, step)[4]


def _frame2(ray):
    """The triangle test's per-ray frame (``shapes.ray_frame``) as ``(n, 1)`` rows:
    computed once per query and compacted with the rays."""
    return tuple(f[:, None] for f in ray_frame(ray))


def closest(acc: Accel, ray, tmin):
    """Per ray: nearest triangle distance (inf on a miss) and its merged-list index,
    equal to the brute-force search."""
    ray2 = tuple(r[:, None] for r in ray)
    n = ray[0].shape[0]
    dt = ray[0].dtype

    def body(leaf, act, const, st):
        tb, ib = st
        T = tri_t(const[0], {k: v[leaf] for k, v in acc.tri.items()}, tmin, const[1])
        T = jnp.where(act[:, None], T, INF)
        tj, j = V.min_argmin(T)
        ij = _row(acc.index, leaf, j)
        better = (tj < tb) | ((tj == tb) & (ij < ib))
        return jnp.where(better, tj, tb), jnp.where(better, ij, ib)

    init = (jnp.full((n,), INF, dt), jnp.full((n,), jnp.iinfo(jnp.int32).max, jnp.int32))
    tb, ib = _traverse(
        acc,
        (ray2, _frame2(ray)),
        init,
        body,
        lambda k, st: (k < INF) & (k <= st[0]),
        lambda tn, tf, _: (tn <= tf) & (tf > tmin),
    )
    return tb, jnp.where(tb < INF, ib, 0)


def crossings(acc: Accel, material, ray, tmax, n_materials):
    """Per shadow ray: surfaces of each material crossed on ``(0, tmax)``, ``(n, M)``,
    equal to the brute-force count. ``material (N,)`` of the merged list; ``tmax (n, 1)``."""
    ray2 = tuple(r[:, None] for r in ray)
    n = ray[0].shape[0]
    dt = ray[0].dtype
    mat = jnp.where(acc.pad, -1, material[acc.index])  # (L, LEAF); padding: no material, not counted
    mids = jnp.arange(n_materials, dtype=mat.dtype)

    def body(leaf, act, const, counts):
        ray2, (tmax, frame) = const
        hit = (tri_crossings(ray2, {k: v[leaf] for k, v in acc.tri.items()}, tmax, frame) > 0) & act[:, None]
        m = mat[leaf]  # (n, LEAF)
        oh = (m[:, :, None] == mids[None, None, :]) & hit[:, :, None]
        return counts + jnp.sum(oh.astype(dt), 1)

    return _traverse(
        acc,
        (ray2, (tmax, _frame2(ray))),
        jnp.zeros((n, n_materials), dt),
        body,
        lambda k, st: k < INF,
        lambda tn, tf, extra: (tn <= tf) & (tf > 0) & (tn < extra[0]),
    )
