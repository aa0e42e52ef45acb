"""Primitive kinds: stacked parameter arrays and their ray intersections.

Each kind is one :class:`equinox.Module` whose fields stack the parameters of all
primitives of that kind (struct of arrays): ``Spheres.center`` is ``(N, 3)``,
``Spheres.radius`` is ``(N,)`` and so on. ``material`` fields are integer ids
into the scene's :class:`~raytrax.materials.Materials` table.

Intersection is done in two passes, which is what keeps reverse mode cheap:

1. ``closest_hit`` (in :mod:`raytrax.intersect`) finds, for every ray, the
   nearest primitive with every input under ``stop_gradient``: one vectorised
   test of all rays against blocks of primitives, a min-reduction, and nothing
   kept for the backward pass.
2. ``*_hit`` functions below recompute the hit of each ray with *its* primitive
   only, differentiably: distance, outward geometric normal, surface
   coordinates ``(u, v)`` and the rate ``(su, sv)`` at which ``u`` and ``v``
   change per unit of world length (for texture filtering).

The gradient of step 2 equals the gradient of a min over all primitives (the
min's derivative flows to the arg-min), without storing ``rays x primitives``
residuals.

Conventions: world units are arbitrary but consistent; normals are unit length
and point out of closed objects (for planes, quads and triangles: the side
given by the right-hand rule on the vertex order); vectors inside kernels are
component-major ``(3, n)`` (see :mod:`raytrax._vec`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from . import _vec as V

INF = float("inf")


def _check_shape(name, arr, shape):
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise ValueError(f"{name}: expected shape {shape}, got {tuple(arr.shape)}")


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
        _check_shape("Spheres.center", self.center, (n, 3))
        _check_shape("Spheres.radius", self.radius, (n,))
        _check_shape("Spheres.material", self.material, (n,))


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
        _check_shape("Planes.point", self.point, (n, 3))
        _check_shape("Planes.normal", self.normal, (n, 3))
        _check_shape("Planes.material", self.material, (n,))


class Quads(eqx.Module):
    """Bounded planar convex quads, ``corners (N, 4, 3)`` in order around the edge.

    The normal follows the right-hand rule on the corner order; ``(u, v)`` run
    from ``0`` at ``corners[0]`` to ``1`` at ``corners[1]`` and ``corners[3]``.
    """

    corners: Float[Array, "N 4 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.corners.shape[0]
        _check_shape("Quads.corners", self.corners, (n, 4, 3))
        _check_shape("Quads.material", self.material, (n,))


class Triangles(eqx.Module):
    """Triangles, ``vertices (N, 3, 3)`` (triangle, vertex, xyz); ``(u, v)`` barycentric."""

    vertices: Float[Array, "N 3 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.vertices.shape[0]
        _check_shape("Triangles.vertices", self.vertices, (n, 3, 3))
        _check_shape("Triangles.material", self.material, (n,))


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
        _check_shape("Tetrahedra.center", self.center, (n, 3))
        _check_shape("Tetrahedra.size", self.size, (n,))
        _check_shape("Tetrahedra.material", self.material, (n,))

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


class Boxes(eqx.Module):
    """Boxes: axis-aligned ``lo``/``hi`` corners ``(N, 3)``, then rotated about their
    centre by ``rotation (N, 3)`` Euler angles in degrees (applied x, then y, then z).

    ``(u, v)`` are the two in-face local coordinates scaled to ``[0, 1]``.
    """

    lo: Float[Array, "N 3"]
    hi: Float[Array, "N 3"]
    rotation: Float[Array, "N 3"]
    material: Int[Array, " N"]

    def __check_init__(self):
        n = self.lo.shape[0]
        _check_shape("Boxes.lo", self.lo, (n, 3))
        _check_shape("Boxes.hi", self.hi, (n, 3))
        _check_shape("Boxes.rotation", self.rotation, (n, 3))
        _check_shape("Boxes.material", self.material, (n,))


class Mesh(eqx.Module):
    """A triangle mesh: ``vertices (V, 3)``, ``faces (F, 3)`` int indices, one material."""

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]
    material: Int[Array, ""]

    def __check_init__(self):
        _check_shape("Mesh.vertices", self.vertices, (None, 3))
        _check_shape("Mesh.faces", self.faces, (None, 3))

    def triangles(self):
        tris = self.vertices[self.faces]
        return tris, jnp.broadcast_to(self.material, (self.faces.shape[0],))


def euler_matrix(deg):
    """Rotation matrices ``(N, 3, 3)`` from Euler angles ``(N, 3)`` in degrees (x, then y, then z)."""
    r = jnp.deg2rad(deg)
    cx, cy, cz = jnp.cos(r[:, 0]), jnp.cos(r[:, 1]), jnp.cos(r[:, 2])
    sx, sy, sz = jnp.sin(r[:, 0]), jnp.sin(r[:, 1]), jnp.sin(r[:, 2])
    one, zero = jnp.ones_like(cx), jnp.zeros_like(cx)
    Rx = jnp.stack(
        [jnp.stack([one, zero, zero], -1), jnp.stack([zero, cx, -sx], -1), jnp.stack([zero, sx, cx], -1)], -2
    )
    Ry = jnp.stack(
        [jnp.stack([cy, zero, sy], -1), jnp.stack([zero, one, zero], -1), jnp.stack([-sy, zero, cy], -1)], -2
    )
    Rz = jnp.stack(
        [jnp.stack([cz, -sz, zero], -1), jnp.stack([sz, cz, zero], -1), jnp.stack([zero, zero, one], -1)], -2
    )
    return Rz @ Ry @ Rx


# ----------------------------------------------------------------------------
# Stop-gradient kernels: (n, 1) ray components against (1, B) primitive
# components, returning an (n, B) matrix of hit distances (inf on a miss).
# ----------------------------------------------------------------------------


def sphere_soa(s: Spheres):
    c = s.center
    return dict(cx=c[:, 0], cy=c[:, 1], cz=c[:, 2], r=s.radius)


def _sphere_roots(ray, P):
    """Both roots ``t1 <= t2`` of the ray-sphere quadratic and its discriminant."""
    ox, oy, oz, dx, dy, dz = ray
    ocx, ocy, ocz = ox - P["cx"], oy - P["cy"], oz - P["cz"]
    b = dx * ocx + dy * ocy + dz * ocz
    c = ocx * ocx + ocy * ocy + ocz * ocz - P["r"] * P["r"]
    disc = b * b - c
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    return -b - sq, -b + sq, disc


def sphere_t(ray, P, tmin):
    t1, t2, disc = _sphere_roots(ray, P)
    t = jnp.where(t1 > tmin, t1, jnp.where(t2 > tmin, t2, INF))
    return jnp.where((disc >= 0) & (P["r"] > 0), t, INF)


def sphere_crossings(ray, P, tmax):
    """Number of surface crossings (0, 1 or 2) of each ray's open segment ``(0, tmax)``."""
    t1, t2, disc = _sphere_roots(ray, P)
    ok = (disc > 0) & (P["r"] > 0)
    n1 = ok & (t1 > 0) & (t1 < tmax)
    n2 = ok & (t2 > 0) & (t2 < tmax)
    return n1.astype(t1.dtype) + n2.astype(t1.dtype)


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


def tri_soa(v0, v1, v2):
    """SoA of triangles from vertex arrays ``(T, 3)`` each."""
    e1, e2 = v1 - v0, v2 - v0
    return dict(
        ax=v0[:, 0],
        ay=v0[:, 1],
        az=v0[:, 2],
        e1x=e1[:, 0],
        e1y=e1[:, 1],
        e1z=e1[:, 2],
        e2x=e2[:, 0],
        e2y=e2[:, 1],
        e2z=e2[:, 2],
    )


def tri_t(ray, P, tmin):
    ox, oy, oz, dx, dy, dz = ray
    # Moeller-Trumbore.
    px = dy * P["e2z"] - dz * P["e2y"]
    py = dz * P["e2x"] - dx * P["e2z"]
    pz = dx * P["e2y"] - dy * P["e2x"]
    det = P["e1x"] * px + P["e1y"] * py + P["e1z"] * pz
    ok = jnp.abs(det) > 1e-20
    inv = 1.0 / jnp.where(ok, det, 1.0)
    tx, ty, tz = ox - P["ax"], oy - P["ay"], oz - P["az"]
    u = (tx * px + ty * py + tz * pz) * inv
    qx = ty * P["e1z"] - tz * P["e1y"]
    qy = tz * P["e1x"] - tx * P["e1z"]
    qz = tx * P["e1y"] - ty * P["e1x"]
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (P["e2x"] * qx + P["e2y"] * qy + P["e2z"] * qz) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tmin)
    return jnp.where(hit, t, INF)


def box_soa(b: Boxes):
    R = euler_matrix(b.rotation)
    c = 0.5 * (b.lo + b.hi)
    h = 0.5 * jnp.abs(b.hi - b.lo)
    P = dict(cx=c[:, 0], cy=c[:, 1], cz=c[:, 2], hx=h[:, 0], hy=h[:, 1], hz=h[:, 2])
    for i in range(3):
        for j in range(3):
            P[f"r{i}{j}"] = R[:, i, j]
    return P


def _box_local(ray, P):
    ox, oy, oz, dx, dy, dz = ray
    qx, qy, qz = ox - P["cx"], oy - P["cy"], oz - P["cz"]
    # local = R^T q : component i uses column i of R.
    ol = [qx * P[f"r0{i}"] + qy * P[f"r1{i}"] + qz * P[f"r2{i}"] for i in range(3)]
    dl = [dx * P[f"r0{i}"] + dy * P[f"r1{i}"] + dz * P[f"r2{i}"] for i in range(3)]
    return ol, dl


def _box_slab(ray, P):
    ol, dl = _box_local(ray, P)
    h = [P["hx"], P["hy"], P["hz"]]
    tn, tf = -INF, INF
    for i in range(3):
        small = jnp.abs(dl[i]) < 1e-30
        inv = 1.0 / jnp.where(small, 1.0, dl[i])
        t1 = (-h[i] - ol[i]) * inv
        t2 = (h[i] - ol[i]) * inv
        inside_slab = jnp.abs(ol[i]) <= h[i]
        lo = jnp.where(small, jnp.where(inside_slab, -INF, INF), jnp.minimum(t1, t2))
        hi = jnp.where(small, jnp.where(inside_slab, INF, -INF), jnp.maximum(t1, t2))
        tn = jnp.maximum(tn, lo)
        tf = jnp.minimum(tf, hi)
    return tn, tf


def box_crossings(ray, P, tmax):
    """Number of surface crossings (0, 1 or 2) of each ray's open segment ``(0, tmax)``."""
    tn, tf = _box_slab(ray, P)
    ok = tn <= tf
    n1 = ok & (tn > 0) & (tn < tmax)
    n2 = ok & (tf > 0) & (tf < tmax)
    return n1.astype(tn.dtype) + n2.astype(tn.dtype)


def box_t(ray, P, tmin):
    tn, tf = _box_slab(ray, P)
    t = jnp.where(tn > tmin, tn, tf)
    return jnp.where((tn <= tf) & (tf > tmin), t, INF)


# ----------------------------------------------------------------------------
# Differentiable per-ray hit recomputation. Inputs: gathered primitive
# parameters (component-major, one primitive per ray), ray origin/direction
# (3, n), and the stop-gradient distance t0 (n,) that selects the root.
# Returns t (n,), outward normal (3, n), uv (2, n), uv rate (2, n).
# ----------------------------------------------------------------------------


def sphere_hit(c, r, o, d, t0):
    oc = o - c
    b = V.dot(d, oc)
    cc = V.dot(oc, oc) - r * r
    sq = V.safe_sqrt(b * b - cc)
    t1, t2 = -b - sq, -b + sq
    t = jnp.where(jnp.abs(t1 - t0) <= jnp.abs(t2 - t0), t1, t2)
    p = o + t[None] * d
    n = V.normalize(p - c)
    u = 0.5 + V.safe_atan2(n[0], n[2]) / (2 * math.pi)
    v = 0.5 + V.safe_atan2(n[1], V.safe_sqrt(n[0] * n[0] + n[2] * n[2])) / math.pi
    inv_r = V.safe_div(1.0, r)
    rate = jnp.stack([inv_r / (2 * math.pi), inv_r / math.pi])
    return t, n, jnp.stack([u, v]), rate


def _tangent_frame(n):
    """Two unit tangents (3, n) for normals (3, n); u-axis is x projected on the plane
    (z for planes facing x)."""
    ex = jnp.stack([jnp.ones_like(n[0]), jnp.zeros_like(n[0]), jnp.zeros_like(n[0])])
    ez = jnp.stack([jnp.zeros_like(n[0]), jnp.zeros_like(n[0]), jnp.ones_like(n[0])])
    a = V.vsel(jnp.abs(n[0]) < 0.9, ex, ez)
    tu = V.normalize(a - V.dot(a, n)[None] * n)
    tv = V.cross(n, tu)
    return tu, tv


def plane_hit(point, normal, o, d, t0):
    n = V.normalize(normal)
    t = V.safe_div(V.dot(point - o, n), V.dot(d, n))
    p = o + t[None] * d
    tu, tv = _tangent_frame(n)
    q = p - point
    uv = jnp.stack([V.dot(q, tu), V.dot(q, tv)])
    return t, n, uv, jnp.ones_like(uv)


def quad_hit(c0, c1, c2, c3, o, d, t0):
    n = V.normalize(V.cross(c2 - c0, c3 - c1))
    t = V.safe_div(V.dot(c0 - o, n), V.dot(d, n))
    p = o + t[None] * d
    e1, e3 = c1 - c0, c3 - c0
    q = p - c0
    l1, l3 = V.dot(e1, e1), V.dot(e3, e3)
    uv = jnp.stack([V.safe_div(V.dot(q, e1), l1), V.safe_div(V.dot(q, e3), l3)])
    rate = jnp.stack([V.safe_div(1.0, V.safe_sqrt(l1)), V.safe_div(1.0, V.safe_sqrt(l3))])
    return t, n, uv, rate


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


def _first_best(vals, better):
    """Index of the first ``better``-most of three arrays (``argmax``/``argmin``'s tie
    rule) and that value, with elementwise selects only."""
    ax = jnp.zeros(vals[0].shape, jnp.int32)
    best = vals[0]
    for i in (1, 2):
        b = better(vals[i], best)
        ax = jnp.where(b, i, ax)
        best = jnp.where(b, vals[i], best)
    return ax, best


def _pick3(vals, ax):
    """``vals[ax]`` per ray from three arrays, by selects."""
    return jnp.where(ax == 0, vals[0], jnp.where(ax == 1, vals[1], vals[2]))


def box_hit(center, half, R, o, d, t0):
    """``R`` is (3, 3, n) (or nested 3 x 3 sequences of (n,) arrays): ``R[i][j]`` the
    rotation entry (row i, column j) per ray. Elementwise throughout (no stacking,
    arg-reductions or gathers), which keeps XLA's fusions vectorisable."""
    q = [o[j] - center[j] for j in range(3)]
    ol = [R[0][i] * q[0] + R[1][i] * q[1] + R[2][i] * q[2] for i in range(3)]
    dl = [R[0][i] * d[0] + R[1][i] * d[1] + R[2][i] * d[2] for i in range(3)]
    tn, tf = [], []
    for i in range(3):
        t1 = V.safe_div(-half[i] - ol[i], dl[i])
        t2 = V.safe_div(half[i] - ol[i], dl[i])
        # Degenerate slabs (ray parallel to a face) never decide the hit: push them out.
        par = jnp.abs(dl[i]) < 1e-30
        tn.append(jnp.where(par, -INF, jnp.minimum(t1, t2)))
        tf.append(jnp.where(par, INF, jnp.maximum(t1, t2)))
    ax_n, tnear = _first_best(tn, lambda a, b: a > b)
    ax_f, tfar = _first_best(tf, lambda a, b: a < b)
    entering = jnp.abs(tnear - t0) <= jnp.abs(tfar - t0)
    t = jnp.where(entering, tnear, tfar)
    # A zero direction (every slab "parallel") leaves t = +-inf; such a ray never hits
    # the box, but inf * 0 below would put NaN into the backward pass of the masked lane.
    t = jnp.where(jnp.isfinite(t), t, 0.0)
    ax = jnp.where(entering, ax_n, ax_f)
    # Materialise the hit (t, face) once: otherwise XLA fuses the whole slab test
    # into each component of the stacked outputs below and repeats it per component.
    t, ax, entering = jax.lax.optimization_barrier((t, ax, entering))
    sgn = jnp.sign(_pick3(dl, ax))
    sgn = jnp.where(sgn == 0, 1.0, sgn)
    outward = jnp.where(entering, -sgn, sgn)
    n = jnp.stack([_pick3(R[j], ax) * outward for j in range(3)])
    # In-face coordinates: the two axes other than `ax`.
    pl = [ol[i] + t * dl[i] for i in range(3)]
    ua = jnp.where(ax == 2, 0, ax + 1)
    va = jnp.where(ax == 0, 2, ax - 1)
    hu, hv = _pick3(half, ua), _pick3(half, va)
    uv = jnp.stack([V.safe_div(_pick3(pl, ua) + hu, 2 * hu), V.safe_div(_pick3(pl, va) + hv, 2 * hv)])
    rate = jnp.stack([V.safe_div(1.0, 2 * hu), V.safe_div(1.0, 2 * hv)])
    return t, n, uv, rate
