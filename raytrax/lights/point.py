"""Point lights: ``position (L, 3)``, ``intensity (L, 3)``."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float

from .. import vec as V
from ..shapes.base import Key, check_shape
from .base import LightSample, LightSpec


class PointLights(eqx.Module):
    """``L`` point lights: ``position (L, 3)`` in world units and ``intensity (L, 3)``.

    In ``classic`` shading ``intensity`` is the light's colour (no falloff); in
    ``physical`` shading it is the radiant intensity in W/sr per channel, and
    irradiance falls off as ``I cos / r^2``. Lights are invisible to camera and
    specular rays.
    """

    position: Float[Array, "L 3"]
    intensity: Float[Array, "L 3"]

    def __check_init__(self):
        n = self.position.shape[0]
        check_shape("PointLights.position", self.position, (n, 3))
        check_shape("PointLights.intensity", self.intensity, (n, 3))


class PointLightSpec(LightSpec):
    name: ClassVar[str] = "point"
    field: ClassVar[str] = "lights"
    builder: ClassVar[str] = "light"
    module: ClassVar[type] = PointLights
    keys: ClassVar[tuple] = (
        Key("position", "position", (3,), "vec3"),
        Key("intensity", "intensity", (3,), "rgb", default=(1.0, 1.0, 1.0)),
    )

    def sample(self, g, l, p):
        v = g.position[l][:, None] - p
        dist = V.norm(v)
        return LightSample(V.normalize(v), dist, g.intensity[l], V.safe_div(1.0, dist * dist))

    def edge_geometry(self, g):
        return g.position
