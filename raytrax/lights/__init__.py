"""Light types and their registry (:data:`raytrax.lights.registry.LIGHTS`): point
lights (:mod:`~raytrax.lights.point`) and directional lights
(:mod:`~raytrax.lights.directional`). Each module owns its light's geometry: the
direction towards it from a shading point, the shadow segment and the falloff."""

from .base import LightSample, LightSpec
from .directional import DirectionalLights
from .point import PointLights
from .registry import BY_FIELD, BY_NAME, LIGHT_TYPES, LIGHTS

__all__ = [
    "BY_FIELD",
    "BY_NAME",
    "LIGHTS",
    "LIGHT_TYPES",
    "DirectionalLights",
    "LightSample",
    "LightSpec",
    "PointLights",
]
