"""Point lights."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float


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
        if self.position.shape != (n, 3) or self.intensity.shape != (n, 3):
            raise ValueError(
                f"PointLights: expected position and intensity of shape (L, 3), got "
                f"{self.position.shape} and {self.intensity.shape}"
            )
