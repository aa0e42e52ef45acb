"""Skipping dead rays: live rays moved to the front (a stable partition, no sort) and
processed in sub-tiles, a sub-tile without a live ray skipped."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def permutation(active):
    """Stable partition of ``active (n,)``: ``order (n,)`` lists the live rays first
    (each group in its original order), ``dest (n,)`` is its inverse (the slot of
    each ray). Two cumulative sums and one scatter: no sort."""
    n = active.shape[0]
    live = jnp.cumsum(active, dtype=jnp.int32)
    dest = jnp.where(active, live - 1, live[-1] + jnp.arange(n, dtype=jnp.int32) - live)
    order = jnp.zeros((n,), jnp.int32).at[dest].set(jnp.arange(n, dtype=jnp.int32), unique_indices=True)
    return order, dest


def take_unique(a, idx):
    """``a[..., idx]`` for indices without repeats: the transpose is then a scatter
    with ``unique_indices`` (no collisions to combine)."""
    return a.at[..., idx].get(unique_indices=True, mode="promise_in_bounds")


def compact_map(fn, args, active, sub):
    """Apply ``fn`` to the rays of ``args`` (arrays with the ray axis last) but skip
    sub-tiles of ``sub`` rays that hold no ``active`` ray: live rays are moved to
    the front first (a stable partition, no sort). Returns ``fn``'s outputs in the
    original ray order."""
    n = active.shape[0]
    shapes = jax.eval_shape(fn, *args)
    if n <= sub:
        zeros = lambda *a: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return jax.lax.cond(jnp.any(active), fn, zeros, *args)
    S = math.ceil(n / sub)
    pad = S * sub - n
    if pad:  # padding rays: inactive, so they sort to the end
        active = jnp.concatenate([active, jnp.zeros((pad,), bool)])
        args = jax.tree_util.tree_map(lambda a: jnp.pad(a, [(0, 0)] * (a.ndim - 1) + [(0, pad)]), args)
    order, dest = permutation(active)
    act = jnp.arange(S * sub, dtype=jnp.int32) < jnp.sum(active, dtype=jnp.int32)

    def split(a):
        a = take_unique(a, order)
        a = a.reshape(a.shape[:-1] + (S, sub))
        return jnp.moveaxis(a, -2, 0)

    sub_args = jax.tree_util.tree_map(split, args)
    sub_act = act.reshape(S, sub)
    sub_shapes = jax.eval_shape(fn, *jax.tree_util.tree_map(lambda a: a[0], sub_args))

    def zeros(*a):
        return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), sub_shapes)

    def one(x):
        a, live = x
        return jax.lax.cond(live[0], fn, zeros, *a)

    outs = jax.lax.map(one, (sub_args, sub_act))
    dest_n = dest[:n]

    def merge(a):
        a = jnp.moveaxis(a, 0, -2)
        a = a.reshape(a.shape[:-2] + (S * sub,))
        return take_unique(a, dest_n)

    return jax.tree_util.tree_map(merge, outs)
