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
    transformation it is a plain zero; under ``jax.vmap`` it is batched where a leaf
    of ``tree`` is (as a carry computed from those leaves is)."""
    leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.inexact)]
    return _seed(jnp.dtype(dtype), *leaves)


def _zero_of(dtype, *xs):
    """``0`` of ``dtype`` computed from the first element of each of ``xs`` without
    arithmetic (an infinite or NaN value gives no NaN): batched where any of them is."""
    if not xs:
        return jnp.zeros((), dtype)
    first = jnp.concatenate([x.reshape(-1)[:1].astype(dtype) for x in xs])
    return jnp.sum(jnp.where(False, first, jnp.zeros_like(first)))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _seed(dtype, *leaves):
    # The value from every leaf: under jax.vmap it is batched where a leaf is, like the
    # tangent the rule below computes from them. (A zero unbatched value with a batched
    # tangent breaks the batching of a jitted function that is then differentiated.)
    return _zero_of(dtype, *leaves)


def _seed_jvp(dtype, primals, tangents):
    live = [t for t in tangents if not isinstance(t, SymbolicZero)]
    # jax calls the rule only when some tangent is live; from the first one.
    return _zero_of(dtype, *primals), _zero_of(dtype, *live[:1])


_seed.defjvp(_seed_jvp, symbolic_zeros=True)
