"""The kind registry: the one place that knows which primitive kinds exist and in
which order.

``KINDS`` lists one :class:`~raytrax.shapes.base.KindSpec` per kind. Everything that
handles primitives loops over it: the scene builder and its ``Scene`` fields, the
scene file's object types, :func:`raytrax.parameters`, the closest-hit search
(:mod:`raytrax.intersect`: kinds in this order, the triangle-family kinds merged into
one triangle list at the place of the first of them), the boundary terms
(:mod:`raytrax.edges`: global primitive ids in this order, spheres first) and
``raytrax info``. Adding a kind is one module plus one entry here.
"""

from __future__ import annotations

from .base import KindSpec
from .box import BoxSpec
from .disk import DiskSpec
from .planar import PlaneSpec, QuadSpec
from .sphere import SphereSpec
from .triangles import MeshSpec, TetrahedronSpec, TriangleSpec

#: Every kind, in the order of search and of global primitive ids. The sphere kind
#: (the one kind :mod:`raytrax.edges` sees as a sphere) must stay first.
KINDS: tuple[KindSpec, ...] = (
    SphereSpec(),
    PlaneSpec(),
    QuadSpec(),
    DiskSpec(),
    TriangleSpec(),
    TetrahedronSpec(),
    MeshSpec(),
    BoxSpec(),
)

BY_NAME: dict[str, KindSpec] = {k.name: k for k in KINDS}
BY_FIELD: dict[str, KindSpec] = {k.field: k for k in KINDS}
#: The scene file's object types, in registry order.
OBJECT_TYPES: tuple[str, ...] = tuple(k.name for k in KINDS)

assert [k.edge for k in KINDS].count("sphere") == 1 and KINDS[0].edge == "sphere"
