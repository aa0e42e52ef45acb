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

from .masks import any_true


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


def run_or_zeros(pred, fn, *args, remat: bool = False):
    """``fn(*args)`` where the scalar bool ``pred`` holds, else zeros shaped like its
    outputs (a ``lax.cond``). ``fn`` is traced once: the zeros' shapes come from the
    trace that the branch reuses (``jax.eval_shape`` of ``fn`` and a ``lax.cond`` on
    ``fn`` would trace it twice, seconds for a whole tracer). ``remat``: ``fn`` under
    ``jax.checkpoint`` inside the branch, so that reverse mode stores only its inputs and
    a skipped call stores and recomputes nothing (a checkpoint around the cond would
    write zero residuals of all of ``fn`` for every skipped call)."""
    f = jax.jit(jax.checkpoint(fn) if remat else fn)
    shapes = jax.eval_shape(f, *args)
    return jax.lax.cond(
        pred, f, lambda *_: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes), *args
    )
