"""Spheres: ``center (N, 3)``, ``radius (N,)``."""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .. import vec as V
from .base import INF, Key, KindSpec, SearchPart, ball_bounds, check_shape


class Spheres(eqx.Module):
    """Spheres: ``center (N, 3)``, ``radius (N,)``, ``material (N,)`` int ids.

    ``(u, v)``: ``u`` longitude in ``[0, 1)`` measured about +y with ``u = 0.5``
    facing +z; ``v`` latitude in ``[0, 1]`` from the south (-y) to the north pole.
    """

    center: Float[Array, "N 3"]
    radius: Float[Array, " N"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.center.shape[0]
        check_shape("Spheres.center", self.center, (n, 3))
        check_shape("Spheres.radius", self.radius, (n,))
        check_shape("Spheres.material", self.material, (n,))


def sphere_soa(s: Spheres):
    c = s.center
    return dict(cx=c[:, 0], cy=c[:, 1], cz=c[:, 2], r=s.radius)


def sphere_roots(ray, P):
    """Both roots ``t1 <= t2`` of the ray-sphere quadratic and its discriminant."""
    ox, oy, oz, dx, dy, dz = ray
    ocx, ocy, ocz = ox - P["cx"], oy - P["cy"], oz - P["cz"]
    b = dx * ocx + dy * ocy + dz * ocz
    c = ocx * ocx + ocy * ocy + ocz * ocz - P["r"] * P["r"]
    disc = b * b - c
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    return -b - sq, -b + sq, disc


def sphere_t(ray, P, tmin):
    t1, t2, disc = sphere_roots(ray, P)
    t = jnp.where(t1 > tmin, t1, jnp.where(t2 > tmin, t2, INF))
    return jnp.where((disc >= 0) & (P["r"] > 0), t, INF)


def sphere_crossings(ray, P, tmax):
    """Number of surface crossings (0, 1 or 2) of each ray's open segment ``(0, tmax)``."""
    t1, t2, disc = sphere_roots(ray, P)
    ok = (disc > 0) & (P["r"] > 0)
    n1 = ok & (t1 > 0) & (t1 < tmax)
    n2 = ok & (t2 > 0) & (t2 < tmax)
    return n1.astype(t1.dtype) + n2.astype(t1.dtype)


def sphere_roots_safe(c, r, o, d):
    """Both roots ``t1 <= t2`` of the ray-sphere quadratic for rays ``o, d`` (``(3,
    n)``, ``d`` unit) and spheres of centre ``c`` (``(3, n)``) and radius ``r``
    (``(n,)``), differentiable everywhere: where the ray misses (negative
    discriminant) both are ``-b``, the closest approach, with a zero square-root
    gradient (:func:`raytrax.vec.safe_sqrt`). The search's :func:`sphere_roots` is the
    same quadratic on struct-of-arrays fields, without gradient care."""
    oc = o - c
    b = V.dot(d, oc)
    cc = V.dot(oc, oc) - r * r
    sq = V.safe_sqrt(b * b - cc)
    return -b - sq, -b + sq


def sphere_hit(c, r, o, d, t0):
    t1, t2 = sphere_roots_safe(c, r, o, d)
    t = jnp.where(jnp.abs(t1 - t0) <= jnp.abs(t2 - t0), t1, t2)
    p = o + t[None] * d
    n = V.normalize(p - c)
    u = 0.5 + V.safe_atan2(n[0], n[2]) / (2 * math.pi)
    v = 0.5 + V.safe_atan2(n[1], V.safe_sqrt(n[0] * n[0] + n[2] * n[2])) / math.pi
    inv_r = V.safe_div(1.0, r)
    rate = jnp.stack([inv_r / (2 * math.pi), inv_r / math.pi])
    return t, n, jnp.stack([u, v]), rate


class SphereSpec(KindSpec):
    name: ClassVar[str] = "sphere"
    field: ClassVar[str] = "spheres"
    module: ClassVar[type] = Spheres
    keys: ClassVar[tuple] = (
        Key("center", "center", (3,), "vec3"),
        Key("radius", "radius", (), "positive", what="a positive number"),
    )
    edge: ClassVar[str] = "sphere"

    def check(self, p, where):
        if not p["radius"] > 0:
            raise ValueError(f"{where}.radius: expected a positive number, got {float(p['radius'])}")

    def search(self, g):
        return SearchPart(
            sphere_soa(g),
            g.material,
            sphere_t,
            lambda i, o, d, t0: sphere_hit(g.center[i].T, g.radius[i], o, d, t0),
            sphere_crossings,
            V.safe_div(1.0, jnp.abs(g.radius)),
            ball_bounds(g.center, g.radius),
        )
