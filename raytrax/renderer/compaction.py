"""The ray queue of the Whitted integrator: live samples packed at the front of a
fixed buffer, processed in sub-tiles, the sub-tiles past the live count skipped.

Layout. A sample owns ``B`` rays (its specular branches). The queue holds a
ray's state as rows ``(2, r, B, Q)``: half, row, branch slot, queue column; one
column is one sample, so every array keeps its ray axis last and contiguous.
Depth ``d`` reads half ``d % 2`` and writes the other (one buffer carried
through the depth loop and updated in place). Sub-tile ``j`` is the ``(r, B,
ns)`` block of columns ``j ns ... (j + 1) ns - 1`` (``m = B ns`` rays). At depth 0
every ray is its own sample (:func:`camera_queue`).

Writing. A sub-tile's samples whose children all have zero weight are dropped:
the live ones are packed to the front of a block (a gather, which XLA:CPU fuses
into the loop that computes the block; its derivative is written so that
reverse mode is a gather too) and the block is written at the queue's live
count (one contiguous ``dynamic_update_slice``). Columns past the live count
hold stale rays; the reader masks them (:func:`read`). No scatter of rays, no
transposes, no pass over the whole buffer per depth.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def camera_queue(a, B: int, ns: int, cap: int, fill, dtype):
    """Camera-ray rows ``a ([r,] n)`` as a two-half queue ``(2, [r,] B, cap)``, in half
    0: ray ``i`` at slot ``i // (S0 ns)``, column ``i % (S0 ns)`` (the first ``S0``
    sub-tiles of ``B ns`` rays hold them all; the order of rays inside a sub-tile
    does not matter); padded with ``fill``. Half 1 is ``fill``."""
    n = a.shape[-1]
    lead = a.shape[:-1]
    cols = -(-n // (B * ns)) * ns
    a = jnp.concatenate([a, jnp.full(lead + (B * cols - n,), fill, dtype)], -1).reshape(lead + (B, cols))
    a = jnp.concatenate([a, jnp.full(lead + (B, cap - cols), fill, dtype)], -1)
    return jnp.stack([a, jnp.full_like(a, fill)])


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
    # materialised once (else XLA fuses the slice and mask into every consumer,
    # the intersection loops included)
    return jax.lax.optimization_barrier((rays.reshape(r, B * ns), sid.reshape(B * ns)))


def pack(alive, width: int):
    """For ``alive (k,)``: ``src (width,)``, the source index of each packed position
    (the live entries in order, then ``k``: none), ``dst (k,)``, the packed position
    of each entry (``width`` where not alive), and the number of live entries."""
    (k,) = alive.shape
    dst = jnp.where(alive, jnp.cumsum(alive, dtype=jnp.int32) - 1, width)
    src = jnp.full((width,), k, jnp.int32).at[dst].set(jnp.arange(k, dtype=jnp.int32), mode="drop", unique_indices=True)
    return src, dst, jnp.sum(alive, dtype=jnp.int32)


@jax.custom_jvp
def _permute(rows, src, dst):
    """``rows (r, B, k)`` at columns ``src (w,)`` (``k``: zero): ``(r, B, w)``. ``dst
    (k,)`` is the inverse map (``w``: dropped); the tangent is written with it, so
    that reverse mode transposes it into a gather as well (a gather's own
    transpose is a scatter-add, a slow loop on XLA:CPU)."""
    padded = jnp.concatenate([rows, jnp.zeros(rows.shape[:2] + (1,), rows.dtype)], -1)
    return jnp.take(padded, src, axis=2, mode="clip", unique_indices=False)


@_permute.defjvp
def _permute_jvp(primals, tangents):
    rows, src, dst = primals
    t = tangents[0]
    w = src.shape[0]
    out_t = jnp.zeros(rows.shape[:2] + (w,), rows.dtype).at[:, :, dst].add(t, mode="drop", unique_indices=True)
    return _permute(rows, src, dst), out_t


def packed(alive, rows, ids, width: int):
    """The samples ``alive (k,)`` of a sub-tile packed to the front of a block
    ``width >= k`` columns wide: rows ``(r, B, width)`` (``rows (r, B, k)``; zero past
    the live ones) and ids ``(width,)`` (``ids (k,)``; ``0`` past them), and the
    number of live samples."""
    src, dst, c = pack(alive, width)
    return _permute(rows, src, dst), jnp.take(ids, src, mode="fill", fill_value=0), c


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
