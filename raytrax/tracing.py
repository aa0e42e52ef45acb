"""Helpers that change what jax's transformations trace, not what a program computes."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero


def tangent_seed(tree, dtype):
    """A scalar ``0`` of ``dtype`` whose tangent, under ``jax.jvp``, ``jax.linearize``
    or ``jax.grad``, is (symbolically) non-zero wherever a float leaf of ``tree`` has
    a tangent; its value and its derivatives are zero.

    Added to the zero initial carry of a ``lax.scan``, it marks that carry as
    differentiated from the first pass over the loop body. A carry that starts as
    a symbolic zero and gains a tangent inside the body makes the scan trace its
    body a second time, and nested scans multiply these passes. Outside any
    transformation, and under ``jax.vmap``, it is a plain unbatched zero."""
    leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.inexact)]
    return _seed(jnp.dtype(dtype), *leaves)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _seed(dtype, *leaves):
    del leaves
    return jnp.zeros((), dtype)


def _seed_jvp(dtype, primals, tangents):
    del primals
    live = [t for t in tangents if not isinstance(t, SymbolicZero)]
    if not live:  # pragma: no cover - jax calls the rule only when some tangent is live
        return jnp.zeros((), dtype), jnp.zeros((), dtype)
    # zero, computed from one differentiated input without arithmetic (an infinite tangent gives no NaN)
    t = live[0].reshape(-1)[:1]
    return jnp.zeros((), dtype), jnp.sum(jnp.where(False, t, jnp.zeros_like(t))).astype(dtype)


_seed.defjvp(_seed_jvp, symbolic_zeros=True)
