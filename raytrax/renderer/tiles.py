"""The image as tiles of camera samples: ``lax.map`` over tiles (each under
``jax.checkpoint``), optionally sharded over devices with ``jax.shard_map``."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from ..camera import primary_rays
from ..intersect import prepare
from ..scene import Scene
from .options import RenderOptions
from .whitted import trace


def render_image(scene: Scene, opts: RenderOptions, key):
    st = opts.settings
    W, H, spp = st.width, st.height, st.spp
    P = W * H
    tile = max(1, min(P, opts.tile_rays // spp))
    n_dev = opts.devices
    n_tiles = math.ceil(P / tile / n_dev) * n_dev
    pix = jnp.minimum(jnp.arange(n_tiles * tile, dtype=jnp.int32), P - 1).reshape(n_tiles, tile)
    ids = jnp.arange(n_tiles, dtype=jnp.int32)

    def run(scene, pix, ids, key):
        kinds = prepare(scene)

        def tile_fn(args):
            pix_t, i = args
            k = None if key is None else jax.random.fold_in(key, i)
            o, d, spread = primary_rays(scene.camera, pix_t, W, H, spp, k)
            rad = trace(scene, kinds, o, d, spread, opts)
            return rad.reshape(3, spp, tile).mean(1).T  # (tile, 3)

        return jax.lax.map(jax.checkpoint(tile_fn), (pix, ids))

    if n_dev > 1:
        from jax.sharding import PartitionSpec as Spec

        mesh = jax.make_mesh(
            (n_dev,), ("tiles",), devices=jax.devices()[:n_dev], axis_types=(jax.sharding.AxisType.Auto,)
        )
        run = jax.shard_map(
            run,
            mesh=mesh,
            in_specs=(Spec(), Spec("tiles"), Spec("tiles"), Spec()),
            out_specs=Spec("tiles"),
            check_vma=False,
        )
    out = run(scene, pix, ids, key)
    return out.reshape(n_tiles * tile, 3)[:P].reshape(H, W, 3)


render_image_jit = eqx.filter_jit(render_image)
