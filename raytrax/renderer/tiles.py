"""The image as tiles of camera samples: ``lax.map`` over tiles (each under
``jax.checkpoint``), optionally sharded over devices with ``jax.shard_map``."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from ..branching import run_or_zeros
from ..camera import cone_spread, sample_positions
from ..chunks import AXIS, equal_chunks, map_leading, over_devices, round_robin, split
from ..compile_options import filter_jit
from ..intersect import prepare
from ..masks import any_true
from ..scene import Scene
from ..tracing import join_live, split_live, tangent_seed
from .options import RenderOptions
from .whitted import ray_part, trace


def map_tiles(tile_fn, scene: Scene, xs, n_dev: int, const=None):
    """``tile_fn(scene, kinds, x, const)`` for every ``x`` along the leading axis of
    the pytree ``xs`` (``lax.map``, each tile under ``jax.checkpoint`` so that reverse
    mode holds one tile's rays at a time; a single tile per device is neither looped
    over nor recomputed), sharded over ``n_dev`` devices
    (``jax.shard_map``; the number of tiles must be a multiple of ``n_dev``). The
    tiles are dealt to the devices in turn (device ``d`` renders tiles ``d, d + n_dev,
    ...``), so that an image region of costly rays (glass, mirrors) is shared."""

    def run(xs, scene_const):
        scene, const = scene_const
        kinds = prepare(scene)
        return map_leading(lambda x: tile_fn(scene, kinds, x, const), xs, remat=True)

    if n_dev <= 1:
        return run(xs, (scene, const))
    out = over_devices(run, n_dev)(jax.tree.map(lambda x: round_robin(x, n_dev), xs), (scene, const))
    return jax.tree.map(lambda y: round_robin(y, n_dev, back=True), out)


def _render_image(scene: Scene, opts: RenderOptions, key):
    st = opts.settings
    W, H, spp = st.width, st.height, st.spp
    P = W * H
    n_dev = opts.devices
    # The fewest tiles of at most tile_rays rays, a multiple of the devices, all of one size.
    n_tiles, tile = equal_chunks(P, max(1, opts.tile_rays // spp), n_dev)
    pix = split(jnp.arange(P, dtype=jnp.int32), n_tiles, tile)  # the last pixel repeated as padding
    ids = jnp.arange(n_tiles, dtype=jnp.int32)

    def tile_fn(scene, kinds, args, key):
        pix_t, i = args
        k = None if key is None else jax.random.fold_in(key, i)
        xy = sample_positions(pix_t, W, spp, scene.dtype, k)
        rad = trace(scene, kinds, xy, cone_spread(scene.camera, H, math.isqrt(spp)), opts)
        return rad.reshape(3, spp, tile).mean(1).T  # (tile, 3)

    out = map_tiles(tile_fn, scene, (pix, ids), n_dev, key)
    return out.reshape(n_tiles * tile, 3)[:P].reshape(H, W, 3)


def splat_positions(scene: Scene, opts: RenderOptions, xy, needed, spread, pixel, weight, n_pixels: int):
    """``sum_m weight[m, k] f_m`` at ``pixel[m]``: images ``(k, n_pixels, 3)`` made of
    the radiance ``f_m`` of camera rays through image positions ``xy (2, M)`` (in
    pixels of an image of ``opts.settings``' size; see
    :func:`raytrax.camera.rays_through`) with cone spread ``spread``; ``pixel (M,)``
    flat indices, ``weight (M, k)`` (no gradient). The rays are traced in tiles of
    ``opts.tile_rays`` (each under ``jax.checkpoint`` where there are several) sharded over
    ``opts.devices``, and each tile is added into the images as it is traced, so
    that memory holds the images and one tile, not every ray's radiance. ``needed
    (M,)`` (no gradient): a tile none of whose rays is needed is skipped."""
    M, k = weight.shape
    n_dev = opts.devices
    # The fewest equal tiles (a multiple of the devices), dealt to the devices in turn:
    # the rays come in runs of like cost (the grid's samples, then the quadrature's,
    # the live ones first), and the tiles past the live ones are skipped.
    n_tiles, c = equal_chunks(M, opts.tile_rays, n_dev)
    xyt = split(xy, n_tiles, c)
    live = any_true(split(needed, n_tiles, c, fill=False), 1)
    pix = split(pixel, n_tiles, c, fill=0)
    wt = split(weight, n_tiles, c, axis=0, fill=0)
    if n_dev > 1:
        xyt, live, pix, wt = (round_robin(x, n_dev) for x in (xyt, live, pix, wt))

    def run(xs, scene_spread):
        scene, spread = scene_spread
        kinds = prepare(scene)

        several = xs[0].shape[0] > 1  # one tile (per device): no loop, and nothing to recompute in reverse mode

        def radiance(x, on):
            def go(x):
                return trace(scene, kinds, x, spread, opts).T

            return run_or_zeros(on, go, x, remat=several)

        def tile(acc, args):
            x, on, p, w = args
            f = radiance(x, on)  # (c, 3)
            # The k weighted copies stacked: reverse mode then sums their cotangents
            # elementwise (a product broadcast over the k images transposes into a
            # reduction over them, a slow kernel on XLA:CPU).
            upd = jnp.stack([w[:, j, None] * f for j in range(k)])  # (k, c, 3)
            return acc.at[:, p].add(upd), None

        acc0 = jnp.zeros((k, n_pixels, 3), scene.dtype) + tangent_seed(scene, scene.dtype)
        if several:
            acc, _ = jax.lax.scan(tile, acc0, xs)
        else:
            acc, _ = tile(acc0, jax.tree.map(lambda x: x[0], xs))
        return jax.lax.psum(acc, AXIS) if n_dev > 1 else acc

    return over_devices(run, n_dev, None)((xyt, live, pix, wt), (scene, spread))


def _only_shading_batched(in_batched) -> bool:
    """Whether the flagged leaves (``in_batched``: flags of ``(scene, key)``, the batched
    leaves or those with a tangent) are all lights, the environment or
    :data:`raytrax.materials.COLOUR_FIELDS`: then the camera, reflected and refracted
    rays, their hits and branches are the same for the whole batch (have no tangent),
    and only the radiance (and a light's shadow rays) differs."""
    scene_b, key_b = in_batched
    rest = ray_part(scene_b)
    return not any(jax.tree.leaves((rest, key_b)))


def _shading_options(opts: RenderOptions, flags) -> RenderOptions:
    """``opts`` for a render whose leaves ``flags`` marks (``flags`` of ``(scene, key)``,
    as :func:`_only_shading_batched` takes them) are batched or differentiated: where
    they only colour a hit (:func:`_only_shading_batched`) and material fields are among
    them, the colours are read apart from the fields that decide a hit's children, so
    that the rays stay unflagged (unbatched, without a tangent); else ``opts`` unchanged."""
    if _only_shading_batched(flags) and any(jax.tree.leaves(flags[0].materials)):
        return dataclasses.replace(opts, split_material_read=True)
    return opts


def _jvp_of_live(opts: RenderOptions, tdef, on, live_p, live_t, dead):
    """JVP of the plain render of ``(scene, key)`` (flattened as ``tdef``) along the
    leaves that ``on`` marks (``live_p``, tangents ``live_t``); the other leaves
    (``dead``) stay constants: no tangent is computed, stored or transposed for them."""

    def of_live(*live):
        scene, key = join_live(tdef, on, live, dead)
        return _render_image(scene, opts, key)

    return jax.jvp(of_live, tuple(live_p), tuple(live_t))


def render_image(scene: Scene, opts: RenderOptions, key):
    """The ``(H, W, 3)`` image of ``scene`` (the tiles of :func:`map_tiles`).

    Under ``jax.vmap`` a batch whose only batched leaves colour what a hit
    sends to the camera (lights, the environment,
    :data:`raytrax.materials.COLOUR_FIELDS`) is batched inside (camera, reflected
    and refracted rays, their hits and branches are shared by the batch); any
    other batch is rendered as a ``lax.map`` of single renders, which costs
    per image what a loop of renders costs, where batching every ray costs
    about twice as much (the dead-ray skipping and the queue's scatters run for
    the whole batch). Derivatives go through the plain render (a
    ``jax.custom_jvp`` whose rule is the render's own JVP), so ``jax.grad``,
    ``jax.jacfwd`` and their ``vmap`` are those of the plain render.

    The render and its JVP rule are each a jitted function, called by these
    rules: under ``jax.grad`` (eager or inside a ``jax.jit``) only the JVP rule is
    traced, where a jitted whole would be traced for its primal first, then for
    its JVP when linearised. Outside any transformation call
    :func:`render_image_jit` (compiled with raytrax's compiler options)."""

    def plain(scene, key):
        return _render_image_jit(scene, opts, key)

    @jax.custom_batching.custom_vmap
    def batch_aware(scene, key):
        return plain(scene, key)

    @batch_aware.def_vmap
    def _batched(axis_size, in_batched, scene, key):
        if _only_shading_batched(in_batched):
            axes = jax.tree.map(lambda b: 0 if b else None, in_batched)
            inside = _shading_options(opts, in_batched)  # else one batched table read batches every ray
            return jax.vmap(lambda s, k: _render_image_jit(s, inside, k), in_axes=axes)(scene, key), True
        leaves, tdef = jax.tree.flatten((scene, key))
        flags = jax.tree.leaves(in_batched)

        def one(batched_leaves):
            it = iter(batched_leaves)
            return plain(*jax.tree.unflatten(tdef, [next(it) if f else x for x, f in zip(leaves, flags)]))

        return jax.lax.map(one, [x for x, f in zip(leaves, flags) if f]), True

    @jax.custom_jvp
    def image(scene, key):
        return batch_aware(scene, key)

    def _image_jvp(primals, tangents):
        # Only the leaves with a tangent are differentiated: the others (symbolic
        # zeros) stay constants of the JVP.
        tdef, on, live_p, live_t, dead = split_live(primals, tangents)
        # Where only colours (and lights, the environment) have a tangent, the rays
        # gain none (read as a batch over colours is, above).
        flags = jax.tree.unflatten(tdef, list(on))
        return _jvp_of_live_jit(_shading_options(opts, flags), tdef, on, live_p, live_t, dead)

    image.defjvp(_image_jvp, symbolic_zeros=True)

    return image(scene, key)


render_image_jit = filter_jit(render_image)
_render_image_jit = filter_jit(_render_image)
_jvp_of_live_jit = filter_jit(_jvp_of_live)
