"""Static options of one compiled render."""

from __future__ import annotations

import dataclasses

from ..scene import Settings

RAYS_PER_TILE = 16384
SUBTILE = 4096


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """Static options of one compiled render (see :class:`~raytrax.scene.Settings`)."""

    settings: Settings
    tile_rays: int = RAYS_PER_TILE
    subtile: int = SUBTILE
    jitter: bool = False
    devices: int = 1
