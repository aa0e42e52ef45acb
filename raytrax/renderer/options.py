"""Static options of one compiled render."""

from __future__ import annotations

import dataclasses

from ..scene import Settings

RAYS_PER_TILE = 16384
SUBTILE = 4096


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """Static options of one compiled render; each distinct value compiles once.

    - ``settings``: the scene's :class:`~raytrax.scene.Settings` with the overrides
      of :func:`raytrax.render` applied (size, spp, depth, shading...).
    - ``tile_rays``: camera rays per tile (``lax.map`` over tiles); reverse mode
      holds one tile's rays at a time, so memory scales with it.
    - ``subtile``: rays per sub-tile of the ray queue (the unit of skipping dead rays).
    - ``jitter``: samples are jittered inside their strata (a PRNG key was given).
    - ``devices``: number of devices the tiles are sharded over.
    - ``split_material_read``: read the material fields that decide a hit's children
      (transparency, reflectivity, ior) apart from those that only colour its own light,
      so that a ``jax.vmap`` over colours leaves every ray unbatched (one read is faster
      where nothing is batched).
    """

    settings: Settings
    tile_rays: int = RAYS_PER_TILE
    subtile: int = SUBTILE
    jitter: bool = False
    devices: int = 1
    split_material_read: bool = False
