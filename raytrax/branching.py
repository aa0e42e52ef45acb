"""Branch predicates that stay branches under ``jax.vmap``.

A ``lax.cond`` whose predicate is batched becomes, under ``jax.vmap``, a select
that runs both branches for every batch member (and, under a later reverse-mode
transformation of a batched forward-mode rule, a ``stop_gradient`` that JAX
cannot transpose). The renderer's conds skip work that no ray needs (a sub-tile
past the live count, a kind that no ray hit, shadow rays when no ray faces a
light); their predicates come from :func:`any_in_batch`, so that under ``vmap``
the branch runs once for the whole batch when any member needs it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

YNN_MIN = 4096
"""Elements from which XLA:CPU hands a byte reduction to its YNNPACK library (below,
it emits the reduction itself, as the 32-wide windows that compile slowly)."""


def any_true(x, axis=None) -> jax.Array:
    """``jnp.any(x, axis)``, compiled cheaply: XLA:CPU rewrites a boolean reduction
    of more than 32 elements into 32-wide windows of ``i1`` vectors (up to 195 KB of
    LLVM IR each, 0.13 s to compile at 4096 elements), and a render holds dozens. A
    whole-array reduction is the maximum of the bytes, padded with zeros to
    :data:`YNN_MIN` elements (XLA then calls YNNPACK: 0.01 s); one along ``axis``
    is the bytes' maximum."""
    b = jnp.asarray(x).astype(jnp.uint8)
    if axis is None:
        b = b.reshape(-1)
        if 32 < b.shape[0] < YNN_MIN:
            b = jnp.concatenate([b, jnp.zeros((YNN_MIN - b.shape[0],), jnp.uint8)])
    return jnp.max(b, axis=axis, initial=0) > 0


def count_true(x, dtype=None) -> jax.Array:
    """``jnp.sum(x)`` of a boolean array (in ``dtype``; default: jax's default integer,
    as ``jnp.sum`` gives), compiled as :func:`any_true` is: a float32 sum (exact below
    2^24 elements), which XLA:CPU hands to YNNPACK from :data:`YNN_MIN` elements on,
    where an integer sum is emitted as 32-wide windows."""
    b = jnp.asarray(x).reshape(-1)
    dtype = jnp.sum(jnp.zeros((1,), bool)).dtype if dtype is None else dtype
    if b.shape[0] >= 2**24 or b.shape[0] <= 32:
        return jnp.sum(b, dtype=dtype)
    f = b.astype(jnp.float32)
    if b.shape[0] < YNN_MIN:
        f = jnp.concatenate([f, jnp.zeros((YNN_MIN - b.shape[0],), jnp.float32)])
    return jnp.sum(f).astype(dtype)


def all_true(x, axis=None) -> jax.Array:
    """``jnp.all(x, axis)``, compiled as :func:`any_true` is."""
    return ~any_true(~jnp.asarray(x, bool), axis)


@jax.custom_batching.custom_vmap
def any_in_batch(x):
    """``jnp.any(x)`` (a scalar bool); under ``jax.vmap`` the *unbatched* ``any``
    over the whole batch, so that a ``lax.cond`` on it stays a branch (run for
    every batch member when any needs it) instead of becoming a select that runs
    both sides."""
    return any_true(x)


@any_in_batch.def_vmap
def _any_in_batch_vmap(axis_size, in_batched, x):
    del axis_size, in_batched
    return any_true(x), False


def run_or_zeros(pred, fn, *args):
    """``fn(*args)`` where the scalar bool ``pred`` holds, else zeros shaped like its
    outputs (a ``lax.cond``). ``fn`` is traced once: the zeros' shapes come from the
    trace that the branch reuses (``jax.eval_shape`` of ``fn`` and a ``lax.cond`` on
    ``fn`` would trace it twice, seconds for a whole tracer)."""
    f = jax.jit(fn)
    shapes = jax.eval_shape(f, *args)
    return jax.lax.cond(
        pred, f, lambda *_: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes), *args
    )
