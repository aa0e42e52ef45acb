"""Small vector helpers on component-major arrays.

Every vector here has its three components on the *leading* axis: a batch of
``n`` points is an array of shape ``(3, n)``. Dot products are then three
multiply-adds over contiguous rows, which XLA:CPU vectorises far better than a
reduction over a trailing axis of length 3.

All helpers are NaN-free in value and in derivative: square roots, divisions
and normalisations use the double-``where`` pattern, so a zero vector or a
negative radicand gives a finite value and a zero (not NaN) gradient.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def min_argmin(x):
    """Minimum of ``x (n, k)`` along its last axis and the first index where it is
    reached, ``(n,)`` and ``(n,)`` int32, as ``jnp.min`` and ``jnp.argmin`` give them
    (ties go to the lowest index). Two plain reductions: XLA:CPU does not vectorise
    the (value, index) reduction of ``argmin``, which ran twice as slow as both of
    these in the intersection search. Where a row holds NaN the index is ``k - 1``."""
    m = jnp.min(x, -1)
    k = x.shape[-1]
    cols = jnp.arange(k, dtype=jnp.int32)
    i = jnp.min(jnp.where(x == m[..., None], cols, k - 1), -1)
    return m, i


def xyz(a):
    """The components of ``a (3, ...)``: three arrays ``(...)``. One ``unstack``, whose
    transpose is a ``stack``: indexing ``a[0]``, ``a[1]``, ``a[2]`` transposes into
    three padded copies summed, which XLA:CPU fuses into kernels that recompute their
    inputs once per component."""
    return jax.lax.unstack(a)


def dot(a, b):
    """Dot product over the leading axis: ``(3, ...) x (3, ...) -> (...)``."""
    ax, ay, az = xyz(a)
    bx, by, bz = xyz(b)
    return ax * bx + ay * by + az * bz


def cross(a, b):
    """Cross product over the leading axis."""
    ax, ay, az = xyz(a)
    bx, by, bz = xyz(b)
    return jnp.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


def safe_sqrt(x, tiny=0.0):
    """``sqrt(max(x, 0))`` with a finite gradient everywhere (zero where ``x <= tiny``)."""
    ok = x > tiny
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def safe_div(num, den, tiny=1e-30):
    """``num / den`` where ``|den| > tiny``, else 0; finite gradient everywhere."""
    ok = jnp.abs(den) > tiny
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def norm(a):
    """Euclidean length over the leading axis, gradient 0 at the zero vector."""
    return safe_sqrt(dot(a, a))


def normalize(a, fallback=None):
    """Unit vector along ``a``; the zero vector maps to ``fallback`` (default zero)."""
    n2 = dot(a, a)
    ok = n2 > 1e-30
    inv = jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0)
    out = a * inv[None]
    if fallback is not None:
        out = jnp.where(ok[None], out, fallback)
    return out


def reflect(d, n):
    """Mirror direction of ``d`` about the (unit) normal ``n``."""
    return d - 2.0 * dot(d, n)[None] * n


def safe_pow(x, p):
    """``max(x, 0) ** p`` with finite gradients for any ``p > 0``."""
    ok = x > 0
    return jnp.where(ok, jnp.where(ok, x, 1.0) ** p, 0.0)


def safe_atan2(y, x):
    """``atan2`` with a zero (not NaN) gradient at the origin."""
    ok = (jnp.abs(x) + jnp.abs(y)) > 0
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0.0), jnp.where(ok, x, 1.0)), 0.0)


def vsel(mask, a, b):
    """Select vectors ``(3, n)`` by a per-ray mask ``(n,)``."""
    return jnp.where(mask[None], a, b)


SELECT_GATHER = 8  # tables of at most this many rows are read by selects


def take_rows(table, idx):
    """Rows ``table[idx]`` of a small parameter table ``(N, k)`` (or ``(N,)``) at
    per-ray indices ``idx (n,)``, component-major: ``(k, n)`` (or ``(n,)``).

    For up to :data:`SELECT_GATHER` rows this is a chain of selects: elementwise,
    so XLA:CPU vectorises it and its transpose is a masked sum over rays instead
    of a scatter-add; one row is a broadcast. Larger tables use a gather.
    """
    flat = table.ndim == 1
    tab = table[:, None] if flat else table
    N, k = tab.shape
    if N > SELECT_GATHER:
        out = tab.at[idx].get(mode="promise_in_bounds").T
    else:
        cols = []
        for j in range(k):
            v = jnp.broadcast_to(tab[0, j], idx.shape)
            for m in range(1, N):
                v = jnp.where(idx == m, tab[m, j], v)
            cols.append(v)
        out = jnp.stack(cols)
    return out[0] if flat else out


def gather_rows(table, i):
    """Rows ``table[i]`` of ``table (N, k)`` at ``i (n,)`` as a list of ``k`` arrays ``(n,)``.

    For a few primitives this is a chain of selects (elementwise; its transpose is a
    masked sum instead of a scatter-add), for one a broadcast; else a gather per
    column (struct of arrays)."""
    N, k = table.shape
    if N == 1:
        return [jnp.broadcast_to(table[0, j], i.shape) for j in range(k)]
    if N <= SELECT_GATHER:
        out = []
        for j in range(k):
            v = jnp.broadcast_to(table[0, j], i.shape)
            for m in range(1, N):
                v = jnp.where(i == m, table[m, j], v)
            out.append(v)
        return out
    return [table[:, j].at[i].get(mode="promise_in_bounds") for j in range(k)]
