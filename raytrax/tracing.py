"""Helpers that change what jax's transformations trace, not what a program computes."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name
from jax.custom_derivatives import SymbolicZero

KEPT = "raytrax_search"
"""The ``jax.ad_checkpoint.checkpoint_name`` of the values that the integrator's shading
checkpoint keeps for reverse mode instead of recomputing them: the search's results and,
where a table is larger than the batch of rays, the rays' rows of it (primitives, texels),
so that reverse mode keeps those rather than the whole table once per batch and depth."""


def kept_rows(rows, table_rows: int, n: int):
    """``rows`` gathered for a batch of ``n`` rays from a table of ``table_rows`` rows,
    named :data:`KEPT` where the table is larger than the batch: reverse mode under the
    integrator's shading checkpoint then keeps the rays' rows, not the whole table once
    per batch of rays and depth to gather from again (36 MB each time for a mesh of 10^6
    triangles, 75 MB a call for a 512 x 512 texture at 256 x 256)."""
    return checkpoint_name(rows, KEPT) if table_rows > n else rows


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
    return _seed(jnp.dtype(dtype), *_float_leaves(tree))


def _float_leaves(tree):
    return [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.inexact)]


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


def zero_batched_as(tree, dtype):
    """A scalar ``0`` of ``dtype`` batched under ``jax.vmap`` wherever a float leaf of
    ``tree`` is (no gradient; computed without arithmetic, so a NaN or infinite leaf
    gives no NaN). Added to a value that a ``jax.custom_jvp`` rule computes from
    nothing, it makes that value batched as the rule's derivative is."""
    return jax.lax.stop_gradient(_zero_of(jnp.dtype(dtype), *_float_leaves(tree)))


def split_live(primals, tangents):
    """The arguments of a ``jax.custom_jvp`` rule defined with ``symbolic_zeros=True``
    split by whether their leaves have a tangent: ``(tdef, on, live, live_tangents,
    dead)``, the primals' tree structure, a flag per leaf (a tuple), the leaves with a
    tangent and their tangents, and the others. :func:`join_live` puts them back
    together, so that a rule can differentiate with respect to the live leaves alone
    (no tangent of the others is computed, stored or transposed)."""
    leaves, tdef = jax.tree.flatten(primals)
    t_leaves = jax.tree.leaves(tangents, is_leaf=lambda t: isinstance(t, SymbolicZero))
    on = tuple(not isinstance(t, SymbolicZero) for t in t_leaves)
    live = [x for x, o in zip(leaves, on) if o]
    live_t = [t for t, o in zip(t_leaves, on) if o]
    dead = [x for x, o in zip(leaves, on) if not o]
    return tdef, on, live, live_t, dead


def join_live(tdef, on, live, dead):
    """The primals that :func:`split_live` split, from ``live`` and ``dead`` leaves."""
    it, rest = iter(live), iter(dead)
    return jax.tree.unflatten(tdef, [next(it) if o else next(rest) for o in on])
