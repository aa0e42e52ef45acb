"""A bounding volume hierarchy over the merged triangle list (triangles,
tetrahedron faces, mesh faces), for the stop-gradient searches of
:mod:`raytrax.intersect`.

Split of the work:

* **Topology, on the host, once** (:func:`build_topology`, called by
  :meth:`raytrax.SceneBuilder.build`): the triangles are ordered by a recursive
  median split of their centroids along the longest axis, cut so that every
  leaf holds exactly :data:`LEAF` triangles (the last one is padded). The order
  is stored in the scene as an integer array (:class:`TriangleBVH`), so the
  scene stays a pytree that ``jit``, ``grad``, ``vmap`` and
  :func:`raytrax.with_parameters` handle; integer leaves are not differentiated.
* **Bounds, in the traced function, every render** (:func:`prepare`): the leaf
  boxes are refit from the current vertex positions (under ``stop_gradient``),
  so the search stays exact when vertices or tetrahedron centres move during a
  fit; only the quality of the grouping can degrade, never correctness.
* **Traversal** (:func:`closest`, :func:`crossings`): every ray tests all leaf
  boxes (struct-of-arrays slab test, ``(rays, leaves)``), then a
  ``lax.while_loop`` visits, per ray, the leaf with the nearest entry distance
  not yet visited, gathering that leaf's ``LEAF`` triangles (``(rays, LEAF)``
  Moeller-Trumbore tile), until no ray has a leaf left that could hold a nearer
  hit (closest hit) or that overlaps its segment (shadow crossings). Rays are
  masked, not compacted, so a step costs ``rays x LEAF`` tests and the loop runs
  as many steps as the busiest ray needs.

The results equal the brute-force search: the same kernel (``shapes.tri_t``) on
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
from .shapes.triangles import tri_t

LEAF = 32  # triangles per leaf
MIN_TRIANGLES = 64  # the BVH is used above this many triangles, brute force below (crossover: benchmarks/README.md)
INF = float("inf")
SHRINK = (8, 8)  # compaction factors of the traversal loop (see _visit)


class TriangleBVH(eqx.Module):
    """Leaf order of the merged triangle list: ``order (L * LEAF,)`` merged-list
    indices, leaf ``l`` being ``order[l * LEAF:(l + 1) * LEAF]``; ``pad`` (same
    shape, int 0/1) marks padding slots (they repeat a triangle of their leaf and
    are never hit)."""

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


def build_topology(centroids, leaf: int | None = None):
    """Host-side leaf order of triangles with ``centroids (N, 3)`` (numpy):
    ``(order, pad)`` int32 arrays of length ``ceil(N / leaf) * leaf``."""
    leaf = LEAF if leaf is None else leaf
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
        left = (-(-ids.shape[0] // leaf) // 2) * leaf  # whole leaves on the left
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
    """Traced search arrays: triangle SoA ``(L, LEAF)`` in leaf order (padding
    slots have zero edges, so never hit), merged-list index ``(L, LEAF)`` of each
    slot, leaf boxes ``(L,)`` per component."""

    tri: dict
    index: jax.Array
    box: dict


def prepare(bvh: TriangleBVH, soa: dict) -> Accel:
    """Permute the triangle SoA (stop-gradient ``(N,)`` arrays of ``tri_soa``) into
    leaf order and refit the leaf boxes to the current vertices."""
    nl = bvh.n_leaves
    P = {k: v[bvh.order] for k, v in soa.items()}
    ax, ay, az = P["ax"], P["ay"], P["az"]
    xs = (ax, ax + P["e1x"], ax + P["e2x"])
    ys = (ay, ay + P["e1y"], ay + P["e2y"])
    zs = (az, az + P["e1z"], az + P["e2z"])
    los, his = [], []
    for comp in (xs, ys, zs):
        los.append(jnp.min(jnp.minimum(jnp.minimum(comp[0], comp[1]), comp[2]).reshape(nl, LEAF), 1))
        his.append(jnp.max(jnp.maximum(jnp.maximum(comp[0], comp[1]), comp[2]).reshape(nl, LEAF), 1))
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
    keep = bvh.pad == 0
    tri = {}
    for k, v in P.items():
        if k.startswith("e"):
            v = jnp.where(keep, v, jnp.zeros((), v.dtype))
        tri[k] = v.reshape(nl, LEAF)
    return Accel(tri, bvh.order.reshape(nl, LEAF), box)


def slab(ray2, box):
    """Entry and exit distances ``(n, L)`` of rays ``(n, 1)`` (the six components) through
    axis-aligned boxes ``(1, L)`` (``box["lox"] ... box["hiz"]``); a ray parallel to a
    slab gets a huge, finite slope of its sign (no ``0 * inf``)."""
    tn, tf = None, None
    for i, c in enumerate("xyz"):
        o, d = ray2[i], ray2[3 + i]
        tiny = jnp.asarray(1e-30, d.dtype)
        inv = 1.0 / jnp.where(jnp.abs(d) < tiny, jnp.where(d < 0, -tiny, tiny), d)
        t1 = (box["lo" + c] - o) * inv
        t2 = (box["hi" + c] - o) * inv
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


def _visit(keys, const, state, body, more, shrink=None):
    """Visit, per ray, leaves in increasing ``keys (n, L)`` (inf: skip).

    ``const``, ``state``: pytrees of per-ray arrays (leading axis ``n``);
    ``body(leaf (n,), active (n,), const, state) -> state`` processes one leaf per
    ray; ``more(key (n,), state) -> (n,) bool`` says whether a ray still wants its
    next leaf (of entry ``key``). Rays are masked, and compacted: once at most
    ``n / shrink[0]`` rays are still active, they are gathered into a buffer of
    that size and the loop goes on there (and so on for the next factors), so
    that the few rays that visit many leaves do not cost a full-width step each.
    """
    cols = jnp.arange(keys.shape[1], dtype=jnp.int32)[None, :]
    shrink = SHRINK if shrink is None else shrink

    def nxt(keys):
        return V.min_argmin(keys)

    def run(keys, const, state, level):
        m = keys.shape[0]
        small = m // shrink[level] if level < len(shrink) else 0
        if small < 64:
            small = 0

        def cond(c):
            _, k, _, st = c
            return count_true(more(k, st)) > small

        def step(c):
            keys, k, leaf, st = c
            act = more(k, st)
            st = body(leaf, act, const, st)
            keys = jnp.where(cols == leaf[:, None], jnp.asarray(INF, keys.dtype), keys)
            k, leaf = nxt(keys)
            return keys, k, leaf, st

        k, leaf = nxt(keys)
        keys, k, leaf, state = jax.lax.while_loop(cond, step, (keys, k, leaf, state))
        if not small:
            return state
        act = more(k, state)
        idx = true_indices(act, small, m)
        sub_keys = jnp.where((idx < m)[:, None], keys[jnp.minimum(idx, m - 1)], jnp.asarray(INF, keys.dtype))
        safe = jnp.minimum(idx, m - 1)
        sub = run(sub_keys, _take(const, safe), _take(state, safe), level + 1)
        return jax.tree_util.tree_map(lambda full, part: full.at[idx].set(part, mode="drop"), state, sub)

    return run(keys, const, state, 0)


def closest(acc: Accel, ray, tmin):
    """Per ray: nearest triangle distance (inf on a miss) and its merged-list index,
    equal to the brute-force search."""
    ray2 = tuple(r[:, None] for r in ray)
    tn, tf = slab(ray2, {k: v[None, :] for k, v in acc.box.items()})
    keys = jnp.where((tn <= tf) & (tf > tmin), tn, INF)  # pyright: ignore
    n = ray[0].shape[0]
    dt = ray[0].dtype

    def body(leaf, act, ray2, st):
        tb, ib = st
        T = tri_t(ray2, {k: v[leaf] for k, v in acc.tri.items()}, tmin)
        T = jnp.where(act[:, None], T, INF)
        tj, j = V.min_argmin(T)
        ij = _row(acc.index, leaf, j)
        better = (tj < tb) | ((tj == tb) & (ij < ib))
        return jnp.where(better, tj, tb), jnp.where(better, ij, ib)

    init = (jnp.full((n,), INF, dt), jnp.full((n,), jnp.iinfo(jnp.int32).max, jnp.int32))
    tb, ib = _visit(keys, ray2, init, body, lambda k, st: (k < INF) & (k <= st[0]))
    return tb, jnp.where(tb < INF, ib, 0)


def crossings(acc: Accel, material, ray, tmax, n_materials):
    """Per shadow ray: surfaces of each material crossed on ``(0, tmax)``, ``(n, M)``,
    equal to the brute-force count. ``material (N,)`` of the merged list; ``tmax (n, 1)``."""
    ray2 = tuple(r[:, None] for r in ray)
    tn, tf = slab(ray2, {k: v[None, :] for k, v in acc.box.items()})
    keys = jnp.where((tn <= tf) & (tf > 0) & (tn < tmax), tn, INF)  # pyright: ignore
    n = ray[0].shape[0]
    dt = ray[0].dtype
    mat = material[acc.index]  # (L, LEAF)
    mids = jnp.arange(n_materials, dtype=mat.dtype)

    def body(leaf, act, const, counts):
        ray2, tmax = const
        hit = (tri_t(ray2, {k: v[leaf] for k, v in acc.tri.items()}, 0.0) < tmax) & act[:, None]
        m = mat[leaf]  # (n, LEAF)
        oh = (m[:, :, None] == mids[None, None, :]) & hit[:, :, None]
        return counts + jnp.sum(oh.astype(dt), 1)

    return _visit(keys, (ray2, tmax), jnp.zeros((n, n_materials), dt), body, lambda k, st: k < INF)
