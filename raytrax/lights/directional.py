"""Directional lights (a light at infinity, such as the sun): ``direction (L, 3)``,
``irradiance (L, 3)``."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import vec as V
from ..shapes.base import Key, check_shape
from .base import LightSample, LightSpec


class DirectionalLights(eqx.Module):
    """``L`` directional lights: ``direction (L, 3)``, the direction the light
    *travels* (any non-zero length; from the light towards the scene), and
    ``irradiance (L, 3)``.

    In ``physical`` shading ``irradiance`` is the irradiance in W/m^2 per channel on
    a surface facing the light (``E cos`` elsewhere, no falloff); in ``classic``
    shading it is the light's colour. Shadows are cast along the direction without
    end.
    """

    direction: Float[Array, "L 3"]
    irradiance: Float[Array, "L 3"]

    def __check_init__(self):
        n = self.direction.shape[0]
        check_shape("DirectionalLights.direction", self.direction, (n, 3))
        check_shape("DirectionalLights.irradiance", self.irradiance, (n, 3))


class DirectionalLightSpec(LightSpec):
    name: ClassVar[str] = "directional"
    field: ClassVar[str] = "directional_lights"
    builder: ClassVar[str] = "directional_light"
    module: ClassVar[type] = DirectionalLights
    keys: ClassVar[tuple] = (
        Key("direction", "direction", (3,), "nonzero3"),
        Key("irradiance", "irradiance", (3,), "rgb", default=(1.0, 1.0, 1.0)),
    )
    directional: ClassVar[bool] = True

    def check(self, p, where):
        if np.linalg.norm(p["direction"]) == 0:
            raise ValueError(f"{where}.direction: expected a non-zero vector")

    def sample(self, g, l, p):
        toward = V.normalize(jnp.broadcast_to(-g.direction[l][:, None], p.shape))
        inf = jnp.full(p.shape[1:], jnp.inf, p.dtype)
        return LightSample(toward, inf, g.irradiance[l], jnp.ones(p.shape[1:], p.dtype))

    def edge_geometry(self, g):
        return g.direction
