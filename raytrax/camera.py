"""Pinhole camera and stratified primary rays."""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from . import vec as V


class Camera(eqx.Module):
    """A pinhole camera.

    ``position (3,)``, ``look_at (3,)``, ``up (3,)`` in world units and ``fov ()``
    the *vertical* field of view in degrees. The seed raytracer's image plane,
    20 x 20 at distance 40, is ``fov = 2 atan(10 / 40) = 28.0725`` degrees.
    Image convention: row 0 is the top row; the camera's right (+x) is to the
    right of the image.
    """

    position: Float[Array, 3]
    look_at: Float[Array, 3]
    up: Float[Array, 3]
    fov: Float[Array, ""]

    def __check_init__(self):
        for name in ("position", "look_at", "up"):
            if getattr(self, name).shape != (3,):
                raise ValueError(f"Camera.{name}: expected shape (3,), got {getattr(self, name).shape}")
        if self.fov.shape != ():
            raise ValueError(f"Camera.fov: expected a scalar, got shape {self.fov.shape}")

    def basis(self):
        """Unit ``forward, right, up`` vectors, each ``(3,)``."""
        fwd = V.normalize(self.look_at - self.position)
        right = V.normalize(V.cross(fwd, self.up))
        up = V.cross(right, fwd)
        return fwd, right, up


def subpixel_offsets(spp: int, dtype):
    """``(spp, 2)`` stratified offsets in ``[0, 1)^2``: cell centres of an
    ``n x n`` grid, ``n = sqrt(spp)``."""
    n = math.isqrt(spp)
    a = (jnp.arange(n, dtype=dtype) + 0.5) / n
    sx, sy = jnp.meshgrid(a, a, indexing="xy")
    return jnp.stack([sx.ravel(), sy.ravel()], -1)


class Frame(NamedTuple):
    """What :func:`rays_through` needs of a camera for an image of a given aspect:
    its ``position``, unit ``fwd``, ``right`` and ``up`` vectors (each ``(3,)``) and
    the half extents ``half_w``, ``half_h`` (scalars) of the image plane at distance
    1. The integrator computes it once per trace (:func:`frame`), outside its loops,
    so that reverse mode keeps these few arrays rather than every intermediate of the
    basis at each loop step."""

    position: jax.Array
    fwd: jax.Array
    right: jax.Array
    up: jax.Array
    half_w: jax.Array
    half_h: jax.Array


def frame(camera: Camera, width: int, height: int) -> Frame:
    """The :class:`Frame` of ``camera`` for an image of ``width x height`` pixels."""
    half_h = jnp.tan(jnp.deg2rad(camera.fov) * 0.5)
    fwd, right, up = camera.basis()
    return Frame(camera.position, fwd, right, up, half_h * (width / height), half_h)


def rays_through(camera: Camera | Frame, xy, width: int, height: int):
    """Origins and unit directions ``(3, M)`` of the rays through continuous image
    positions ``xy (2, M)`` in pixels (x to the right from the left edge, y down
    from the top; pixel ``(row, col)`` covers ``[col, col + 1) x [row, row + 1)``).
    ``camera``: a :class:`Camera`, or its :func:`frame` for this image size."""
    f = frame(camera, width, height) if isinstance(camera, Camera) else camera
    x = xy[0] / width * 2.0 - 1.0
    y = 1.0 - xy[1] / height * 2.0
    d = f.fwd[:, None] + (x * f.half_w)[None] * f.right[:, None] + (y * f.half_h)[None] * f.up[:, None]
    d = V.normalize(d)
    return jnp.broadcast_to(f.position[:, None], d.shape), d


def cone_spread(camera: Camera, height: int, n: int = 1):
    """Cone spread angle (radians per unit distance) of one sample of an ``n x n``
    grid per pixel of an image ``height`` pixels tall (texture footprints)."""
    return 2.0 * jnp.tan(jnp.deg2rad(camera.fov) * 0.5) / height / n


def primary_rays(camera: Camera, pix, width: int, height: int, spp: int, key=None):
    """Camera rays for flat pixel indices ``pix (P,)`` (row-major).

    Returns origins and unit directions ``(3, spp * P)`` ordered sample-major
    (all pixels for sample 0, then sample 1...), and the cone spread angle (in
    radians per unit distance) of one sample, used for texture filtering.
    With ``key`` each sample is jittered uniformly inside its stratum.
    """
    xy = sample_positions(pix, width, spp, camera.position.dtype, key)
    o, d = rays_through(camera, xy, width, height)
    return o, d, cone_spread(camera, height, math.isqrt(spp))


def sample_positions(pix, width: int, spp: int, dtype, key=None):
    """The image positions ``(2, spp * P)`` (pixels, as :func:`rays_through` takes
    them) of the ``spp`` samples of each flat pixel index ``pix (P,)``, ordered as
    :func:`primary_rays` orders its rays; jittered inside their strata with ``key``."""
    n = math.isqrt(spp)
    offs = subpixel_offsets(spp, dtype)  # (spp, 2)
    row = (pix // width).astype(dtype)
    col = (pix % width).astype(dtype)
    sx = offs[:, 0:1]  # (spp, 1)
    sy = offs[:, 1:2]
    if key is not None:
        j = jax.random.uniform(key, (2, spp, pix.shape[0]), dtype=dtype) - 0.5
        sx = sx + j[0] / n
        sy = sy + j[1] / n
    return jnp.stack([(col[None, :] + sx).ravel(), (row[None, :] + sy).ravel()])
