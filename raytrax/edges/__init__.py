"""Boundary terms of the image derivative: silhouettes, hard shadows, and both
seen through mirrors and glass.

A pixel is the integral of the radiance ``f(x, theta)`` over its area. Where
``f`` jumps along a curve that moves with ``theta`` (an object's silhouette, the
line where two surfaces cross, a crease between two faces, the edge of a hard
shadow, any of these seen in a mirror or through glass), the derivative of that
integral has a *boundary* term besides the integral of ``df/dtheta`` that
automatic differentiation of the samples gives:

    dI/dtheta = int_P df/dtheta dA  +  int_(edges in P) (f_minus - f_plus) v_n dl

with ``v_n`` the speed of the edge along its normal (pointing to the ``plus``
side). This module estimates the second term; :func:`raytrax.render` adds it
when called with ``edge_gradients=True``.

Method (analytic edge functions found between neighbouring samples; see
``docs/gradients.md`` for why this and not edge sampling or reparameterisation):

1. A stop-gradient pass traces a regular ``n x n`` grid of samples per pixel
   along its *specular chain*: the camera ray, then at every mirror or glass
   hit the dominant child (the refracted ray of a material whose transparency is
   at least its reflectivity, unless totally internally reflected; else the
   reflected ray), for as many levels as the render's ``max_depth``. Per level
   it records the primitive hit (a box face or a triangle counts as its own
   primitive) and, for every light, the first and last occluder on the shadow
   segment from the hit to the light.
2. Two neighbouring samples (horizontal or vertical) whose records differ
   bracket an edge, at the first chain level where they differ. The chain prefix
   they share is a fixed sequence of primitives and branch kinds, so the ray at
   that level is a smooth function of the image position ``x`` and of the scene
   (this is how the refractive index moves an edge seen through glass). On that
   ray an *edge function* ``g(x, theta)`` is chosen, negative on the first
   sample's side and zero on the edge:

   * the first sample's primitive is missed by the second ray: ``g`` is that
     primitive's miss function (a sphere's ``|oc x d|^2 - r^2``, a polygon's
     signed distance from the ray's plane hit to its boundary, a convex solid's
     ``t_near - t_far``), and the same the other way round;
   * both rays hit both primitives: ``g = t_A - t_B``, the depth difference,
     whose zero set is where the two surfaces cross (or a crease);
   * a contact, where a polygon's silhouette edge lies on the other polygon's
     plane (a box resting on the floor; found by evaluating ``t_A - t_B`` at the
     located edge point): the depth difference, as where the two cross. Lifting
     the solid would reveal what lies under it, which neither sample sees, while
     sinking it only moves the line where the two meet: the image has a kink
     there, and this gives the sinking side's derivative;
   * same primitive, different shadow record for light ``k``: ``g`` is the
     occluder's miss function on the line from the hit point ``p(x)`` to the
     light, so it moves with the light, the occluder and the receiver.

3. The edge point ``x_s`` is found by bisection between the two samples, and
   the implicit function theorem gives the edge's displacement
   ``dx_s/dtheta = -g_theta / g_x``. Rows of samples estimate the boundary
   integral by Fubini (``int dy sum_crossings (f_a - f_b) dx_s/dtheta``), columns
   likewise; the two share each edge by the weights ``g_x^4`` and ``g_y^4`` over
   ``g_x^4 + g_y^4``, which keeps every term bounded however the edge is oriented
   and gives each edge mostly to the direction that crosses it steeply (there one
   crossing stands for a short piece of edge).
4. Each crossing stands for the piece of edge between the rows (columns) on
   either side of it. Where the edge ends or changes character inside that strip
   (a corner, a T-junction with another edge, the end of a shadow on another
   object), the piece is cut there: the edge is followed to the neighbouring row
   (Newton's method on ``g``) and the records on both sides of it are compared
   with those at ``x_s``; if they differ, bisection finds where (run only on the
   pieces where that comparison failed, packed together). The records
   include the hard procedural pattern (checker or stripes colour) at each hit,
   so a piece is also cut where a pattern edge meets it. Where the neighbouring
   row's pair of samples straddles another edge as well (a shadow edge running
   into a silhouette), that row has no crossing of this edge, and the rows on
   either side extend their pieces to it. The piece is then split between the
   pixels it crosses. This makes the quadrature error ``O(1/n^2)`` instead of
   ``O(1/n)`` at corners, T-junctions and pixel boundaries.
5. Each crossing adds

       c * g(x_s, theta),   c = -(f_a - f_b) ell sign(g_dir) w / |g_dir|

   (``ell``: the strip length the crossing stands for, ``1/n`` inside an edge)
   (``w``: the direction's weight above) to the pixels its piece covers, with
   ``c`` and ``x_s`` held constant: its value is ``0`` (``g(x_s) = 0``) and its
   derivative is the boundary term. ``f_a - f_b`` is the jump of the sample
   radiance (of one light's contribution for a shadow edge), measured by two
   probe rays just on either side of ``x_s`` with the hard (unfiltered)
   patterns: the limit the estimate converges to is the image as the samples
   grow, where the pattern filter's width goes to 0. A crossing whose probes do
   not see the two primitives that define it (near a corner, where the samples
   straddle two edges) adds nothing; the pieces of its neighbours are cut there.
   One exception, for a silhouette (a contact's too) and for a mesh face's
   shadow edge: where the probe on the far side sees a *third* primitive (or
   lies in the shadow of the mesh's next face), the jump is measured as it is,
   and the crossing beyond it is located as a new event of the same pair,
   between that probe and the far sample; it may find a fourth, and so on. Next
   to the outline of a coarse closed mesh the faces are seen almost edge-on, and
   most pairs straddle a crease and the outline at once. A neighbouring row
   counts as having the crossing of such an edge when its sample on the far
   side sees the same as this pair's and its other sample something else. A
   mesh is one occluder for its shadow's edges: a closed mesh's shadow segment
   crosses a front and a back face, both recorded, and its shadow's edge (its
   outline seen from the light) is counted once.
6. A sphere's silhouette needs two more things, because the radiance beside it
   goes like ``f_s + a sqrt(distance)`` (the hit slides along the ray as
   ``sqrt(-g)``): the inside probe is extrapolated to the edge with ``a``,
   fitted to it and to two more rays 1/16 and 1/4 of the spacing inside; and
   the interior term of the samples (plain AD), which has the integrable
   singularity ``d t_hit / d theta = g_theta / (2 sqrt(-g))`` there, is
   integrated better than the grid does: along each crossing row, the first
   two inside samples (at ``k + phi`` spacings from the edge) are replaced by
   the integral of the samples' derivative from the edge to ``1.5 + phi``,
   by 6-point Gauss-Legendre in ``u = sqrt(distance)``, where the singularity
   is smooth and a terminator's kink just inside (where the radiance starts
   to grow like ``sqrt(distance - d_k)``) is a kink, not a singularity. These
   are 8 differentiable camera rays per silhouette crossing, traced as the
   grid's samples are, weighted by the crossing's row weight and piece length
   (value zero: the nodes minus the samples they replace, minus its own
   stop-gradient). A row's error on the singular term, ``sqrt(h) zeta(1/2,
   phi)`` (Hurwitz zeta) per unit of ``a``, has a sign that depends on where
   the samples fall, so on a grid it adds up along a silhouette instead of
   averaging out. Without both, a lone sphere's vertical centre gradient is
   14 % off at spp 256 and at 1024 (see ``docs/gradients.md``;
   ``benchmarks/bench_sphere_edges.py`` measures the sphere of
   ``scenes/edge_sphere.toml``).

The estimate converges to the derivative of the pixel integral as ``n`` grows.
What it does not include: edges along the non-dominant specular branch (the
faint reflection on glass), a change between refraction and total internal
reflection (continuous in the physical model; a jump in the classic one),
edges of procedural textures (use ``filter_textures=True``, which makes them
continuous), the horizon of an infinite plane, the terminator of a surface lit
at grazing angles (there the jump is zero anyway), and pairs of samples that
straddle two edges closer together than the sample spacing (but for the
exception of step 5).
"""

from .events import DEPTH, MISS, SHADOW, Events, edge_value
from .prims import Prims, build_prims, first_t, id_offsets, kind_ids, miss
from .records import Records, object_key, records
from .term import (
    BISECTION_STEPS,
    CHUNK,
    END_STEPS,
    NEWTON_STEPS,
    QUAD_NODES,
    QUAD_SAMPLES,
    EdgeOptions,
    edge_image,
    find_edges,
)

__all__ = [
    "BISECTION_STEPS",
    "CHUNK",
    "DEPTH",
    "END_STEPS",
    "MISS",
    "NEWTON_STEPS",
    "QUAD_NODES",
    "QUAD_SAMPLES",
    "SHADOW",
    "EdgeOptions",
    "Events",
    "Prims",
    "Records",
    "build_prims",
    "edge_image",
    "edge_value",
    "find_edges",
    "first_t",
    "id_offsets",
    "kind_ids",
    "miss",
    "object_key",
    "records",
]
