"""Disks: flat circles of ``radius (N,)`` about ``center (N, 3)``, facing ``normal (N, 3)``."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .. import vec as V
from .base import (
    INF,
    EdgePolygons,
    Key,
    KindSpec,
    SearchPart,
    ball_bounds,
    check_shape,
    plane_distance,
    tangent_frame,
    unit_rows,
)


class Disks(eqx.Module):
    """Disks: ``center (N, 3)``, ``normal (N, 3)`` (any length, not zero; the disk's
    front side), ``radius (N,)``, ``material (N,)`` int ids.

    ``(u, v)``: planar coordinates over the disk's bounding square, ``0`` to ``1``
    along the tangent axes of :func:`raytrax.shapes.base.tangent_frame` (``u`` is
    world x projected on the disk's plane, or z for a disk facing x), so ``(0.5,
    0.5)`` is the centre and a texture is not stretched.
    """

    center: Float[Array, "N 3"]
    normal: Float[Array, "N 3"]
    radius: Float[Array, " N"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.center.shape[0]
        check_shape("Disks.center", self.center, (n, 3))
        check_shape("Disks.normal", self.normal, (n, 3))
        check_shape("Disks.radius", self.radius, (n,))
        check_shape("Disks.material", self.material, (n,))


def disk_soa(g: Disks):
    n = unit_rows(g.normal)
    c = g.center
    return dict(cx=c[:, 0], cy=c[:, 1], cz=c[:, 2], nx=n[:, 0], ny=n[:, 1], nz=n[:, 2], r2=g.radius * g.radius)


def disk_t(ray, P, tmin):
    """Distance to the disk's plane where the hit lies within the radius (inf otherwise)."""
    ox, oy, oz, dx, dy, dz = ray
    den = dx * P["nx"] + dy * P["ny"] + dz * P["nz"]
    qx, qy, qz = P["cx"] - ox, P["cy"] - oy, P["cz"] - oz
    num = qx * P["nx"] + qy * P["ny"] + qz * P["nz"]
    ok = jnp.abs(den) > 1e-12
    t = num / jnp.where(ok, den, 1.0)
    ex, ey, ez = ox + t * dx - P["cx"], oy + t * dy - P["cy"], oz + t * dz - P["cz"]
    inside = ex * ex + ey * ey + ez * ez <= P["r2"]
    return jnp.where(ok & (t > tmin) & inside, t, INF)


def disk_hit(center, normal, radius, o, d, t0):
    n = V.normalize(normal)
    t = plane_distance(center, n, o, d)
    p = o + t[None] * d
    tu, tv = tangent_frame(n)
    q = p - center
    inv = V.safe_div(0.5, radius)
    uv = jnp.stack([0.5 + V.dot(q, tu) * inv, 0.5 + V.dot(q, tv) * inv])
    return t, n, uv, jnp.stack([inv, inv])


class DiskSpec(KindSpec):
    name: ClassVar[str] = "disk"
    field: ClassVar[str] = "disks"
    module: ClassVar[type] = Disks
    edge: ClassVar[str] = "disk"
    keys: ClassVar[tuple] = (
        Key("center", "center", (3,), "vec3"),
        Key("normal", "normal", (3,), "nonzero3"),
        Key("radius", "radius", (), "positive", what="a positive number"),
    )

    def check(self, p, where):
        if np.linalg.norm(p["normal"]) == 0:
            raise ValueError(f"{where}.normal: expected a non-zero vector")
        if not p["radius"] > 0:
            raise ValueError(f"{where}.radius: expected a positive number, got {float(p['radius'])}")

    def search(self, g):
        return SearchPart(
            disk_soa(g),
            g.material,
            disk_t,
            lambda i, o, d, t0: disk_hit(g.center[i].T, g.normal[i].T, g.radius[i], o, d, t0),
            bounds=ball_bounds(g.center, g.radius),  # its sphere's box: loose, never too small
        )

    def edge_polygons(self, g):
        N = g.center.shape[0]
        z = jnp.zeros((N, 4, 3), g.center.dtype)
        return EdgePolygons(
            g.center, unit_rows(g.normal), z, z, jnp.ones((N,), bool), g.radius, g.material.astype(jnp.int32)
        )
