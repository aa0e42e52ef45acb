"""The light registry: every light type, in the order of the renderer's light loop
and of light indices in :mod:`raytrax.edges`. Adding a light type is one module
plus one entry here."""

from __future__ import annotations

from .base import LightSpec
from .directional import DirectionalLightSpec
from .point import PointLightSpec

LIGHTS: tuple[LightSpec, ...] = (PointLightSpec(), DirectionalLightSpec())
BY_NAME: dict[str, LightSpec] = {s.name: s for s in LIGHTS}
BY_FIELD: dict[str, LightSpec] = {s.field: s for s in LIGHTS}
LIGHT_TYPES: tuple[str, ...] = tuple(s.name for s in LIGHTS)
