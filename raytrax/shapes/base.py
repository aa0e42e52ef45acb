"""What every primitive kind shares: the :class:`KindSpec` interface that the kind
registry (:mod:`raytrax.shapes.registry`) lists, parameter keys, and small helpers.

A kind is one module of :mod:`raytrax.shapes` holding

* an :class:`equinox.Module` with the stacked parameters of all primitives of the
  kind (struct of arrays: ``Spheres.center (N, 3)``), ``material (N,)`` int ids;
* stop-gradient search kernels ``*_t(ray, P, tmin) -> (n, B)`` over struct-of-arrays
  components (``P`` from ``*_soa``), and a differentiable per-ray recomputation
  ``*_hit(..., o, d, t0) -> (t, normal, uv, rate)`` (see :mod:`raytrax.intersect`);
* a :class:`KindSpec` subclass: how the kind is validated, built, described,
  named by :func:`raytrax.parameters`, searched, and seen by the boundary terms
  of :mod:`raytrax.edges`.

Conventions: world units are arbitrary but consistent; normals are unit length and
point out of closed objects (for planes, quads, disks and triangles: the side given
by the right-hand rule or the stated normal); vectors inside kernels are
component-major ``(3, n)`` (see :mod:`raytrax.vec`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import vec as V

INF = float("inf")


def check_shape(name, arr, shape):
    """Raise ``ValueError`` unless ``arr.shape`` matches ``shape`` (``None``: any size)."""
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=False)):
        raise ValueError(f"{name}: expected shape {shape}, got {tuple(arr.shape)}")


def plane_distance(point, normal, o, d):
    """Distance along ``d`` from ``o`` (``(3, n)`` each) to the plane through ``point``
    with normal ``normal`` (``(3, n)`` or broadcastable; need not be unit): the ray
    parameter ``t`` of the hit, in units of ``|d|``; 0 where ``d`` is parallel to the
    plane. Differentiable everywhere (:func:`raytrax.vec.safe_div`); the one home of
    the ray-plane formula for planes, quads, disks and the edge functions."""
    return V.safe_div(V.dot(point - o, normal), V.dot(d, normal))


def tangent_frame(n):
    """Two unit tangents (3, n) for normals (3, n); u-axis is x projected on the plane
    (z for planes facing x)."""
    ex = jnp.stack([jnp.ones_like(n[0]), jnp.zeros_like(n[0]), jnp.zeros_like(n[0])])
    ez = jnp.stack([jnp.zeros_like(n[0]), jnp.zeros_like(n[0]), jnp.ones_like(n[0])])
    a = V.vsel(jnp.abs(n[0]) < 0.9, ex, ez)
    tu = V.normalize(a - V.dot(a, n)[None] * n)
    tv = V.cross(n, tu)
    return tu, tv


def unit_rows(x):
    """Rows of ``x (..., 3)`` scaled to unit length (zero rows stay zero)."""
    n2 = jnp.sum(x * x, -1, keepdims=True)
    ok = n2 > 1e-30
    return jnp.where(ok, x / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0)


class Key(NamedTuple):
    """One parameter of a kind as the scene file, the builder and
    :func:`raytrax.parameters` name it.

    ``attr``: the field of the kind's module; ``shape``: per primitive; ``ftype``: how
    the scene file reads it (``vec3``, ``nonzero3``, ``positive``, ``matrix``,
    ``angles3``); ``default``: ``None`` when required.
    """

    name: str
    attr: str
    shape: tuple
    ftype: str
    default: Any = None
    what: str = ""  # the words of a file error ("a positive edge length")


class SearchPart(NamedTuple):
    """What :func:`raytrax.intersect.prepare` needs of a kind: stop-gradient
    component arrays ``(N,)``, materials, the ``(ray, P, tmin) -> (n, B)`` distance
    kernel, the differentiable ``(idx, o, d, t0) -> (t, n, uv, rate)`` hit, the
    surface-crossing kernel of shadow rays (``None``: one crossing per hit), and each
    primitive's curvature ``(N,)`` (1 / radius, per world unit; ``None``: flat), which
    widens the texture footprint of rays a curved mirror reflects, and its world-space
    bounding box ``bounds (2, 3, N)`` (lower, upper corner; ``None``: unbounded, never
    culled), with which a kind of many primitives is searched in culled groups."""

    soa: dict
    material: jax.Array
    tfun: Callable
    hit: Callable
    crossings: Callable | None = None
    curvature: jax.Array | None = None
    bounds: jax.Array | None = None


def ball_bounds(center, radius):
    """``SearchPart.bounds`` ``(2, 3, N)`` of balls of ``center (N, 3)`` and ``radius
    (N,)``: the box of a sphere, and a safe (loose) one for a disk of that radius."""
    r = jnp.abs(radius)[:, None]
    return jnp.stack([(center - r).T, (center + r).T])


class EdgePolygons(NamedTuple):
    """A kind's primitives as convex planar polygons for :mod:`raytrax.edges`, ``P``
    polygons of at most 4 edges: a point of the plane ``pp (P, 3)``, the unit normal
    ``pn (P, 3)``, edge origins ``eo (P, 4, 3)`` and unit in-plane edge normals
    pointing inside ``em (P, 4, 3)``, ``finite (P,)`` (False: an infinite plane),
    ``radius (P,)`` (> 0: a disk of that radius about ``pp``, edges unused), and
    ``material (P,)``."""

    pp: jax.Array
    pn: jax.Array
    eo: jax.Array
    em: jax.Array
    finite: jax.Array
    radius: jax.Array
    material: jax.Array


def polygons_from_edges(origins, dirs, normal, material, finite=None, radius=None):
    """:class:`EdgePolygons` from edge origins and directions ``(N, 4, 3)`` and
    normals ``(N, 3)``."""
    n = unit_rows(normal)
    m = unit_rows(jnp.cross(n[:, None, :], dirs))
    N = normal.shape[0]
    fin = jnp.ones((N,), bool) if finite is None else finite
    rad = jnp.zeros((N,), normal.dtype) if radius is None else radius
    return EdgePolygons(origins[:, 0], n, origins, m, fin, rad, material.astype(jnp.int32))


def quad_polygons(corners, material):
    """:class:`EdgePolygons` of convex quads ``corners (N, 4, 3)`` in order around the edge."""
    c = corners
    e = jnp.roll(c, -1, axis=1) - c
    n = jnp.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1])
    return polygons_from_edges(c, e, n, material)


def F64(x, shape=None):
    """A finite float64 NumPy array of ``shape``, or ``ValueError`` naming nothing
    (callers prefix the key path)."""
    a = np.asarray(x, dtype=np.float64)
    if shape is not None and a.shape != tuple(shape):
        raise ValueError(f"expected shape {tuple(shape)}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"expected finite numbers, got {x!r}")
    return a


def check_stored(spec, p: dict, where: str) -> None:
    """Run ``spec.check`` again on the values as a float32 scene stores them: a value
    that rounds to infinity, or geometry that rounding makes degenerate (a radius to 0,
    a quad's corners out of plane), is refused here rather than by the loader later."""
    stored = {}
    for k, v in p.items():
        a = np.asarray(v)
        if not np.issubdtype(a.dtype, np.floating):
            stored[k] = a
            continue
        with np.errstate(over="ignore"):
            s = a.astype(np.float32)
        if not np.all(np.isfinite(s)):
            raise ValueError(f"{where}.{k}: expected numbers within the float32 range, got {v!r}")
        stored[k] = s.astype(np.float64)
    try:
        spec.check(stored, where)
    except ValueError as e:
        raise ValueError(f"{e} (the value as stored in float32)") from None


def _plain(x):
    """``x`` (array) as nested Python floats (tuples), or a float."""
    a = np.asarray(x, np.float64)
    if a.ndim == 0:
        return float(a)
    if a.ndim == 1:
        return tuple(float(v) for v in a)
    return tuple(_plain(r) for r in a)


@dataclasses.dataclass(frozen=True)
class KindSpec:
    """One primitive kind, as the rest of raytrax sees it.

    The defaults implement a *stacked* kind: its module's fields are the keys'
    ``attr`` (each ``(N,) + shape``) then ``material (N,)``. Subclasses set the
    class attributes and override what differs.
    """

    name: ClassVar[str]  # the scene file's type and the object kind
    field: ClassVar[str]  # the Scene attribute (``scene.spheres``)
    module: ClassVar[type]
    keys: ClassVar[tuple[Key, ...]]
    edge: ClassVar[str] = "polygon"  # how raytrax.edges sees it: "sphere", "polygon" or "disk" (a round polygon)
    faces_per: ClassVar[int] = 1  # edge-primitive ids per object (a box's 6 faces)
    solid_faces: ClassVar[int] = 0  # faces of one convex solid (box 6, tetrahedron 4), 0: not a solid
    triangle_family: ClassVar[bool] = False  # searched in the merged triangle list
    builder_args: ClassVar[tuple[str, ...]] = ()  # positional builder arguments of a kind without keys

    # -- description -> runtime ------------------------------------------------
    def validate(self, params: dict, where: str) -> dict:
        """Check and convert one primitive's ``params`` (key name -> value) for the
        builder; errors are ``ValueError`` starting with ``where.key``."""
        out = {}
        for k in self.keys:
            v = params.get(k.name, k.default)
            if v is None:
                raise ValueError(f"{where}.{k.name}: missing")
            try:
                out[k.name] = F64(v, k.shape)
            except ValueError as e:
                raise ValueError(f"{where}.{k.name}: {e}") from None
        self.check(out, where)
        check_stored(self, out, where)
        return out

    def check(self, p: dict, where: str) -> None:
        """Value checks beyond shapes and finiteness (geometry), on validated ``p``."""

    def build(self, items: list, F: Callable, I: Callable):
        """The kind's module from ``items``: ``(params, material id)`` pairs in object
        order; ``F(x, shape)`` makes float leaves, ``I(x)`` int ids."""
        cols = [F([p[k.name] for p, _ in items], (-1,) + k.shape) for k in self.keys]
        return self.module(*cols, I([m for _, m in items]))

    def count(self, group) -> int:
        return int(group.material.shape[0])

    def describe(self, group, j: int) -> tuple[dict, int]:
        """Primitive ``j``'s parameters (Python floats and tuples) and material id."""
        p = {}
        for k in self.keys:
            v = _plain(getattr(group, k.attr)[j])
            if k.default is not None and np.array_equal(np.asarray(v), np.asarray(k.default, np.float64)):
                continue  # an optional key at its default is not written
            p[k.name] = v
        return p, int(group.material[j])

    def slots(self, group, j: int) -> list:
        """``(key, get(group) -> leaf, row, shape)`` of primitive ``j``'s named parameters."""
        return [(k.name, (lambda g, a=k.attr: getattr(g, a)), j, k.shape) for k in self.keys]

    def n_ids(self, group) -> int:
        """Global primitive ids of the group in :mod:`raytrax.edges` (polygons or spheres)."""
        return self.count(group) * self.faces_per

    def n_triangles(self, params: dict) -> int:
        """Triangles one primitive adds to the merged triangle list."""
        return 0

    def face_groups(self, group) -> tuple[int, ...]:
        """Edge-primitive ids per object, for kinds whose objects are made of faces
        that :mod:`raytrax.edges` must treat as one occluder (a mesh: its shadow's
        edge is its outline, which several of its faces share); ``()`` for every
        other kind (a convex solid's faces are grouped by ``solid_faces``)."""
        return ()

    # -- traced ----------------------------------------------------------------
    def search(self, group) -> SearchPart | None:
        """The kind's own search, or ``None`` for triangle-family kinds."""
        return None

    def triangles(self, group):
        """Triangle family: ``(vertices (T, 3, 3), material (T,))`` of the whole group."""
        raise NotImplementedError

    def edge_polygons(self, group) -> EdgePolygons:
        """Polygon kinds: the group as :class:`EdgePolygons` (``faces_per`` per object)."""
        raise NotImplementedError

    def edge_face(self, group, idx, o, d, t):
        """Kinds with ``faces_per > 1``: which face of primitive ``idx`` the ray
        ``o + t d`` meets, ``(n,)`` int in ``[0, faces_per)``."""
        return jnp.zeros(idx.shape, jnp.int32)
