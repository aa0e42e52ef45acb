"""The ray queue of the Whitted integrator: live samples packed at the front of a
fixed buffer, processed in sub-tiles, the sub-tiles past the live count skipped.

Layout. A depth's rays live in one flat buffer of ``S * m`` rays, cut into ``S``
sub-tiles of ``m`` rays. At depth 0 every ray is its own sample (the camera
rays, in order). At depth >= 1 a sample owns ``B`` rays (its specular
branches); sub-tile ``j`` holds the queue's samples ``j ns ... (j + 1) ns - 1``
(``ns = m / B``) slot-major, ``(B, ns)``, so every array keeps its ray axis
last and contiguous. A sample whose children all have zero weight is dropped;
the live ones are written (a scatter, only from live sub-tiles) to the next
queue positions in order, so the next depth's live rays again form a prefix.
No full-buffer gather or permutation happens per depth: the per-depth cost
beyond the live rays is one fill of the next buffer.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def to_tiles(a, S: int, m: int, fill):
    """``a ([r,] n)`` as ``S`` sub-tiles of ``m``: ``(S, [r,] m)``, padded with ``fill``."""
    n = a.shape[-1]
    a = jnp.concatenate([a, jnp.full(a.shape[:-1] + (S * m - n,), fill, a.dtype)], -1)
    return jnp.moveaxis(a.reshape(a.shape[:-1] + (S, m)), -2, 0)


def write_queue(bufs, q, alive, rows, ids):
    """Write the ``B`` rays of samples ``q (k,)`` (queue positions; only where
    ``alive``) into the next depth's buffers ``bufs = (rays (S, r, m), ids (S, m))``:
    ``rays <- rows (r, B, k)``, ``ids <- ids (B, k)``. Sub-tiles of ``m`` rays
    hold ``m / B`` samples slot-major (module docstring). One scatter per buffer,
    indexed by (sub-tile, column) with the ``r`` rows as its window."""
    buf, idbuf = bufs
    S, r, m = buf.shape
    B = rows.shape[1]
    ns = m // B
    nsq = jnp.asarray(ns, q.dtype)
    t = jnp.where(alive, jax.lax.div(q, nsq), S)  # S: out of bounds, dropped
    col = jax.lax.rem(q, nsq)[None] + (jnp.arange(B, dtype=q.dtype) * ns)[:, None]  # (B, k)
    tb = jnp.broadcast_to(t, col.shape).reshape(-1)
    col = col.reshape(-1)
    buf = buf.at[tb, :, col].set(rows.reshape(r, -1).T, mode="drop", unique_indices=True)
    idbuf = idbuf.at[tb, col].set(ids.reshape(-1), mode="drop", unique_indices=True)
    return buf, idbuf


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
