"""Primitive kinds: stacked parameter arrays, their ray intersections, and the kind
registry (:data:`raytrax.shapes.registry.KINDS`).

Each kind lives in one module (:mod:`~raytrax.shapes.sphere`,
:mod:`~raytrax.shapes.planar` for planes and quads, :mod:`~raytrax.shapes.disk`,
:mod:`~raytrax.shapes.triangles` for triangles, tetrahedra and meshes,
:mod:`~raytrax.shapes.box`) and is listed once in :mod:`~raytrax.shapes.registry`.

Intersection is done in two passes, which is what keeps reverse mode cheap:

1. ``closest_hit`` (in :mod:`raytrax.intersect`) finds, for every ray, the
   nearest primitive with every input under ``stop_gradient``: one vectorised
   test of all rays against blocks of primitives, a min-reduction, and nothing
   kept for the backward pass.
2. each kind's ``*_hit`` function recomputes the hit of each ray with *its*
   primitive only, differentiably: distance, outward geometric normal, surface
   coordinates ``(u, v)`` and the rate ``(su, sv)`` at which ``u`` and ``v``
   change per unit of world length (for texture filtering).

The gradient of step 2 equals the gradient of a min over all primitives (the
min's derivative flows to the arg-min), without storing ``rays x primitives``
residuals.
"""

from .base import INF, EdgePolygons, Key, KindSpec, SearchPart
from .box import Boxes, box_crossings, box_hit, box_soa, box_t, euler_matrix
from .disk import Disks, disk_hit, disk_soa, disk_t
from .planar import Planes, Quads, plane_hit, plane_soa, plane_t, quad_hit, quad_soa, quad_t
from .registry import BY_FIELD, BY_NAME, KINDS, OBJECT_TYPES
from .sphere import Spheres, sphere_crossings, sphere_hit, sphere_roots_safe, sphere_soa, sphere_t
from .triangles import Mesh, Tetrahedra, Triangles, ray_frame, tri_crossings, tri_hit, tri_soa, tri_t

__all__ = [
    "INF",
    "BY_FIELD",
    "BY_NAME",
    "KINDS",
    "OBJECT_TYPES",
    "Boxes",
    "Disks",
    "EdgePolygons",
    "Key",
    "KindSpec",
    "Mesh",
    "Planes",
    "Quads",
    "SearchPart",
    "Spheres",
    "Tetrahedra",
    "Triangles",
    "box_crossings",
    "box_hit",
    "box_soa",
    "box_t",
    "disk_hit",
    "disk_soa",
    "disk_t",
    "euler_matrix",
    "plane_hit",
    "plane_soa",
    "plane_t",
    "quad_hit",
    "quad_soa",
    "quad_t",
    "ray_frame",
    "sphere_crossings",
    "sphere_hit",
    "sphere_roots_safe",
    "sphere_soa",
    "sphere_t",
    "tri_crossings",
    "tri_hit",
    "tri_soa",
    "tri_t",
]
