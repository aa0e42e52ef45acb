"""The ray queue of the Whitted integrator: live samples packed at the front of a
fixed buffer, processed in sub-tiles, the sub-tiles past the live count skipped.

Layout. A sample owns ``B`` rays (its specular branches). The queue holds a
ray's state as rows ``(2, r, B, Q)``: half, row, branch slot, queue column; one
column is one sample, so every array keeps its ray axis last and contiguous.
Depth ``d`` reads half ``d % 2`` and writes the other (one buffer carried
through the depth loop and updated in place). Sub-tile ``j`` is the ``(r, B,
ns)`` block of columns ``j ns ... (j + 1) ns - 1`` (``m = B ns`` rays). Depth 0
reads no queue: each sub-tile makes its own ``m`` camera rays, one per sample.

Writing. A sub-tile's samples whose children all have zero weight are dropped:
the live ones are packed to the front of a block (a gather, in chunks that are
skipped past the live count when nothing is differentiated; its derivative is
written so that reverse mode is a gather too) and the block is written at the queue's live
count (one contiguous ``dynamic_update_slice``). Columns past the live count
hold stale rays; the reader masks them (:func:`read`). No scatter of rays, no
transposes, no pass over the whole buffer per depth.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..masks import pack_map


def read(bufs, half, j, ns: int, live_cols, n: int):
    """Sub-tile ``j`` of half ``half`` of the queue ``bufs = (rays (2, r, B, Q), ids (2,
    B, Q))``: rays ``(r, B ns)`` and sample ids ``(B ns,)``, the columns at or past
    ``live_cols`` masked (zero rays, id ``n``: no sample)."""
    queue, ids = bufs
    _, r, B, _ = queue.shape
    start = j * ns
    zero = jnp.zeros((), start.dtype)
    rays = jax.lax.dynamic_slice(queue, (half, zero, zero, start), (1, r, B, ns))[0]
    sid = jax.lax.dynamic_slice(ids, (half, zero, start), (1, B, ns))[0]
    ok = (start + jnp.arange(ns, dtype=start.dtype)) < live_cols  # (ns,)
    rays = jnp.where(ok, rays, jnp.zeros((), rays.dtype))
    sid = jnp.where(ok, sid, n)
    # Read once per sub-tile: what materialises the rays is the conditional around this
    # read in the integrator (its output is a buffer). The barrier alone does not stop
    # XLA:CPU from fusing the slice and mask into every consumer, the intersection
    # loops included: a read outside a conditional made the forward render 30 % slower.
    return jax.lax.optimization_barrier((rays.reshape(r, B * ns), sid.reshape(B * ns)))


def pack(alive, width: int):
    """For ``alive (k,)``: ``src (width,)``, the source index of each packed position
    (the live entries in order, then ``k``: none), ``dst (k,)``, the packed position
    of each entry (``width`` where not alive), and the number of live entries
    (:func:`raytrax.masks.pack_map`)."""
    return pack_map(alive, width, alive.shape[0], jnp.int32)


PACK_CHUNK = 1024


def _gather_cols(rows, src):
    """``rows (r, B, k)`` at columns ``src (w,)`` (``k``: zero): ``(r, B, w)``."""
    padded = jnp.concatenate([rows, jnp.zeros(rows.shape[:2] + (1,), rows.dtype)], -1)
    return jnp.take(padded, src, axis=2, mode="clip", unique_indices=False)


@jax.custom_jvp
def _permute(rows, src, dst, c):
    """``rows (r, B, k)`` at columns ``src (w,)`` (``k``: zero): ``(r, B, w)``, where
    only the first ``c`` columns are live (the rest are zero here). ``dst (k,)`` is
    the inverse map (``w``: dropped).

    Evaluated alone, the columns are gathered in chunks of :data:`PACK_CHUNK`, a
    chunk wholly past ``c`` skipped (zero). Differentiated, it is one gather, and
    the tangent is written with ``dst``, so that reverse mode transposes it into a
    gather as well (a gather's own transpose is a scatter-add, a slow loop on
    XLA:CPU); the skipping conditionals would cost more in reverse mode than they
    save."""
    w = src.shape[0]
    C = PACK_CHUNK
    if w <= C or w % C:
        return _gather_cols(rows, src)
    zero = jnp.zeros(rows.shape[:2] + (C,), rows.dtype)
    parts = [jax.lax.cond(lo < c, _gather_cols, lambda *_: zero, rows, src[lo : lo + C]) for lo in range(0, w, C)]
    return jnp.concatenate(parts, -1)


@_permute.defjvp
def _permute_jvp(primals, tangents):
    rows, src, dst, c = primals
    t = tangents[0]
    w = src.shape[0]
    out_t = jnp.zeros(rows.shape[:2] + (w,), rows.dtype).at[:, :, dst].add(t, mode="drop", unique_indices=True)
    return _gather_cols(rows, src), out_t


def packed(alive, rows, ids, width: int):
    """The samples ``alive (k,)`` of a sub-tile packed to the front of a block
    ``width >= k`` columns wide: rows ``(r, B, width)`` (``rows (r, B, k)``; zero past
    the live ones) and ids ``(width,)`` (``ids (k,)``; ``0`` past them), and the
    number of live samples."""
    src, dst, c = pack(alive, width)
    return _permute(rows, src, dst, c), jnp.take(ids, src, mode="fill", fill_value=0), c


def append(bufs, half, cnt, block, bid):
    """The queue ``bufs = (rays (2, r, B, Q), ids (2, B, Q))`` with the block ``(r, B,
    w)``, ids ``(w,)`` written into half ``half`` at column ``cnt`` (one contiguous
    write; ``Q >= cnt + w``)."""
    queue, idq = bufs
    B = block.shape[1]
    zero = jnp.zeros((), cnt.dtype)
    queue = jax.lax.dynamic_update_slice(queue, block[None], (half, zero, zero, cnt))
    idq = jax.lax.dynamic_update_slice(idq, jnp.broadcast_to(bid, (1, B) + bid.shape), (half, zero, cnt))
    return queue, idq


def top_children(cand_w, B: int):
    """Indices ``(B, k)`` of the ``B`` heaviest of ``c`` candidate children per
    sample, scored by the channel-max of ``cand_w (3, c, k)`` (no gradient), in
    ``lax.top_k``'s order (descending, ties to the lower index); ``c`` for slots
    past the candidates when ``B > c``. Rank counting, elementwise: cheaper on
    CPU than a ``top_k`` call for the few candidates here."""
    score = jax.lax.stop_gradient(jnp.maximum(jnp.maximum(cand_w[0], cand_w[1]), cand_w[2]))  # (c, k)
    c, k = score.shape
    rank = []
    for j in range(c):
        r = jnp.zeros((k,), jnp.int32)
        for i in range(c):
            if i != j:
                r = r + (score[i] >= score[j] if i < j else score[i] > score[j]).astype(jnp.int32)
        rank.append(r)
    top = []
    for r in range(B):
        pick = jnp.full((k,), c, jnp.int32)
        for j in range(c):
            pick = jnp.where(rank[j] == r, j, pick)
        top.append(pick)
    return jnp.stack(top)


def pick(a, top):
    """``a (d, c, k)`` at candidate indices ``top (B, k)`` -> ``(d, B, k)`` (zero where
    ``top == c``): a select chain, elementwise also in reverse mode."""
    c = a.shape[1]
    out = jnp.zeros(a.shape[:1] + top.shape, a.dtype)
    for j in range(c):
        out = jnp.where(top[None] == j, a[:, j : j + 1], out)
    return out
