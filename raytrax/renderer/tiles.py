"""The image as tiles of camera samples: ``lax.map`` over tiles (each under
``jax.checkpoint``), optionally sharded over devices with ``jax.shard_map``."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from ..camera import primary_rays, rays_through
from ..intersect import prepare
from ..scene import Scene
from .options import RenderOptions
from .whitted import trace


def map_tiles(tile_fn, scene: Scene, xs, n_dev: int, const=None):
    """``tile_fn(scene, kinds, x, const)`` for every ``x`` along the leading axis of
    the pytree ``xs`` (``lax.map``, each tile under ``jax.checkpoint`` so that reverse
    mode holds one tile's rays at a time), sharded over ``n_dev`` devices
    (``jax.shard_map``; the number of tiles must be a multiple of ``n_dev``)."""

    def run(scene, xs, const):
        kinds = prepare(scene)
        return jax.lax.map(jax.checkpoint(lambda x: tile_fn(scene, kinds, x, const)), xs)

    if n_dev > 1:
        from jax.sharding import PartitionSpec as Spec

        mesh = jax.make_mesh(
            (n_dev,), ("tiles",), devices=jax.devices()[:n_dev], axis_types=(jax.sharding.AxisType.Auto,)
        )
        run = jax.shard_map(
            run, mesh=mesh, in_specs=(Spec(), Spec("tiles"), Spec()), out_specs=Spec("tiles"), check_vma=False
        )
    return run(scene, xs, const)


def render_image(scene: Scene, opts: RenderOptions, key):
    st = opts.settings
    W, H, spp = st.width, st.height, st.spp
    P = W * H
    tile = max(1, min(P, opts.tile_rays // spp))
    n_dev = opts.devices
    n_tiles = math.ceil(P / tile / n_dev) * n_dev
    pix = jnp.minimum(jnp.arange(n_tiles * tile, dtype=jnp.int32), P - 1).reshape(n_tiles, tile)
    ids = jnp.arange(n_tiles, dtype=jnp.int32)

    def tile_fn(scene, kinds, args, key):
        pix_t, i = args
        k = None if key is None else jax.random.fold_in(key, i)
        o, d, spread = primary_rays(scene.camera, pix_t, W, H, spp, k)
        rad = trace(scene, kinds, o, d, spread, opts)
        return rad.reshape(3, spp, tile).mean(1).T  # (tile, 3)

    out = map_tiles(tile_fn, scene, (pix, ids), n_dev, key)
    return out.reshape(n_tiles * tile, 3)[:P].reshape(H, W, 3)


def trace_positions(scene: Scene, opts: RenderOptions, xy, needed, spread):
    """Radiance ``(M, 3)`` of camera rays through image positions ``xy (2, M)`` (in
    pixels of an image of ``opts.settings``' size; see :func:`raytrax.camera.rays_through`),
    with cone spread ``spread``; in tiles of ``opts.tile_rays`` rays sharded over
    ``opts.devices``. ``needed (M,)`` (no gradient): a tile none of whose rays is
    needed is skipped (its radiance is 0)."""
    st = opts.settings
    M = xy.shape[1]
    c = max(1, min(M, opts.tile_rays))
    n_tiles = math.ceil(M / c / opts.devices) * opts.devices
    pad = n_tiles * c - M
    xyt = jnp.pad(xy, ((0, 0), (0, pad)), mode="edge").reshape(2, n_tiles, c).transpose(1, 0, 2)
    live = jnp.any(jnp.pad(needed, (0, pad)).reshape(n_tiles, c), 1)

    def tile_fn(scene, kinds, args, spread):
        x, on = args

        def run(x):
            o, d = rays_through(scene.camera, x, st.width, st.height)
            return trace(scene, kinds, o, d, spread, opts).T

        return jax.lax.cond(on, run, lambda x: jnp.zeros((c, 3), scene.dtype), x)

    out = map_tiles(tile_fn, scene, (xyt, live), opts.devices, spread)
    return out.reshape(n_tiles * c, 3)[:M]


render_image_jit = eqx.filter_jit(render_image)
