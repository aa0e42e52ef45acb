"""Splitting a batch axis into equal chunks and joining it back.

Every batched pass over many rays (render tiles, the edge term's records, its solve
chunks, its probes) runs chunk by chunk under ``lax.map`` or ``lax.scan``, so that
memory holds one chunk's intermediates. These helpers do the bookkeeping once: pad
the batch axis to ``n * size`` entries, move the chunk index to the front, and after
the map join the chunks and drop the padding. :func:`over_devices` splits the chunks
over devices (``jax.shard_map`` along the axis :data:`AXIS`).
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

AXIS = "tiles"  # the device axis of :func:`over_devices` (for collectives such as ``psum``)


def equal_chunks(m: int, most: int, multiple: int = 1) -> tuple[int, int]:
    """``(n, size)``: the fewest chunks (a multiple of ``multiple``) of at most ``most``
    entries that hold ``m`` entries, all of the same ``size`` (the padding is less
    than ``n``)."""
    n = math.ceil(max(1, m) / max(1, most) / multiple) * multiple
    return n, max(1, math.ceil(m / n))


def split(x, n: int, size: int, axis: int = -1, fill=None):
    """``x`` with its ``axis`` (``m <= n * size`` entries) padded to ``n * size`` and
    split into ``n`` chunks of ``size``, the chunk index moved to the front: ``(n, ...,
    size, ...)``. Padding repeats the last entry (``fill=None``: a valid input for
    any computation) or is ``fill``."""
    axis = axis % x.ndim
    m = x.shape[axis]
    if m > n * size:
        raise ValueError(f"split: {m} entries do not fit {n} chunks of {size}")
    pad = [(0, 0)] * x.ndim
    pad[axis] = (0, n * size - m)
    if n * size > m:
        x = jnp.pad(x, pad, mode="edge") if fill is None else jnp.pad(x, pad, constant_values=fill)
    x = x.reshape(x.shape[:axis] + (n, size) + x.shape[axis + 1 :])
    return jnp.moveaxis(x, axis, 0)


def join(y, m: int, axis: int = -1):
    """The inverse of :func:`split`: chunks ``(n, ..., size, ...)`` (``size`` at
    ``axis`` of each chunk) joined along ``axis`` and cut to its first ``m`` entries."""
    axis = axis % (y.ndim - 1)
    y = jnp.moveaxis(y, 0, axis)  # (..., n, size, ...)
    y = y.reshape(y.shape[:axis] + (y.shape[axis] * y.shape[axis + 1],) + y.shape[axis + 2 :])
    return jax.lax.slice_in_dim(y, 0, m, axis=axis)


def over_devices(run, n_dev: int, out_spec: str | None = AXIS):
    """``run(xs, const)`` with the pytree ``xs`` split along its leading axis (a
    multiple of ``n_dev``) over ``n_dev`` devices (``jax.shard_map`` over the mesh axis
    :data:`AXIS`) and ``const`` on every device; ``out_spec``: the output's partition,
    :data:`AXIS` (its leading axis, like ``xs``) or ``None`` (replicated: ``run`` sums
    over devices itself, e.g. ``jax.lax.psum(x, AXIS)``). ``n_dev <= 1``: ``run``."""
    if n_dev <= 1:
        return run
    from jax.sharding import PartitionSpec as Spec

    mesh = jax.make_mesh((n_dev,), (AXIS,), devices=jax.devices()[:n_dev], axis_types=(jax.sharding.AxisType.Auto,))
    return jax.shard_map(run, mesh=mesh, in_specs=(Spec(AXIS), Spec()), out_specs=Spec(out_spec), check_vma=False)


def round_robin(x, n_dev: int, back: bool = False):
    """Chunks ``(n, ...)`` reordered so that device ``d`` of :func:`over_devices` holds
    chunks ``d, d + n_dev, d + 2 n_dev...`` (``back``: the inverse order)."""
    a, b = (n_dev, x.shape[0] // n_dev) if back else (x.shape[0] // n_dev, n_dev)
    return jnp.swapaxes(x.reshape((a, b) + x.shape[1:]), 0, 1).reshape(x.shape)


def map_leading(fn, xs: Any, remat: bool = False):
    """``jax.lax.map(fn, xs)`` over the leading axis of the pytree ``xs`` (each call
    under ``jax.checkpoint`` with ``remat``, so that reverse mode holds one entry's
    intermediates at a time). A single entry is called directly: no loop, and
    nothing to recompute (reverse mode holds that entry's intermediates either way)."""
    tm = jax.tree_util.tree_map
    if jax.tree_util.tree_leaves(xs)[0].shape[0] == 1:
        return tm(lambda y: y[None], fn(tm(lambda x: x[0], xs)))
    return jax.lax.map(jax.checkpoint(fn) if remat else fn, xs)


def map_chunks(
    fn,
    xs: Any,
    m: int,
    n: int,
    size: int,
    in_axis: int = -1,
    out_axis: int = -1,
    devices: int = 1,
    deal: bool = False,
    const: Any = None,
):
    """``fn(chunk)`` (``fn(chunk, const)`` when ``const`` is given) over ``n`` chunks
    of ``size`` of the pytree ``xs`` (every leaf has ``m`` entries along ``in_axis``;
    padded by repeating the last) under ``lax.map``, its outputs (``size`` entries
    along ``out_axis``) joined and cut to ``m``.

    ``devices > 1`` (``n`` a multiple of it): the chunks split over that many devices
    (:func:`over_devices`), in contiguous blocks or, with ``deal``, dealt round-robin
    (for work packed at the front, such as compacted events). ``const`` is then on
    every device: pass there what ``fn`` needs of an array that another sharded map
    made (closing over it would mix two meshes)."""
    tm = jax.tree_util.tree_map
    chunks = tm(lambda x: split(x, n, size, in_axis), xs)

    def over(xs, c):
        return map_leading(fn if const is None else (lambda x: fn(x, c)), xs)

    if devices > 1:
        if n % devices:
            raise ValueError(f"map_chunks: {n} chunks do not split over {devices} devices")
        if deal:
            chunks = tm(lambda x: round_robin(x, devices), chunks)

        def gathered(xs, c):  # every device gets all chunks' outputs (see below)
            return tm(lambda y: jax.lax.all_gather(y, AXIS, tiled=True), over(xs, c))

        # The outputs come back replicated, not sharded: the bookkeeping that follows
        # (prefix sums, compaction over all entries) is then local to each device, where
        # XLA would otherwise partition a prefix sum over a sharded axis into a
        # reduce-window of the whole length per device (quadratic: 20 s of a 0.5 s render).
        out = over_devices(gathered, devices, None)(chunks, const)
        if deal:
            out = tm(lambda y: round_robin(y, devices, back=True), out)
    else:
        out = over(chunks, const)
    return tm(lambda y: join(y, m, out_axis), out)


def map_worklist(fn, spawn, xs: Any, n_live, n: int, size: int, devices: int = 1, const: Any = None):
    """:func:`map_chunks` over a work list that grows: ``fn(chunk, const) -> (out, aux)``
    over the ``n`` chunks of ``size`` entries of the pytree ``xs`` (every leaf has ``n *
    size`` entries along its last axis, the first ``n_live`` of them live), where after
    each chunk ``spawn(chunk, aux) -> (new (size,), entries)`` names entries to add to the
    list (``entries``: a pytree like ``chunk``, taken where ``new``). They are appended
    after the list's last entry, from the next chunk on, so that a later chunk of the
    same loop runs them (``fn`` is compiled once; an added entry may add more); those
    that find no room are dropped and counted. Chunks are not skipped here: ``fn``
    skips those without live entries itself.

    Returns ``fn``'s outputs ``out`` joined (``size`` entries along their last axis
    per chunk; ``aux`` goes to ``spawn`` only and is not kept), the final list (``xs``
    with the added entries in its free slots) and the number dropped. ``devices > 1``: the chunks dealt to the devices in turn (``n`` a multiple
    of ``devices``), each device adding to its own list in its own chunks."""
    tm = jax.tree_util.tree_map
    chunks = tm(lambda x: split(x, n, size), xs)  # (n, ..., size)

    def grow(chunks, c, live):
        k = jax.tree_util.tree_leaves(chunks)[0].shape[0]
        cap = k * size
        flat = tm(lambda x: jnp.moveaxis(x, 0, -2).reshape(x.shape[1:-1] + (cap,)), chunks)
        shapes = jax.eval_shape(fn, tm(lambda x: x[..., :size], flat), c)[0]
        outs = tm(lambda s: jnp.zeros(s.shape[:-1] + (cap,), s.dtype), shapes)

        def body(j, st):
            flat, outs, end, lost = st
            j = jnp.asarray(j, jnp.int32)
            chunk = tm(lambda x: jax.lax.dynamic_slice_in_dim(x, j * size, size, -1), flat)
            out, aux = fn(chunk, c)
            outs = tm(lambda o, y: jax.lax.dynamic_update_slice_in_dim(o, y, j * size, -1), outs, out)
            new, ent = spawn(chunk, aux)
            start = jnp.maximum(end, (j + 1) * size)
            rank = jnp.cumsum(new.astype(jnp.int32))
            pos = jnp.where(new, start + rank - 1, cap)
            flat = tm(lambda x, e: x.at[..., pos].set(e, mode="drop"), flat, ent)
            stop = start + rank[-1]
            return flat, outs, jnp.minimum(stop, cap), lost + jnp.maximum(stop - cap, 0)

        z = jnp.zeros((), jnp.int32)
        flat, outs, _, lost = jax.lax.fori_loop(0, k, body, (flat, outs, live, z))
        return outs, flat, lost

    n_live = jnp.asarray(n_live, jnp.int32)
    if devices <= 1:
        outs, flat, lost = grow(chunks, const, n_live)
        return outs, flat, lost
    if n % devices:
        raise ValueError(f"map_worklist: {n} chunks do not split over {devices} devices")
    # Device d holds chunks d, d + devices...: its live entries are a prefix of them.
    first = (
        jnp.arange(devices, dtype=jnp.int32)[:, None] + devices * jnp.arange(n // devices, dtype=jnp.int32)[None]
    ) * size
    per = jnp.sum(jnp.clip(n_live - first, 0, size), 1).astype(jnp.int32)

    def run(ch, c):
        cc, per = c
        outs, flat, lost = grow(ch, cc, per[jax.lax.axis_index(AXIS)])
        back = tm(lambda y: jax.lax.all_gather(y[None], AXIS, tiled=True), (outs, flat))
        return back, jax.lax.psum(lost, AXIS)[None]

    (outs, flat), lost = over_devices(run, devices, None)(tm(lambda x: round_robin(x, devices), chunks), (const, per))

    def redeal(y):  # (devices, ..., local list) -> the global list in chunk order
        y = y.reshape(y.shape[:-1] + (n // devices, size))  # (devices, ..., local chunks, size)
        y = jnp.moveaxis(y, -2, 1)  # (devices, local chunks, ..., size)
        y = y.reshape((n,) + y.shape[2:])  # device-major chunks
        y = round_robin(y, devices, back=True)
        return jnp.moveaxis(y, 0, -2).reshape(y.shape[1:-1] + (n * size,))

    return tm(redeal, outs), tm(redeal, flat), lost[0]
