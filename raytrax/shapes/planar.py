"""Infinite planes and bounded convex quads."""

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
    check_shape,
    plane_distance,
    quad_polygons,
    tangent_frame,
    unit_rows,
)


class Planes(eqx.Module):
    """Infinite planes through ``point (N, 3)`` with ``normal (N, 3)``.

    ``(u, v)`` are world-length coordinates along two tangent axes (so a checker
    ``scale`` on a plane is cells per world unit).
    """

    point: Float[Array, "N 3"]
    normal: Float[Array, "N 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.point.shape[0]
        check_shape("Planes.point", self.point, (n, 3))
        check_shape("Planes.normal", self.normal, (n, 3))
        check_shape("Planes.material", self.material, (n,))


class Quads(eqx.Module):
    """Bounded planar convex quads, ``corners (N, 4, 3)`` in order around the edge.

    The normal follows the right-hand rule on the corner order; ``(u, v)`` run
    from ``0`` at ``corners[0]`` to ``1`` at ``corners[1]`` and ``corners[3]``.
    """

    corners: Float[Array, "N 4 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.corners.shape[0]
        check_shape("Quads.corners", self.corners, (n, 4, 3))
        check_shape("Quads.material", self.material, (n,))


def plane_soa(p: Planes):
    n = p.normal / jnp.maximum(jnp.linalg.norm(p.normal, axis=-1, keepdims=True), 1e-30)
    return dict(px=p.point[:, 0], py=p.point[:, 1], pz=p.point[:, 2], nx=n[:, 0], ny=n[:, 1], nz=n[:, 2])


def plane_t(ray, P, tmin):
    ox, oy, oz, dx, dy, dz = ray
    den = dx * P["nx"] + dy * P["ny"] + dz * P["nz"]
    num = (P["px"] - ox) * P["nx"] + (P["py"] - oy) * P["ny"] + (P["pz"] - oz) * P["nz"]
    ok = jnp.abs(den) > 1e-12
    t = num / jnp.where(ok, den, 1.0)
    return jnp.where(ok & (t > tmin), t, INF)


def plane_hit(point, normal, o, d, t0):
    n = V.normalize(normal)
    t = plane_distance(point, n, o, d)
    p = o + t[None] * d
    tu, tv = tangent_frame(n)
    q = p - point
    uv = jnp.stack([V.dot(q, tu), V.dot(q, tv)])
    return t, n, uv, jnp.ones_like(uv)


def _quad_frame(corners):
    """Plane normal (N, 3) of quads from the cross product of their diagonals."""
    c0, c1, c2, c3 = corners[:, 0], corners[:, 1], corners[:, 2], corners[:, 3]
    n = jnp.cross(c2 - c0, c3 - c1)
    return n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-30)


def quad_soa(q: Quads):
    c = q.corners
    n = _quad_frame(c)
    P = dict(nx=n[:, 0], ny=n[:, 1], nz=n[:, 2])
    for i in range(4):
        e = c[:, (i + 1) % 4] - c[:, i]
        m = jnp.cross(n, e)  # inside test: (p - c_i) . (n x e_i) >= 0
        P[f"c{i}x"], P[f"c{i}y"], P[f"c{i}z"] = c[:, i, 0], c[:, i, 1], c[:, i, 2]
        P[f"m{i}x"], P[f"m{i}y"], P[f"m{i}z"] = m[:, 0], m[:, 1], m[:, 2]
    return P


def quad_t(ray, P, tmin):
    ox, oy, oz, dx, dy, dz = ray
    den = dx * P["nx"] + dy * P["ny"] + dz * P["nz"]
    num = (P["c0x"] - ox) * P["nx"] + (P["c0y"] - oy) * P["ny"] + (P["c0z"] - oz) * P["nz"]
    ok = jnp.abs(den) > 1e-12
    t = num / jnp.where(ok, den, 1.0)
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    inside = ok & (t > tmin)
    for i in range(4):
        s = (px - P[f"c{i}x"]) * P[f"m{i}x"] + (py - P[f"c{i}y"]) * P[f"m{i}y"] + (pz - P[f"c{i}z"]) * P[f"m{i}z"]
        inside = inside & (s >= 0)
    return jnp.where(inside, t, INF)


def quad_hit(c0, c1, c2, c3, o, d, t0):
    n = V.normalize(V.cross(c2 - c0, c3 - c1))
    t = plane_distance(c0, n, o, d)
    p = o + t[None] * d
    e1, e3 = c1 - c0, c3 - c0
    q = p - c0
    l1, l3 = V.dot(e1, e1), V.dot(e3, e3)
    uv = jnp.stack([V.safe_div(V.dot(q, e1), l1), V.safe_div(V.dot(q, e3), l3)])
    rate = jnp.stack([V.safe_div(1.0, V.safe_sqrt(l1)), V.safe_div(1.0, V.safe_sqrt(l3))])
    return t, n, uv, rate


class PlaneSpec(KindSpec):
    name: ClassVar[str] = "plane"
    field: ClassVar[str] = "planes"
    module: ClassVar[type] = Planes
    keys: ClassVar[tuple] = (Key("point", "point", (3,), "vec3"), Key("normal", "normal", (3,), "nonzero3"))

    def check(self, p, where):
        if np.linalg.norm(p["normal"]) == 0:
            raise ValueError(f"{where}.normal: expected a non-zero vector")

    def search(self, g):
        return SearchPart(
            plane_soa(g), g.material, plane_t, lambda i, o, d, t0: plane_hit(g.point[i].T, g.normal[i].T, o, d, t0)
        )

    def edge_polygons(self, g):
        N = g.point.shape[0]
        z = jnp.zeros((N, 4, 3), g.point.dtype)
        return EdgePolygons(
            g.point,
            unit_rows(g.normal),
            z,
            z,
            jnp.zeros((N,), bool),
            jnp.zeros((N,), g.point.dtype),
            g.material.astype(jnp.int32),
        )


class QuadSpec(KindSpec):
    name: ClassVar[str] = "quad"
    field: ClassVar[str] = "quads"
    module: ClassVar[type] = Quads
    keys: ClassVar[tuple] = (
        Key(
            "corners",
            "corners",
            (4, 3),
            "matrix",
            what="an array of 4 corners ([x, y, z] each, in order around the edge)",
        ),
    )

    def check(self, p, where):
        c = p["corners"]
        n = np.cross(c[2] - c[0], c[3] - c[1])
        size = max(np.ptp(c, axis=0).max(), 1e-300)
        if np.linalg.norm(n) <= 1e-9 * size * size:
            raise ValueError(
                f"{where}.corners: expected a convex quad with non-zero area and corners in "
                f"order around its edge, got a degenerate or self-intersecting quad"
            )
        n = n / np.linalg.norm(n)
        off = np.abs((c - c[0]) @ n).max()
        if off > 1e-6 * size:
            raise ValueError(f"{where}.corners: the four corners are not coplanar (off by {off:.3g})")
        for k in range(4):
            e = c[(k + 1) % 4] - c[k]
            if np.dot(np.cross(n, e), c[(k + 2) % 4] - c[k]) < -1e-9 * size * size:
                raise ValueError(f"{where}.corners: expected a convex quad with corners in order around its edge")

    def search(self, g):
        def hit(i, o, d, t0):
            c = g.corners[i]
            return quad_hit(c[:, 0].T, c[:, 1].T, c[:, 2].T, c[:, 3].T, o, d, t0)

        c = g.corners
        return SearchPart(quad_soa(g), g.material, quad_t, hit, bounds=jnp.stack([c.min(1).T, c.max(1).T]))

    def edge_polygons(self, g):
        return quad_polygons(g.corners, g.material)
