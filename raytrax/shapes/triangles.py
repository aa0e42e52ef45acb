"""Triangle-based kinds: triangles, regular tetrahedra and meshes.

All three are searched as one merged triangle list (``Scene.merged_triangles``, in
registry order), brute force or through :mod:`raytrax.bvh`.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .. import vec as V
from .base import INF, Key, KindSpec, check_shape, polygons_from_edges


class Triangles(eqx.Module):
    """Triangles, ``vertices (N, 3, 3)`` (triangle, vertex, xyz); ``(u, v)`` barycentric."""

    vertices: Float[Array, "N 3 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.vertices.shape[0]
        check_shape("Triangles.vertices", self.vertices, (n, 3, 3))
        check_shape("Triangles.material", self.material, (n,))

    def triangles(self):
        return self.vertices, self.material


class Tetrahedra(eqx.Module):
    """Regular tetrahedra, ``center (N, 3)`` (centroid) and ``size (N,)`` (edge length).

    One face lies horizontal at the bottom, the apex points up (+y). Each is
    intersected as four triangles generated inside the traced function, so
    centre and size are differentiable.
    """

    center: Float[Array, "N 3"]
    size: Float[Array, " N"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.center.shape[0]
        check_shape("Tetrahedra.center", self.center, (n, 3))
        check_shape("Tetrahedra.size", self.size, (n,))
        check_shape("Tetrahedra.material", self.material, (n,))

    def triangles(self):
        """The four faces as ``(4N, 3, 3)`` vertices (outward winding) and materials."""
        a = self.size
        R = a * (math.sqrt(6.0) / 4.0)  # circumradius
        rb = a / math.sqrt(3.0)  # radius of the base circle
        yb = -R / 3.0
        zero = jnp.zeros_like(a)
        apex = jnp.stack([zero, R, zero], -1)
        base = []
        for ang in (90.0, 210.0, 330.0):
            c, s = math.cos(math.radians(ang)), math.sin(math.radians(ang))
            base.append(jnp.stack([rb * c, yb, rb * s], -1))
        b0, b1, b2 = base
        # Outward winding (counter-clockwise seen from outside).
        faces = [
            (b0, b1, b2),
            (apex, b1, b0),
            (apex, b2, b1),
            (apex, b0, b2),
        ]
        c = self.center
        tris = jnp.stack([jnp.stack([p + c, q + c, r + c], 1) for p, q, r in faces], 1)
        tris = tris.reshape(-1, 3, 3)  # (tetrahedron, face) -> face; outward normals (tests/test_shapes.py)
        return tris, jnp.repeat(self.material, 4)


class Mesh(eqx.Module):
    """A triangle mesh: ``vertices (V, 3)``, ``faces (F, 3)`` int indices, one material."""

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]
    material: Int[Array, ""]

    def __check_init__(self):
        check_shape("Mesh.vertices", self.vertices, (None, 3))
        check_shape("Mesh.faces", self.faces, (None, 3))

    def triangles(self):
        tris = self.vertices[self.faces]
        return tris, jnp.broadcast_to(self.material, (self.faces.shape[0],))


def tri_soa(v0, v1, v2):
    """SoA of triangles from vertex arrays ``(T, 3)`` each: the vertices' components
    ``ax ... cz`` (the search's test needs the vertices themselves, see :func:`tri_t`)."""
    return {f"{p}{c}": v[:, i] for p, v in zip("abc", (v0, v1, v2)) for i, c in enumerate("xyz")}


def ray_frame(ray):
    """Per-ray constants of :func:`tri_t` for rays ``ray`` (the six components
    ``ox ... dz``): the ray's own frame, in which the ray is the z axis and z measures
    the ray parameter (Woop, Benthin and Wald 2013). With ``k`` the axis of the
    direction's largest component and ``i, j`` the two others in cyclic order after it,
    a point ``p`` maps to ``(q_i - s_i q_k, q_j - s_j q_k, q_k / d_k)`` with ``q = p - o``
    and ``s = d / d_k``. Returns the origin, which axis is ``k`` (``on_x``, ``on_y``;
    z where neither), ``s_i``, ``s_j`` and ``1 / d_k``."""
    ox, oy, oz, dx, dy, dz = ray
    ax, ay, az = jnp.abs(dx), jnp.abs(dy), jnp.abs(dz)
    on_x = (ax >= ay) & (ax >= az)
    on_y = ~on_x & (ay >= az)
    inv = 1.0 / jnp.where(on_x, dx, jnp.where(on_y, dy, dz))  # never 0: the largest component
    si = jnp.where(on_x, dy, jnp.where(on_y, dz, dx)) * inv
    sj = jnp.where(on_x, dz, jnp.where(on_y, dx, dy)) * inv
    return ox, oy, oz, on_x, on_y, si, sj, inv


def _tri_test(ray, P, frame):
    """The watertight test of :func:`tri_t`: whether each ray meets each triangle's plane
    inside it, ``hit``, and the ray parameter of that point as ``T / D`` with ``D > 0``
    (no division: the callers compare ``T`` with ``D`` times a distance)."""
    ox, oy, oz, on_x, on_y, si, sj, inv = ray_frame(ray) if frame is None else frame

    def project(p):
        X, Y, Z = P[p + "x"] - ox, P[p + "y"] - oy, P[p + "z"] - oz
        qk = jnp.where(on_x, X, jnp.where(on_y, Y, Z))
        qi = jnp.where(on_x, Y, jnp.where(on_y, Z, X))
        qj = jnp.where(on_x, Z, jnp.where(on_y, X, Y))
        return qi - si * qk, qj - sj * qk, inv * qk

    def edge(px, py, qx, qy):  # twice the 2D cross product p x q; edge(q, p) == -edge(p, q) exactly
        return (px * qy - py * qx) - (qx * py - qy * px)

    Ax, Ay, Az = project("a")
    Bx, By, Bz = project("b")
    Cx, Cy, Cz = project("c")
    U, V_, W = edge(Bx, By, Cx, Cy), edge(Cx, Cy, Ax, Ay), edge(Ax, Ay, Bx, By)
    inside = (jnp.minimum(jnp.minimum(U, V_), W) >= 0) | (jnp.maximum(jnp.maximum(U, V_), W) <= 0)
    det = U + V_ + W
    T = U * Az + V_ * Bz + W * Cz
    neg = det < 0
    return inside & (det != 0), jnp.where(neg, -T, T), jnp.where(neg, -det, det)


def tri_t(ray, P, tmin, frame=None):
    """Distance along ``ray`` (the six components) to the triangles ``P`` (:func:`tri_soa`),
    ``inf`` where it misses or is not beyond ``tmin``; broadcasting like the arrays.
    ``frame``: the rays' :func:`ray_frame`, where a loop over many triangles computes
    it once (else it is computed here).

    Watertight: the vertices are mapped into the ray's frame (:func:`ray_frame`) and
    the ray is inside where the three 2D edge functions agree in sign
    (zero counts as inside). A vertex shared by two triangles maps to the same point in
    both, and each edge function is written so that it rounds to exactly the negation
    of itself with the edge's ends swapped (with or without fused multiply-adds), so a
    ray through a shared edge or vertex hits at least one of its triangles. A
    degenerate triangle (zero area as the ray sees it) is never hit."""
    hit, T, D = _tri_test(ray, P, frame)
    ok = hit & (T > tmin * D)
    # One division, last, of values that are already masked: XLA then fuses the whole
    # test into one kernel (a division in the middle split it into several, each
    # recomputing the projections).
    return jnp.where(ok, T, INF) / jnp.where(ok, D, 1.0)


def tri_crossings(ray, P, tmax, frame=None):
    """Whether ``ray`` crosses the triangles ``P`` within the open segment ``(0, tmax)``
    (:func:`tri_t`'s watertight test, without its division), as 0 or 1 in the rays'
    dtype; broadcasting like the arrays."""
    hit, T, D = _tri_test(ray, P, frame)
    return (hit & (T > 0) & (T < tmax * D)).astype(ray[0].dtype)


def tri_hit(v0, v1, v2, o, d, t0):
    e1, e2 = v1 - v0, v2 - v0
    pv = V.cross(d, e2)
    det = V.dot(e1, pv)
    tv = o - v0
    qv = V.cross(tv, e1)
    u = V.safe_div(V.dot(tv, pv), det)
    v = V.safe_div(V.dot(d, qv), det)
    t = V.safe_div(V.dot(e2, qv), det)
    n = V.normalize(V.cross(e1, e2))
    rate = jnp.stack([V.safe_div(1.0, V.norm(e1)), V.safe_div(1.0, V.norm(e2))])
    return t, n, jnp.stack([u, v]), rate


def triangle_polygons(T, material):
    """:class:`~raytrax.shapes.base.EdgePolygons` of triangles ``T (N, 3, 3)`` (the
    fourth edge repeats the third)."""
    v0, v1, v2 = T[:, 0], T[:, 1], T[:, 2]
    origins = jnp.stack([v0, v1, v2, v2], 1)
    dirs = jnp.stack([v1 - v0, v2 - v1, v0 - v2, v0 - v2], 1)
    return polygons_from_edges(origins, dirs, jnp.cross(v1 - v0, v2 - v0), material)


class _TriangleFamily(KindSpec):
    triangle_family: ClassVar[bool] = True

    def triangles(self, g):
        return g.triangles()

    def edge_polygons(self, g):
        return triangle_polygons(*g.triangles())


class TriangleSpec(_TriangleFamily):
    name: ClassVar[str] = "triangle"
    field: ClassVar[str] = "triangles"
    module: ClassVar[type] = Triangles
    keys: ClassVar[tuple] = (
        Key("vertices", "vertices", (3, 3), "matrix", what="an array of 3 vertices ([x, y, z] each)"),
    )

    def check(self, p, where):
        v = p["vertices"]
        size = max(np.ptp(v, axis=0).max(), 1e-300)
        if np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0])) <= 1e-9 * size * size:
            raise ValueError(f"{where}.vertices: degenerate triangle (zero area)")

    def n_triangles(self, params):
        return 1


class TetrahedronSpec(_TriangleFamily):
    name: ClassVar[str] = "tetrahedron"
    field: ClassVar[str] = "tetrahedra"
    module: ClassVar[type] = Tetrahedra
    keys: ClassVar[tuple] = (
        Key("center", "center", (3,), "vec3"),
        Key("size", "size", (), "positive", what="a positive edge length"),
    )
    faces_per: ClassVar[int] = 4
    solid_faces: ClassVar[int] = 4

    def check(self, p, where):
        if not p["size"] > 0:
            raise ValueError(f"{where}.size: expected a positive number, got {float(p['size'])}")

    def n_triangles(self, params):
        return 4


class MeshSpec(_TriangleFamily):
    """Meshes: the group is a tuple of :class:`Mesh` (one per object)."""

    name: ClassVar[str] = "mesh"
    field: ClassVar[str] = "meshes"
    module: ClassVar[type] = Mesh
    keys: ClassVar[tuple] = ()
    builder_args: ClassVar[tuple] = ("vertices", "faces")

    def validate(self, params, where):
        v = np.asarray(params.get("vertices"), dtype=np.float64)
        f = np.asarray(params.get("faces"))
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
            raise ValueError(f"{where}.vertices: expected a (V, 3) array with V >= 3, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"{where}.faces: expected an integer (F, 3) array, got shape {f.shape} of {f.dtype}")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"{where}.faces: vertex index out of range [0, {v.shape[0]})")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{where}.vertices: expected finite numbers")
        return dict(vertices=v, faces=f.astype(np.int32))

    def build(self, items, F, I):
        return tuple(Mesh(F(p["vertices"]), jnp.asarray(p["faces"]), jnp.asarray(m, dtype=jnp.int32)) for p, m in items)

    def count(self, group):
        return len(group)

    def describe(self, group, j):
        g = group[j]
        p = dict(vertices=np.asarray(g.vertices).astype(np.float64), faces=np.asarray(g.faces).astype(np.int64))
        return p, int(g.material)

    def slots(self, group, j):
        return [("vertices", (lambda g, j=j: g[j].vertices), None, tuple(group[j].vertices.shape))]

    def n_ids(self, group):
        return sum(self.face_groups(group))

    def face_groups(self, group):
        return tuple(int(m.faces.shape[0]) for m in group)

    def n_triangles(self, params):
        return int(np.asarray(params["faces"]).shape[0])

    def triangles(self, group):
        parts = [m.triangles() for m in group]
        if not parts:
            return None
        return jnp.concatenate([t for t, _ in parts], 0), jnp.concatenate([m for _, m in parts], 0)

    def edge_polygons(self, group):
        tm = self.triangles(group)
        assert tm is not None, "edge polygons of an empty mesh group"
        return triangle_polygons(*tm)
