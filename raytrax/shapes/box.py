"""Boxes: axis-aligned corners rotated about their centre."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .. import vec as V
from .base import INF, Key, KindSpec, SearchPart, check_shape, quad_polygons


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
        check_shape("Boxes.lo", self.lo, (n, 3))
        check_shape("Boxes.hi", self.hi, (n, 3))
        check_shape("Boxes.rotation", self.rotation, (n, 3))
        check_shape("Boxes.material", self.material, (n,))


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


def box_frame(b: Boxes):
    """Rotation ``(N, 3, 3)``, centre ``(N, 3)`` and half sizes ``(N, 3)`` of boxes."""
    return euler_matrix(b.rotation), 0.5 * (b.lo + b.hi), 0.5 * jnp.abs(b.hi - b.lo)


def box_soa(b: Boxes):
    R, c, h = box_frame(b)
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
    """Entry and exit distances ``tn, tf`` of the slab test (the box is missed where
    ``tn > tf`` or either is NaN). No gradient flows here (the search), so the IEEE
    infinities of ``1 / 0`` do the work of a parallel-ray branch: a ray parallel to a
    slab gets ``(-inf, inf)`` inside it and an empty interval outside; exactly on its
    boundary plane ``0 * inf`` makes both NaN, and every comparison then misses."""
    ol, dl = _box_local(ray, P)
    h = [P["hx"], P["hy"], P["hz"]]
    tn, tf = -INF, INF
    for i in range(3):
        inv = 1.0 / dl[i]
        t1 = (-h[i] - ol[i]) * inv
        t2 = (h[i] - ol[i]) * inv
        tn = jnp.maximum(tn, jnp.minimum(t1, t2))
        tf = jnp.minimum(tf, jnp.maximum(t1, t2))
    return tn, tf


def box_crossings(ray, P, tmax):
    """Number of surface crossings (0, 1 or 2) of each ray's open segment ``(0, tmax)``."""
    tn, tf = _box_slab(ray, P)
    ok = tn <= tf
    n1 = ok & (tn > 0) & (tn < tmax)
    n2 = ok & (tf > 0) & (tf < tmax)
    return n1.astype(ray[0].dtype) + n2.astype(ray[0].dtype)


def box_t(ray, P, tmin):
    tn, tf = _box_slab(ray, P)
    t = jnp.where(tn > tmin, tn, tf)
    return jnp.where((tn <= tf) & (tf > tmin), t, INF)


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


def _face_signs():
    """``(6, 4, 3)`` corner signs of the unit box's faces, face ``2 axis + (side > 0)``."""
    out = []
    for a in range(3):
        u, v = (a + 1) % 3, (a + 2) % 3
        for s in (-1.0, 1.0):
            face = []
            order = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
            for su, sv in order if s > 0 else order[::-1]:  # counter-clockwise seen from outside
                c = [0.0, 0.0, 0.0]
                c[a], c[u], c[v] = s, su, sv
                face.append(c)
            out.append(face)
    return out


def box_faces(boxes: Boxes):
    """Box faces as quads ``(6 N, 4, 3)``, face ``2 axis + (side > 0)`` of each box."""
    R, c, h = box_frame(boxes)
    loc = jnp.asarray(_face_signs(), c.dtype)[None] * h[:, None, None, :]  # (N, 6, 4, 3)
    world = c[:, None, None, :] + jnp.einsum("nij,nfkj->nfki", R, loc)
    return world.reshape(-1, 4, 3)


class BoxSpec(KindSpec):
    name: ClassVar[str] = "box"
    field: ClassVar[str] = "boxes"
    module: ClassVar[type] = Boxes
    keys: ClassVar[tuple] = (
        Key("min", "lo", (3,), "vec3"),
        Key("max", "hi", (3,), "vec3"),
        Key("rotation", "rotation", (3,), "angles3", default=(0.0, 0.0, 0.0)),
    )
    faces_per: ClassVar[int] = 6
    solid_faces: ClassVar[int] = 6

    def check(self, p, where):
        lo, hi = p["min"], p["max"]
        if np.any(hi <= lo):
            raise ValueError(
                f"{where}.max: expected every component greater than min, got min={lo.tolist()} max={hi.tolist()}"
            )

    def search(self, g):
        R, c, h = box_frame(g)
        table = jnp.concatenate([R.reshape(-1, 9), c, h], 1)  # per box, not per ray

        def hit(i, o, d, t0):
            P = V.gather_rows(table, i)
            return box_hit(P[9:12], P[12:15], [P[0:3], P[3:6], P[6:9]], o, d, t0)

        ext = jnp.einsum("nij,nj->ni", jnp.abs(R), h)  # half extent of the rotated box per world axis
        return SearchPart(
            box_soa(g), g.material, box_t, hit, box_crossings, bounds=jnp.stack([(c - ext).T, (c + ext).T])
        )

    def edge_polygons(self, g):
        return quad_polygons(box_faces(g), jnp.repeat(g.material, 6))

    def edge_face(self, g, idx, o, d, t):
        """Face ``2 axis + (side > 0)`` of box ``idx`` where ray ``o + t d`` meets it."""
        R, c, h = box_frame(g)
        R, c, h = R[idx], c[idx].T, h[idx].T
        p = o + t[None] * d
        loc = jnp.einsum("nji,jn->in", R, p - c)  # R^T (p - c)
        rel = jnp.abs(loc) / jnp.maximum(h, 1e-30)
        ax = jnp.argmax(rel, 0)
        side = jnp.take_along_axis(loc, ax[None], 0)[0] > 0
        return 2 * ax.astype(jnp.int32) + side.astype(jnp.int32)
