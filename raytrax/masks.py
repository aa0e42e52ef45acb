"""Reductions of boolean masks that XLA:CPU compiles cheaply.

A render holds dozens of reductions over a few thousand rays (is any ray left,
how many are alive, which ones). XLA:CPU rewrites a boolean or integer reduction
of more than 32 elements into 32-wide reduce-windows, which LLVM turns into up to
200 KB of IR each (0.05-0.13 s to compile one, where the empty program takes
0.016 s), and ``jnp.nonzero`` with a ``size`` compiles in 0.17 s. The versions
here give the same values (tests/test_masks.py) and compile in 0.01-0.07 s: bytes
or float32 reduced by the YNNPACK library (which XLA calls from :data:`YNN_MIN`
elements on), small masks (up to :data:`SMALL_MAX` elements) in rows of 32 bytes or
integers, and one prefix sum and scatter for the indices.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

YNN_MIN = 4096
"""Elements from which XLA:CPU hands a byte reduction to its YNNPACK library (below,
it emits the reduction itself, as the 32-wide windows that compile slowly)."""


def _default_int():
    """jax's default integer dtype (int64 with x64 enabled, else int32), as ``jnp.sum``
    of a boolean array and ``jnp.nonzero`` give."""
    return jax.dtypes.canonicalize_dtype(jnp.int_)


def _pad_for_ynn(x):
    """A flat ``x`` of 33 to ``YNN_MIN - 1`` elements padded with zeros to
    :data:`YNN_MIN` (so that XLA:CPU reduces it with YNNPACK); others unchanged."""
    n = x.shape[0]
    if 32 < n < YNN_MIN:
        x = jnp.concatenate([x, jnp.zeros((YNN_MIN - n,), x.dtype)])
    return x


SMALL_MAX = 512
"""Up to this many elements (flat) a mask is reduced in rows of 32 (:func:`_rows_of_32`),
not padded for YNNPACK: as cheap to compile, and the library call's overhead is most of
the cost of so small a reduction (the edge finder reduces masks of 128-512 entries
thousands of times per call)."""


def _rows_of_32(x, op):
    """``op`` (``jnp.max`` or ``jnp.sum``) of a flat ``x`` as reductions of at most 32
    elements each (rows of 32, zero-padded, then the rows' results), which XLA:CPU
    emits as plain loops."""
    while x.shape[0] > 32:
        n = x.shape[0]
        r = -(-n // 32)
        if r * 32 > n:
            x = jnp.concatenate([x, jnp.zeros((r * 32 - n,), x.dtype)])
        x = op(x.reshape(r, 32), axis=1)
    return op(x)


def any_true(x, axis=None) -> jax.Array:
    """``jnp.any(x, axis)``, compiled cheaply: XLA:CPU rewrites a boolean reduction
    of more than 32 elements into 32-wide windows of ``i1`` vectors (up to 195 KB of
    LLVM IR each, 0.13 s to compile at 4096 elements), and a render holds dozens. A
    whole-array reduction is the maximum of the bytes: in rows of 32 up to
    :data:`SMALL_MAX` elements, else padded with zeros to :data:`YNN_MIN` elements
    (XLA then calls YNNPACK: 0.01 s); one along ``axis`` is the bytes' maximum."""
    b = jnp.asarray(x).astype(jnp.uint8)
    if axis is None:
        b = b.reshape(-1)
        if 32 < b.shape[0] <= SMALL_MAX:
            return _rows_of_32(b, jnp.max) > 0
        b = _pad_for_ynn(b)
    return jnp.max(b, axis=axis, initial=0) > 0


def count_true(x, dtype=None) -> jax.Array:
    """``jnp.sum(x)`` of a boolean array (in ``dtype``; default: jax's default integer,
    as ``jnp.sum`` gives), compiled as :func:`any_true` is: up to :data:`SMALL_MAX`
    elements an integer sum in rows of 32, beyond a float32 sum (exact below 2^24
    elements), which XLA:CPU hands to YNNPACK from :data:`YNN_MIN` elements on, where
    an integer sum is emitted as 32-wide windows."""
    b = jnp.asarray(x).reshape(-1)
    dtype = _default_int() if dtype is None else dtype
    if b.shape[0] >= 2**24 or b.shape[0] <= 32:
        return jnp.sum(b, dtype=dtype)
    if b.shape[0] <= SMALL_MAX:
        return _rows_of_32(b.astype(jnp.int32), jnp.sum).astype(dtype)
    return jnp.sum(_pad_for_ynn(b.astype(jnp.float32))).astype(dtype)


def all_true(x, axis=None) -> jax.Array:
    """``jnp.all(x, axis)``, compiled as :func:`any_true` is."""
    return ~any_true(~jnp.asarray(x, bool), axis)


PREFIX_ROW = 64
"""Row length of :func:`prefix_count`'s two-level sum."""


def _prefix_sum(x):
    """Inclusive prefix sum of the float32 counts ``x (n,)``, exact below 2^24."""
    (n,) = x.shape
    R = PREFIX_ROW
    rows = -(-n // R)
    if rows * R > n:
        x = jnp.concatenate([x, jnp.zeros((rows * R - n,), x.dtype)])
    i = jnp.arange(R)
    upper = (i[:, None] <= i[None, :]).astype(x.dtype)  # (R, R): column c sums entries 0..c
    hi = jax.lax.Precision.HIGHEST
    within = jnp.dot(x.reshape(rows, R), upper, precision=hi)  # (rows, R)
    totals = within[:, -1]
    if rows <= 4 * R:
        r = jnp.arange(rows)
        before = (r[:, None] < r[None, :]).astype(x.dtype)  # (rows, rows): the rows above each
        offset = jnp.dot(totals, before, precision=hi)
    else:  # the rows' own prefix sum, one level up
        offset = _prefix_sum(totals) - totals
    return (within + offset[:, None]).reshape(rows * R)[:n]


def prefix_count(mask) -> jax.Array:
    """``jnp.cumsum(mask, dtype=jnp.int32)`` of a 1-D boolean ``mask``: the number of
    true entries up to and including each position. As small matrix products in
    float32 (exact: counts below 2^24), rows of :data:`PREFIX_ROW` entries summed
    within each row, then the rows' totals summed before each row (one more level
    above 16,384 entries). XLA:CPU calls a library for the products, where it emits
    ``jnp.cumsum`` as three levels of reduce-windows: at 4,096 entries 0.055 s to
    compile against 0.084 s, and 44 us a call against 112 us."""
    (n,) = mask.shape
    if n < 2 * PREFIX_ROW or n >= 2**24:
        return jnp.cumsum(mask, dtype=jnp.int32)
    return _prefix_sum(mask.astype(jnp.float32)).astype(jnp.int32)


def pack_map(mask, size: int, fill_value: int = 0, dtype=None):
    """Where the true entries of a 1-D ``mask (k,)`` go when packed to the front of
    ``size`` slots: ``src (size,)``, the index of the entry each slot receives (the true
    entries in order, then ``fill_value``), ``dst (k,)``, the slot of each entry
    (``size`` where false, ``size`` or more past the last slot), and the number of true entries
    (``int32``). ``dtype``: of ``src`` (default: jax's default integer). One prefix
    sum (:func:`prefix_count`) and one scatter."""
    (k,) = mask.shape
    dtype = _default_int() if dtype is None else dtype
    rank = prefix_count(mask)  # its last entry is the count
    dst = jnp.where(mask, rank - 1, size)  # past the end: dropped by the scatter
    src = jnp.full((size,), fill_value, dtype).at[dst].set(jnp.arange(k, dtype=dtype), mode="drop", unique_indices=True)
    return src, dst, rank[-1]


def true_indices(mask, size: int, fill_value: int = 0, dtype=None) -> jax.Array:
    """``jnp.nonzero(mask, size=size, fill_value=fill_value)[0]`` for a 1-D ``mask``:
    the indices where it holds, in order, then ``fill_value`` (``dtype``: default
    jax's default integer, as ``jnp.nonzero`` gives). The ``src`` of :func:`pack_map`
    (``jnp.nonzero`` compiles about twice as long and runs no faster)."""
    return pack_map(mask, size, fill_value, dtype)[0]
