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
   with those at ``x_s``; if they differ, bisection finds where. The records
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
straddle two edges closer together than the sample spacing.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import textures as tx
from . import vec as V
from .camera import rays_through
from .intersect import EPS_REL, closest_kind, no_hit, prepare
from .lights import LIGHTS
from .materials import fresnel_dielectric, refract
from .shapes import KINDS
from .textures import pattern_cell

BISECTION_STEPS = 14  # edge point between two samples: 2^-14 of their spacing
END_STEPS = 8  # end of an edge piece inside its strip: 2^-8 of the spacing
NEWTON_STEPS = 3  # following an edge to the neighbouring row
CHUNK = 512  # events solved per step of the (skippable) chunk loop
QUAD_SAMPLES = 2  # inside samples of a sphere's silhouette row replaced by a quadrature
QUAD_NODES = 6  # its Gauss-Legendre nodes in sqrt(distance)
MAX_FACES = 6


class Prims(NamedTuple):
    """Every primitive as a sphere or a convex planar polygon (component-major).

    Global ids: spheres ``[0, ns)``, then polygons: planes, quads, triangles
    (in the order of :meth:`raytrax.Scene.merged_triangles`), box faces (6 per box,
    face ``2 axis + (side > 0)``).
    """

    c: jax.Array  # (3, Ns) sphere centres
    r: jax.Array  # (Ns,)
    pp: jax.Array  # (3, Np) a point of the polygon's plane
    pn: jax.Array  # (3, Np) unit plane normal
    eo: jax.Array  # (4, 3, Np) edge origins
    em: jax.Array  # (4, 3, Np) unit in-plane edge normals pointing inside
    finite: jax.Array  # (Np,) False for infinite planes
    prad: jax.Array  # (Np,) > 0: a disk of that radius about pp (the edges are unused)
    solid: jax.Array  # (Np,) polygon index of the first face of its convex solid, -1: none
    nface: jax.Array  # (Np,) faces of that solid (6 box, 4 tetrahedron, 0 none)
    light: jax.Array  # (3, L) positions; directions of travel where ldir
    ldir: jax.Array  # (L,) the light is directional
    far: jax.Array  # () beyond every finite primitive (the far end of a directional light's shadow segment)
    mat: jax.Array  # (Ns + Np,) material of each global id
    trans: jax.Array  # (M,) transparency
    refl: jax.Array  # (M,) largest reflectivity component
    ior: jax.Array  # (M,) refractive index


def build_prims(scene) -> tuple[Prims, dict]:
    """The :class:`Prims` of ``scene`` (differentiable), in the order of the kind
    registry (:data:`raytrax.shapes.KINDS`), and :func:`id_offsets` with the
    ``solid`` table (polygon index of each polygon's solid's first face, -1: none)."""
    dt = scene.dtype
    off = id_offsets(scene)
    ns = off["ns"]
    parts = []  # EdgePolygons per kind
    solids = []  # (first polygon index, faces per solid, number of solids)
    for spec in KINDS:
        if spec.edge == "sphere":
            continue
        group = scene.prims[spec.field]
        n = spec.n_ids(group)
        if not n:
            continue
        if spec.solid_faces:
            solids.append((off[spec.name] - ns, spec.solid_faces, n // spec.solid_faces))
        parts.append(spec.edge_polygons(group))
    if parts:
        pp, pn, eo, em, fin, prad, pmat = (jnp.concatenate(x, 0) for x in zip(*parts, strict=True))
    else:  # one dummy polygon keeps the gathers well defined
        pp = pn = jnp.zeros((1, 3), dt)
        eo = em = jnp.zeros((1, 4, 3), dt)
        fin = jnp.zeros((1,), bool)
        prad = jnp.zeros((1,), dt)
        pmat = jnp.zeros((1,), jnp.int32)
    npoly = fin.shape[0]
    solid = np.full((npoly,), -1, np.int32)
    nface = np.zeros((npoly,), np.int32)
    for start, k, m in solids:
        idx = start + np.arange(k * m)
        solid[idx] = start + (np.arange(k * m) // k) * k
        nface[idx] = k
    sph = scene.prims[KINDS[0].field]
    if ns:
        c, r = sph.center.T, sph.radius
        smat = sph.material.astype(jnp.int32)
    else:
        c, r = jnp.zeros((3, 1), dt), jnp.zeros((1,), dt)
        smat = jnp.zeros((0,), jnp.int32)
    mat = jnp.concatenate([smat, pmat.astype(jnp.int32)])
    ms = scene.materials
    lg = [(s.edge_geometry(scene.light_sets[s.field]), s.directional) for s in LIGHTS]
    lg = [(g, flag) for g, flag in lg if g.shape[0]]
    if lg:
        L = jnp.concatenate([g for g, _ in lg], 0).T
        ldir = jnp.concatenate([jnp.full((g.shape[0],), flag) for g, flag in lg])
    else:
        L, ldir = jnp.zeros((3, 1), dt), jnp.zeros((1,), bool)
    # A bound on every finite primitive's distance from the origin.
    ext = jnp.max(jnp.abs(eo), axis=(1, 2)) * 2.0 + jnp.max(jnp.abs(pp), axis=1) + prad
    far = jnp.max(jnp.where(fin, ext, 0.0))
    if ns:
        far = jnp.maximum(far, jnp.max(jnp.max(jnp.abs(c), axis=0) * 2.0 + r))
    far = jax.lax.stop_gradient(2.0 * far + 1.0)
    prims = Prims(
        c,
        r,
        pp.T,
        pn.T,
        jnp.transpose(eo, (1, 2, 0)),
        jnp.transpose(em, (1, 2, 0)),
        fin,
        prad,
        jnp.asarray(solid),
        jnp.asarray(nface),
        L,
        ldir,
        far,
        mat,
        ms.transparency,
        jnp.max(ms.reflectivity, axis=1),
        ms.ior,
    )
    return prims, dict(off, solid=solid)


# ----------------------------------------------------------------------------
# Per-event geometry: ``ids (E,)`` global primitive ids, rays ``o, d (3, E)``.
# ----------------------------------------------------------------------------


def _split(P: Prims, ns, ids):
    is_s = ids < ns
    si = jnp.clip(ids, 0, P.r.shape[0] - 1)
    pi = jnp.clip(ids - ns, 0, P.finite.shape[0] - 1)
    return is_s, si, pi


def miss(P: Prims, ns, ids, o, d):
    """Miss function of primitive ``ids`` for the line ``o + t d``: ``> 0`` when the
    line misses it, ``< 0`` when it hits, zero on its silhouette; and an integer
    *feature* naming the smooth piece of it that is active (the polygon edge, the
    entry and exit planes of a convex solid; 0 for a sphere), which changes at a
    corner of the silhouette."""
    is_s, si, pi = _split(P, ns, ids)
    oc = P.c[:, si] - o
    x = V.cross(oc, d)
    gs = V.dot(x, x) - P.r[si] ** 2 * V.dot(d, d)
    n = P.pn[:, pi]
    t = V.safe_div(V.dot(P.pp[:, pi] - o, n), V.dot(d, n))
    p = o + t[None] * d
    s = jnp.stack([V.dot(p - P.eo[i][:, pi], P.em[i][:, pi]) for i in range(4)])
    gp = -jnp.min(s, 0)
    feat = jnp.argmin(s, 0).astype(jnp.int32)
    gp = jnp.where(P.finite[pi], gp, -1.0)
    # A disk: distance of the plane hit from its centre beyond the radius.
    disk = P.prad[pi] > 0
    gp = jnp.where(disk, V.norm(p - P.pp[:, pi]) - P.prad[pi], gp)
    feat = jnp.where(disk, 0, feat)
    if P.solid.shape[0] and MAX_FACES:
        # A face of a convex solid (box, tetrahedron): the solid's own miss function,
        # t_near - t_far over its face planes, so that a crease between two of its
        # faces is never mistaken for its silhouette.
        first = jnp.maximum(P.solid[pi], 0)
        big = jnp.asarray(1e30, o.dtype)
        tn, tf = -big, big
        jn = jf = jnp.zeros_like(feat)
        for j in range(MAX_FACES):
            fj = jnp.clip(first + j, 0, P.finite.shape[0] - 1)
            use = j < P.nface[pi]
            nj = P.pn[:, fj]
            den = V.dot(d, nj)
            num = V.dot(P.pp[:, fj] - o, nj)
            t = V.safe_div(num, den)
            par = jnp.abs(den) <= 1e-30
            enter = jnp.where(par, jnp.where(num >= 0, -big, big), jnp.where(den < 0, t, -big))
            leave = jnp.where(par, jnp.where(num >= 0, big, -big), jnp.where(den > 0, t, big))
            jn = jnp.where(use & (enter > tn), j, jn)
            jf = jnp.where(use & (leave < tf), j, jf)
            tn = jnp.where(use, jnp.maximum(tn, enter), tn)
            tf = jnp.where(use, jnp.minimum(tf, leave), tf)
        solid = P.solid[pi] >= 0
        gp = jnp.where(solid, tn - tf, gp)
        feat = jnp.where(solid, 8 * jn + jf, feat)
    return jnp.where(is_s, gs, gp), jnp.where(is_s, 0, feat)


def first_t(P: Prims, ns, ids, o, d):
    """Distance along unit ``d`` to the first crossing of primitive ``ids``'s surface
    (a sphere's first positive root, a polygon's plane)."""
    is_s, si, pi = _split(P, ns, ids)
    oc = P.c[:, si] - o
    b = V.dot(oc, d)
    disc = b * b - (V.dot(oc, oc) - P.r[si] ** 2)
    sq = V.safe_sqrt(disc)
    ts = jnp.where(b - sq > 0, b - sq, b + sq)
    n = P.pn[:, pi]
    tp = V.safe_div(V.dot(P.pp[:, pi] - o, n), V.dot(d, n))
    return jnp.where(is_s, ts, tp)


def _step(P: Prims, ns, ids, want_t, o, d):
    """The specular child of rays ``o, d (3, E)`` at their hit on primitive ``ids``:
    refracted where ``want_t`` (unless totally internally reflected), else
    reflected, from the same offset origins as the renderer's. Returns the child's
    origin and direction and whether it was refracted."""
    is_s, si, pi = _split(P, ns, ids)
    t = first_t(P, ns, ids, o, d)
    p = o + t[None] * d
    n = V.vsel(is_s, V.normalize(p - P.c[:, si]), P.pn[:, pi])
    cos_d = V.dot(d, n)
    front = cos_d < 0
    n_s = V.vsel(front, n, -n)
    cos_i = jnp.abs(cos_d)
    ior = P.ior[P.mat[jnp.clip(ids, 0, P.mat.shape[0] - 1)]]
    eta = jnp.where(front, V.safe_div(1.0, ior), ior)
    _, cos_t, tir = fresnel_dielectric(cos_i, eta)
    refr = want_t & ~tir
    eps = EPS_REL * (1.0 + jnp.max(jnp.abs(p), 0))
    o2 = V.vsel(refr, p - eps[None] * n_s, p + eps[None] * n_s)
    d2 = V.vsel(refr, refract(d, n_s, eta, cos_t), V.reflect(d, n_s))
    return o2, d2, refr


MISS, DEPTH, SHADOW = 0, 1, 2


class Events(NamedTuple):
    typ: jax.Array  # (E,) MISS, DEPTH or SHADOW
    level: jax.Array  # (E,) chain level of the edge (0: seen directly)
    chain: jax.Array  # (D, E) primitives of the shared chain (levels < level are used)
    refr: jax.Array  # (D, E) the chain refracts (else reflects) at that level
    p1: jax.Array  # (E,) primitive missed (MISS), A (DEPTH), receiver (SHADOW)
    p2: jax.Array  # (E,) B (DEPTH), occluder (SHADOW)
    light: jax.Array  # (E,) light index (SHADOW)
    sign: jax.Array  # (E,) +-1: g = sign * G is <= 0 on the first sample's side


def _chain_ray(scene, P: Prims, ns, ev: Events, xy, width, height):
    """The ray at each event's chain level, for image positions ``xy (2, E)``."""
    o, d = rays_through(scene.camera, xy, width, height)
    for lv in range(ev.chain.shape[0] - 1):
        o2, d2, _ = _step(P, ns, ev.chain[lv], ev.refr[lv], o, d)
        go = lv < ev.level
        o, d = V.vsel(go, o2, o), V.vsel(go, d2, d)
    return o, d


def edge_value(scene, P: Prims, ns, ev: Events, xy, width, height, feature=False):
    """``G(x)`` of each event at image positions ``xy (2, E)`` (before ``sign``), and
    with ``feature=True`` also the feature of :func:`miss` (0 for depth crossings)."""
    o, d = _chain_ray(scene, P, ns, ev, xy, width, height)
    ta = first_t(P, ns, ev.p1, o, d)
    tb = first_t(P, ns, ev.p2, o, d)
    shadow = ev.typ == SHADOW
    p = o + ta[None] * d
    li = jnp.clip(ev.light, 0, P.light.shape[1] - 1)
    L = P.light[:, li]
    toward = V.vsel(P.ldir[li], V.normalize(-L), V.normalize(L - p))
    o2 = V.vsel(shadow, p, o)
    d2 = V.vsel(shadow, toward, d)
    m, f = miss(P, ns, jnp.where(ev.typ == MISS, ev.p1, ev.p2), o2, d2)
    depth = ev.typ == DEPTH
    G = jnp.where(depth, ta - tb, m)
    return (G, jnp.where(depth, 0, f)) if feature else G


# ----------------------------------------------------------------------------
# The stop-gradient sample records.
# ----------------------------------------------------------------------------


def _search(scene, kinds, off, o, d, tmax=None):
    """Global id (-1: none) and distance of the first primitive along rays ``o, d``
    (closer than ``tmax`` when given)."""
    n = o.shape[1]
    ray = (o[0], o[1], o[2], d[0], d[1], d[2])
    best_t = jnp.full((n,), jnp.inf, o.dtype)
    best_id = jnp.full((n,), -1, jnp.int32)
    for k in kinds:
        t, idx = closest_kind(k, ray, 0.0)
        start, _, per = kind_ids(off, k)
        gid = start + per * idx
        if per > 1:  # which face of the primitive (a box's)
            group = scene.prims[k.spec.field]
            gid = gid + k.spec.edge_face(group, idx, o, d, jnp.where(jnp.isfinite(t), t, 0.0))
        better = t < best_t
        best_t = jnp.where(better, t, best_t)
        best_id = jnp.where(better, gid, best_id)
    if tmax is not None:
        best_id = jnp.where(best_t < tmax, best_id, -1)
    return best_id, best_t


def kind_ids(off, k) -> tuple[int, int, int]:
    """Global ids of the primitives of search kind ``k`` (:func:`raytrax.intersect.prepare`):
    ``[start, end)``, ``per`` ids per primitive (a box's 6 faces)."""
    return off["spans"][k.name]


def id_offsets(scene) -> dict:
    """First global id of each kind (registry order, see :class:`Prims`), ``ns`` (the
    number of spheres), ``total``, and ``spans``: ``(start, end, per)`` of each
    search kind of :func:`raytrax.intersect.prepare` (``"triangle"``: the merged
    triangle list)."""
    off: dict = {}
    spans: dict = {}
    g = 0
    for spec in KINDS:
        n = spec.n_ids(scene.prims[spec.field])
        off[spec.name] = g
        if spec.triangle_family:
            s0 = spans.get("triangle", (g, g, 1))[0]
            spans["triangle"] = (s0, g + n, 1)
        else:
            spans[spec.name] = (g, g + n, spec.faces_per)
        g += n
    off["ns"] = off[KINDS[1].name]
    off["total"] = g
    off["spans"] = spans
    return off


class Records(NamedTuple):
    """What the specular chain of each camera ray meets (no gradient), ``D`` levels."""

    hit: jax.Array  # (D, M) primitive at each level; -1 background, -2 the chain has ended
    refr: jax.Array  # (D, M) the chain refracts (else reflects) at that hit
    first: jax.Array  # (D, L, M) first occluder between the hit and each light (-1: none; see object_key)
    last: jax.Array  # (D, L, M) last occluder
    cell: jax.Array  # (D, M) the hard procedural pattern at the hit (0 / 1; see textures.pattern_cell)


def object_key(P: Prims, ns, g):
    """The object of global primitive ids ``g`` (-1 stays -1): the first face of a
    convex solid for each of its faces, else the primitive itself."""
    pi = jnp.clip(g - ns, 0, P.solid.shape[0] - 1)
    solid = (g >= ns) & (P.solid[pi] >= 0)
    return jnp.where(solid, ns + P.solid[pi], g)


def _occluders(scene, kinds, off, P: Prims, p, hit):
    """First and last occluder ``(L, M)`` on the segments from points ``p (3, M)``
    to each light (-1: none, or ``~hit``); a directional light's segment runs to
    beyond every finite primitive."""
    eps = 1e-4 * (1.0 + jnp.max(jnp.abs(p), 0))

    def one(args):
        Lpos, isd = args
        Lp = Lpos[:, None]
        Lv = Lp - p
        ld = V.vsel(jnp.broadcast_to(isd, p.shape[1:]), V.normalize(jnp.broadcast_to(-Lp, p.shape)), V.normalize(Lv))
        dist = jnp.where(isd, P.far + V.norm(p), V.norm(Lv))
        end = V.vsel(jnp.broadcast_to(isd, p.shape[1:]), p + dist[None] * ld, jnp.broadcast_to(Lp, p.shape))
        f, _ = _search(scene, kinds, off, p + eps[None] * ld, ld, dist - 2 * eps)
        la, _ = _search(scene, kinds, off, end, -ld, dist - 2 * eps)
        return jnp.where(hit, f, -1), jnp.where(hit, la, -1)

    return jax.lax.map(one, (P.light.T, P.ldir))


def _hit_cell(scene, kinds, off, gid, o, d, t, mat):
    """The hard pattern colour (0 / 1) at the hits ``gid`` of rays ``o, d`` at distance
    ``t``; all 0 when no material has a checker or stripes."""
    mats = scene.materials
    if tx.CHECKER not in mats.kinds_present and tx.STRIPES not in mats.kinds_present:
        return jnp.zeros(gid.shape, jnp.int32)
    uv = jnp.zeros((2,) + gid.shape, o.dtype)
    for k in kinds:
        start, end, per = kind_ids(off, k)
        sel = (gid >= start) & (gid < end)
        idx = jnp.where(sel, (gid - start) // per, 0)
        _, _, uvk, _ = jax.lax.cond(jnp.any(sel), k.hit, no_hit, idx, o, d, jnp.where(sel, t, 0.0))
        uv = jnp.where(sel[None], uvk, uv)
    return jnp.where(gid >= 0, pattern_cell(mats, mat, uv), 0)


def records(scene, kinds, off, P: Prims, xy, width, height, depth) -> Records:
    """:class:`Records` of the camera rays through image positions ``xy (2, M)``;
    ``scene`` and ``P`` without gradient, ``kinds = prepare(scene)``."""
    o, d = rays_through(scene.camera, xy, width, height)
    M = xy.shape[1]
    ns = off["ns"]
    L = scene.n_lights

    def live(o, d, alive):
        gid, t = _search(scene, kinds, off, o, d)
        gid = jnp.where(alive, gid, -2)
        hit = gid >= 0
        p = o + jnp.where(hit, t, 0.0)[None] * d
        if L:
            # Occluders as objects: a convex solid is its first face, whichever faces
            # the shadow segment crosses.
            first, last = (object_key(P, ns, x) for x in _occluders(scene, kinds, off, P, p, hit))
        else:
            first = last = jnp.zeros((0, M), jnp.int32)
        mat = P.mat[jnp.clip(gid, 0, P.mat.shape[0] - 1)]
        T, R = P.trans[mat], P.refl[mat]
        cont = hit & ((T > 0) | (R > 0))
        o2, d2, refr = _step(P, ns, gid, (T > 0) & (T >= R), o, d)
        cell = _hit_cell(scene, kinds, off, gid, o, d, jnp.where(hit, t, 0.0), mat)
        return (o2, d2, cont), (gid, cont & refr, first, last, cell)

    def dead(o, d, alive):  # no chain continues: skip the searches
        none = jnp.full((L, M), -1, jnp.int32)
        return (o, d, alive), (
            jnp.full((M,), -2, jnp.int32),
            jnp.zeros((M,), bool),
            none,
            none,
            jnp.zeros((M,), jnp.int32),
        )

    def level(carry, _):
        return jax.lax.cond(jnp.any(carry[2]), live, dead, *carry)

    # One compiled level, scanned over the chain (levels after the last mirror or glass
    # hit of every ray cost nothing).
    _, out = jax.lax.scan(level, (o, d, jnp.ones((M,), bool)), None, length=depth)
    return Records(*out)


def _rec_equal(r1: Records, r2: Records):
    """Records ``(.., M)`` equal in every field, ``(M,)``."""
    eq = jnp.all(r1.hit == r2.hit, 0) & jnp.all(r1.refr == r2.refr, 0) & jnp.all(r1.cell == r2.cell, 0)
    if r1.first.shape[1]:
        eq = eq & jnp.all(r1.first == r2.first, (0, 1)) & jnp.all(r1.last == r2.last, (0, 1))
    return eq


def _rec_slice(r: Records, s: slice) -> Records:
    return Records(*(x[..., s] for x in r))


@dataclasses.dataclass(frozen=True)
class EdgeOptions:
    """Static options of the boundary term: ``samples`` per pixel side (``n``),
    ``budget``, the most sample pairs with an edge between them (``None``: a
    quarter of all samples, at least 4096), and ``depth``, the chain levels
    followed (the render's ``max_depth + 1``)."""

    samples: int = 4
    budget: int | None = None
    depth: int = 1


def _pairs(Gw, Gh):
    j = jnp.arange(Gw)
    i = jnp.arange(Gh)
    a_h = (i[:, None] * Gw + j[None, :-1]).ravel()
    a_v = (i[:-1, None] * Gw + j[None, :]).ravel()
    a = jnp.concatenate([a_h, a_v]).astype(jnp.int32)
    b = jnp.concatenate([a_h + 1, a_v + Gw]).astype(jnp.int32)
    horiz = jnp.concatenate([jnp.ones_like(a_h, bool), jnp.zeros_like(a_v, bool)])
    return a, b, horiz


def _at_level(x, level):
    """``x (D, E)`` at each event's ``level (E,)``."""
    return jnp.take_along_axis(x, level[None], 0)[0]


def _pieces(p0, p1, width, height):
    """Split the segments ``p0 -> p1 (2, E)`` at pixel boundaries (at most one per
    axis): pixel ids ``(3, E)`` and length fractions ``(3, E)`` of the three pieces."""

    def cross(c0, c1):
        has = jnp.floor(c0) != jnp.floor(c1)
        tau = V.safe_div(jnp.floor(jnp.maximum(c0, c1)) - c0, c1 - c0)
        return jnp.where(has, jnp.clip(tau, 0.0, 1.0), 1.0)

    cx, cy = cross(p0[0], p1[0]), cross(p0[1], p1[1])
    taus = [jnp.zeros_like(cx), jnp.minimum(cx, cy), jnp.maximum(cx, cy), jnp.ones_like(cx)]
    pix, wts = [], []
    for j in range(3):
        pix.append(_pixel_of(p0 + (0.5 * (taus[j] + taus[j + 1]))[None] * (p1 - p0), width, height))
        wts.append(taus[j + 1] - taus[j])
    return jnp.stack(pix), jnp.stack(wts)


def _pixel_of(x, width, height):
    """Row-major pixel id ``(E,)`` of image positions ``x (2, E)`` (clipped to the image)."""
    px = jnp.clip(jnp.floor(x[0]).astype(jnp.int32), 0, width - 1)
    py = jnp.clip(jnp.floor(x[1]).astype(jnp.int32), 0, height - 1)
    return py * width + px


def edge_term(scene, width, height, eo: EdgeOptions, radiance_at, radiance_grad):
    """The boundary term as an ``(height, width, 3)`` image whose *value* is zero and
    whose derivative with respect to ``scene`` is the edge contribution, and the
    number of sample pairs with an edge between them.

    ``radiance_at(xy (2, M), light=None) -> (M, 3)``: radiance of camera rays
    through image positions ``xy`` (with ``light (M,)``: per ray, that light's
    contribution alone, or everything at index ``L``), treated as a constant. The
    jump ``f_minus - f_plus`` is measured by probe rays just on either side of the
    edge point (``1/256`` of the sample spacing away for visibility edges, 0.03
    pixel for shadow edges), where the probes see the same as the two samples
    (else the crossing adds nothing). ``radiance_grad(xy (2, M)) -> (M, 3)``: the
    same rays shaded as the grid's samples are, differentiable with respect to
    ``scene`` (the silhouette quadrature of step 6).
    """
    n = eo.samples
    D = eo.depth
    Gw, Gh = width * n, height * n
    S = Gw * Gh
    h = 1.0 / n
    sg = jax.lax.stop_gradient(scene)
    kinds = prepare(sg)
    P, off = build_prims(scene)
    P_sg = jax.lax.stop_gradient(P)
    ns = off["ns"]

    def rec_at(x):
        return records(sg, kinds, off, P_sg, x, width, height, D)

    dt = scene.dtype
    jj, ii = jnp.meshgrid(jnp.arange(Gw), jnp.arange(Gh), indexing="xy")
    xy = jnp.stack([(jj.ravel().astype(dt) + 0.5) / n, (ii.ravel().astype(dt) + 0.5) / n])
    R = rec_at(xy)
    L = R.first.shape[1]
    a, b, horiz = _pairs(Gw, Gh)

    def okey(g):
        return object_key(P_sg, ns, g)

    ha, hb = R.hit[:, a], R.hit[:, b]
    same_r = R.refr[:, a] == R.refr[:, b]
    # Visibility: the first chain level whose hits differ, after a common prefix.
    pre = jnp.ones(a.shape, bool)
    vis_act = jnp.zeros(a.shape, bool)
    lv = jnp.zeros(a.shape, jnp.int32)
    for lvl in range(D):
        dh = ha[lvl] != hb[lvl]
        new = pre & dh
        vis_act = vis_act | new
        lv = jnp.where(new, lvl, lv)
        pre = pre & ~dh & same_r[lvl]
    act = [vis_act]
    # Shadows: per light, the first level (same hit, common prefix) whose shadow
    # records differ; slots for light k, candidate occluder j (last / first occluder
    # of either sample's shadow segment), each distinct occluding object once.
    ls = []
    for k in range(L):
        pre = jnp.ones(a.shape, bool)
        found = jnp.zeros(a.shape, bool)
        lk = jnp.zeros(a.shape, jnp.int32)
        for lvl in range(D):
            eqh = ha[lvl] == hb[lvl]
            dif = (
                pre
                & eqh
                & (ha[lvl] >= 0)
                & ~found
                & ((R.first[lvl, k, a] != R.first[lvl, k, b]) | (R.last[lvl, k, a] != R.last[lvl, k, b]))
            )
            lk = jnp.where(dif, lvl, lk)
            found = found | dif
            pre = pre & eqh & same_r[lvl]
        ls.append(lk)
        recv = okey(_at_level(ha, lk))
        cands = [
            _at_level(R.last[:, k, a], lk),
            _at_level(R.first[:, k, a], lk),
            _at_level(R.last[:, k, b], lk),
            _at_level(R.first[:, k, b], lk),
        ]
        keys = [okey(c) for c in cands]
        for j in range(4):
            new = found & (cands[j] >= 0) & (keys[j] != recv)
            for i in range(j):
                new = new & (keys[j] != keys[i])
            act.append(new)
    nslot = 1 + 4 * L
    act = jnp.stack(act, 1).ravel()  # (npairs * nslot,) pair-major
    budget = eo.budget if eo.budget is not None else max(4096, S // 4)
    budget = min(budget, act.shape[0])
    C = min(CHUNK, budget)
    nc = -(-budget // C)
    K = nc * C
    count = jnp.sum(act)
    (flat,) = jnp.nonzero(act, size=K, fill_value=0)
    flat = flat.astype(jnp.int32)
    live = jnp.arange(K) < count
    pair = flat // nslot
    slot = flat % nslot
    ea, eb = a[pair], b[pair]
    vis = slot == 0
    k_ev = jnp.maximum(slot - 1, 0) // 4
    j_ev = jnp.maximum(slot - 1, 0) % 4
    if L:
        level = jnp.where(vis, lv[pair], jnp.stack(ls)[k_ev, pair])
    else:
        level = lv[pair]
    chain, refr = R.hit[:, ea], R.refr[:, ea]
    A = _at_level(chain, level)
    B = R.hit[level, eb]
    if L:
        fa, la = R.first[level, k_ev, ea], R.last[level, k_ev, ea]
        fb, lb = R.first[level, k_ev, eb], R.last[level, k_ev, eb]
        occ = jnp.where(j_ev == 0, la, jnp.where(j_ev == 1, fa, jnp.where(j_ev == 2, lb, fb)))
    else:
        fa = la = fb = lb = occ = jnp.zeros_like(A)
    inputs = {
        "live": live,
        "vis": vis,
        "level": level,
        "chain": chain,
        "refr": refr,
        "A": A,
        "B": B,
        "occ": occ,
        "k": k_ev,
        "fa": fa,
        "la": la,
        "fb": fb,
        "lb": lb,
        "xa": xy[:, ea],
        "xb": xy[:, eb],
        "eh": horiz[pair],
    }

    def solve(c):
        """Everything about one chunk of ``C`` events that needs no gradient."""
        zeros = jnp.zeros_like(c["A"])
        A, B, xa, xb, eh, vis = c["A"], c["B"], c["xa"], c["xb"], c["eh"], c["vis"]

        def mk(typ, p1, p2, sign):
            return Events(typ, c["level"], c["chain"], c["refr"], p1, p2, c["k"], sign)

        def cat(*evs):
            return Events(*(jnp.concatenate(f, -1) for f in zip(*evs)))

        def G(ev, x, feature=False):
            return edge_value(sg, P_sg, ns, ev, x, width, height, feature)

        # One batched evaluation (one compiled copy of G) classifies every event:
        # visibility (which edge function separates the two samples?) and shadows
        # (is the occluder hit by one shadow segment and missed by the other?).
        ev_d = mk(zeros + DEPTH, A, B, zeros)
        ev_s = mk(zeros + SHADOW, A, c["occ"], zeros)
        evs = [mk(zeros + MISS, A, B, zeros), mk(zeros + MISS, B, A, zeros), ev_d, ev_d, ev_s, ev_s]
        vals = G(cat(*evs), jnp.concatenate([xb, xa, xa, xb, xa, xb], 1)).reshape(len(evs), -1)  # pyright: ignore
        mAb, mBa = vals[0], vals[1]
        case1 = (A >= 0) & (mAb > 0)
        case2 = ~case1 & (B >= 0) & (mBa > 0)
        # Depth crossings: t_A - t_B changes sign between the samples (two surfaces
        # crossing, or a crease of a convex solid).
        up = (vals[2] <= 0) & (vals[3] >= 0)
        down = (vals[2] >= 0) & (vals[3] <= 0)
        case3 = ~case1 & ~case2 & (A >= 0) & (B >= 0) & (up | down)
        typ_v = jnp.where(case1 | case2, MISS, DEPTH)
        ok_v = case1 | case2 | case3
        ma, mb = vals[4], vals[5]
        ok_s = (c["occ"] >= 0) & ((ma <= 0) != (mb <= 0))
        ev = mk(
            jnp.where(vis, typ_v, SHADOW),
            jnp.where(vis, jnp.where(case2, B, A), A),
            jnp.where(vis, B, c["occ"]),
            jnp.where(vis, jnp.where(case2 | (case3 & ~up), -1, 1), jnp.where(ma <= 0, 1, -1)),
        )
        sgn = ev.sign.astype(dt)
        ok = c["live"] & jnp.where(vis, ok_v, ok_s)
        ev2 = cat(ev, ev)
        sgn2 = jnp.concatenate([sgn, sgn])

        def g2(x):
            return sgn2 * G(ev2, x)

        # Bisection on the doubled batch (both copies of each bracket; the second is
        # differentiated along y below, and below the two copies follow the edge to
        # either side).
        xa2, xb2 = jnp.concatenate([xa, xa], 1), jnp.concatenate([xb, xb], 1)

        def bisect(_, lohi):
            lo, hi = lohi
            mid = 0.5 * (lo + hi)
            neg = g2(xa2 + mid[None] * (xb2 - xa2)) <= 0  # pyright: ignore
            return jnp.where(neg, mid, lo), jnp.where(neg, hi, mid)

        lo, hi = jax.lax.fori_loop(0, BISECTION_STEPS, bisect, (jnp.zeros_like(sgn2), jnp.ones_like(sgn2)))
        xs2 = xa2 + (0.5 * (lo + hi))[None] * (xb2 - xa2)
        tang = jnp.concatenate([jnp.zeros_like(xa).at[0].set(1.0), jnp.zeros_like(xa).at[1].set(1.0)], 1)
        _, gxy = jax.jvp(g2, (xs2,), (tang,))
        E = A.shape[0]
        gx, gy = gxy[:E], gxy[E:]
        xs = xs2[:, :E]
        den = jnp.abs(gx) + jnp.abs(gy)
        ok = ok & (den > 0) & jnp.isfinite(den)
        ga = jnp.where(eh, gx, gy)  # along the pair
        gc = jnp.where(eh, gy, gx)  # across
        # The jump, measured on either side of the edge point. Probes sit 1/256 of the
        # sample spacing from a visibility edge (camera rays are exact there). The
        # renderer offsets shadow rays from the surface (by 1e-4 of the scene's scale),
        # which moves its shadow edges by ~1e-3 pixel; shadow probes keep 0.03 pixel
        # (at most 0.45 of the spacing) from the edge, on both sides of that edge.
        frac = jnp.where(vis, 1.0 / 256.0, jnp.maximum(1.0 / 256.0, jnp.minimum(0.45, 0.03 * n)))
        u = (xb - xa) * frac[None]
        probes = jnp.concatenate([xs - u, xs + u], 1)
        # A sphere's silhouette: the radiance beside it is f_s + a sqrt(distance); the
        # inside probe is extrapolated to the edge with ``a``, fitted from it and two
        # more rays 1/16 and 1/4 of the spacing inside (phi h: the first inside
        # sample's distance from the edge; step 6 of the module docstring).
        sil = vis & (ev.typ == MISS) & (ev.p1 < ns)
        in_b = case2  # the sphere is on the second sample's side
        t_s = 0.5 * (lo[:E] + hi[:E])
        phi = jnp.clip(jnp.where(in_b, 1.0 - t_s, t_s), 1e-6, 1.0)
        step_in = jnp.where(in_b[None], xb - xa, xa - xb)
        inner = jnp.concatenate([xs + step_in / 16.0, xs + step_in / 4.0], 1)

        # The piece of edge this crossing stands for: up to the neighbouring rows
        # (columns) on either side, cut where the edge ends or what lies on either
        # side of it changes (records at the edge, beside it, differ from the probes').
        # One loop: step 0 takes the records beside the edge point itself (the
        # probes') and its feature, step 1 looks a whole row (column) away on either
        # side, the remaining steps bisect for the end where that failed.
        along = jnp.stack([eh, ~eh]).astype(dt)
        across = 1.0 - along
        tdir = across - V.safe_div(gc, ga)[None] * along  # the edge's direction per unit across

        def dup(x):
            return jnp.concatenate([x, x], -1)

        along2, tdir2, xs2b, u2, ga2 = (dup(x) for x in (along, tdir, xs, u, ga))
        sided = jnp.concatenate([-jnp.ones_like(sgn), jnp.ones_like(sgn)]) * h

        def on_edge(x):
            """Follow the edge from ``x`` along the pair direction (chord-Newton steps
            in one loop); returns the last point evaluated, whether ``g`` vanishes
            there, and its feature."""

            def newton(_, st):
                x, _, _, _ = st
                gv, f = G(ev2, x, feature=True)
                gv = sgn2 * gv
                return x - V.safe_div(gv, ga2)[None] * along2, x, jnp.abs(gv) <= 0.05 * h * jnp.abs(ga2), f

            _, x1, conv, f = jax.lax.fori_loop(
                0, NEWTON_STEPS + 1, newton, (x, x, jnp.zeros(sgn2.shape, bool), jnp.zeros(sgn2.shape, jnp.int32))
            )
            return x1, conv, f

        def seen(x, r):
            """Does the pair of grid samples around ``x`` (a point of the edge on a
            sample row or column) see the same on either side as the probes there
            (records ``r``)? If not (it straddles another edge too), that row has no
            crossing of this edge, and the rows beside it cover its piece."""
            t = x * n - 0.5  # grid coordinates
            ca = jnp.floor(jnp.where(along2 > 0, t, jnp.round(t))).astype(jnp.int32)
            inside = (
                (ca[0] >= 0)
                & (ca[1] >= 0)
                & (ca[0] + along2[0].astype(jnp.int32) < Gw)
                & (ca[1] + along2[1].astype(jnp.int32) < Gh)
            )
            ia = jnp.clip(ca[1], 0, Gh - 1) * Gw + jnp.clip(ca[0], 0, Gw - 1)
            ib = jnp.clip(ia + jnp.where(along2[0] > 0, 1, Gw), 0, S - 1)
            at = jax.tree_util.tree_map(lambda v: v[..., jnp.concatenate([ia, ib])], R)
            # Compared on what makes this event: the chain prefix, the hit at its
            # level and, for a shadow edge, its light's occluders there.
            lv4 = jnp.tile(c["level"], 4)
            same = jnp.ones(lv4.shape, bool)
            for q in range(D):
                same = same & ((q > lv4) | (at.hit[q] == r.hit[q])) & ((q >= lv4) | (at.refr[q] == r.refr[q]))
            if L:
                k4, ar = jnp.tile(c["k"], 4), jnp.arange(4 * E)
                same = same & (
                    jnp.tile(vis, 4)
                    | ((at.first[lv4, k4, ar] == r.first[lv4, k4, ar]) & (at.last[lv4, k4, ar] == r.last[lv4, k4, ar]))
                )
            return ~inside | (same[: 2 * E] & same[2 * E :])

        def end_step(i, st):
            lo, hi, full, lost, ref, feat = st
            mid = jnp.where(i == 0, 0.0, jnp.where(i == 1, hi, 0.5 * (lo + hi)))
            x, conv, f = on_edge(xs2b + mid[None] * tdir2)
            r = rec_at(jnp.concatenate([x - u2, x + u2], 1))  # minus side, plus side (each 2E)
            ref = jax.tree_util.tree_map(lambda new, old: jnp.where(i == 0, new, old), r, ref)
            feat = jnp.where(i == 0, f, feat)
            v = (
                conv
                & (f == feat)
                & _rec_equal(_rec_slice(r, slice(0, 2 * E)), _rec_slice(ref, slice(0, 2 * E)))
                & _rec_equal(_rec_slice(r, slice(2 * E, 4 * E)), _rec_slice(ref, slice(2 * E, 4 * E)))
            )
            nb = seen(x, r)
            full = jnp.where(i == 1, v & nb, full)
            lost = jnp.where(i == 1, v & ~nb, lost)
            lo = jnp.where((i > 1) & v, mid, lo)
            hi = jnp.where((i > 1) & ~v, mid, hi)
            return lo, hi, full, lost, ref, feat

        ref0 = Records(
            jnp.zeros((D, 4 * E), jnp.int32),
            jnp.zeros((D, 4 * E), bool),
            jnp.zeros((D, L, 4 * E), jnp.int32),
            jnp.zeros((D, L, 4 * E), jnp.int32),
            jnp.zeros((D, 4 * E), jnp.int32),
        )
        no = jnp.zeros(sided.shape, bool)
        lo, hi, full, lost, ref, _ = jax.lax.fori_loop(
            0, END_STEPS + 2, end_step, (jnp.zeros_like(sided), sided, no, no, ref0, jnp.zeros(sided.shape, jnp.int32))
        )
        r_m, r_p = _rec_slice(ref, slice(0, E)), _rec_slice(ref, slice(2 * E, 3 * E))
        lvl = c["level"]
        pre_m = pre_p = jnp.ones_like(ok)
        for q in range(D):
            before = q < lvl
            pre_m = pre_m & (~before | ((r_m.hit[q] == c["chain"][q]) & (r_m.refr[q] == c["refr"][q])))
            pre_p = pre_p & (~before | ((r_p.hit[q] == c["chain"][q]) & (r_p.refr[q] == c["refr"][q])))
        hm, hp = _at_level(r_m.hit, lvl), _at_level(r_p.hit, lvl)
        jump_ok = pre_m & pre_p & (hm == A) & jnp.where(vis, hp == B, hp == A)
        if L:
            ar = jnp.arange(E)
            sh = (
                (r_m.first[lvl, c["k"], ar] == c["fa"])
                & (r_m.last[lvl, c["k"], ar] == c["la"])
                & (r_p.first[lvl, c["k"], ar] == c["fb"])
                & (r_p.last[lvl, c["k"], ar] == c["lb"])
            )
            jump_ok = jump_ok & (vis | sh)
        # A shadow edge's jump is that of its light's contribution alone; one compiled
        # trace, mapped over the lights and then everything (index L).
        # One trace of each ray: the probes with their light (index L: everything), and
        # without spheres no inner rays.
        which = jnp.where(vis, L, c["k"])
        pts = jnp.concatenate([probes, inner], 1) if ns else probes
        sel = jnp.concatenate([which, which] + ([jnp.full((2 * E,), L, jnp.int32)] if ns else []))
        fl = radiance_at(pts, sel)
        fr = fl[: 2 * E]
        # f = f_s + A sqrt(q) + B q at the inside distances q = 1/256 (the probe), 1/16
        # and 1/4 of the spacing: A by elimination of f_s and B.
        q0, q1, q2 = 1.0 / 256.0, 1.0 / 16.0, 1.0 / 4.0
        f0 = jnp.where(in_b[:, None], fr[E:], fr[:E])
        f1, f2 = (fl[2 * E : 3 * E], fl[3 * E :]) if ns else (f0, f0)
        A = ((f1 - f0) * (q2 - q0) - (f2 - f0) * (q1 - q0)) / (
            (math.sqrt(q1) - math.sqrt(q0)) * (q2 - q0) - (math.sqrt(q2) - math.sqrt(q0)) * (q1 - q0)
        )
        A = jnp.where(sil[:, None] & jnp.isfinite(A), A, 0.0)
        fin = f0 - A * math.sqrt(q0)  # the inside probe extrapolated to the edge
        fm = jnp.where(in_b[:, None], fr[:E], fin)
        fp = jnp.where(in_b[:, None], fin, fr[E:])
        df = jnp.where(jump_ok[:, None], fm - fp, 0.0)

        ext = jnp.where(full, 0.5 * h, jnp.where(lost, h, jnp.abs(0.5 * (lo + hi))))
        e_m, e_p = ext[:E], ext[E:]
        pix, wts = _pieces(xs - e_m[None] * tdir, xs + e_p[None] * tdir, width, height)
        # Rows and columns share each edge by the weight |g_a|^4 / (g_x^4 + g_y^4): each
        # direction takes the edges it crosses steeply, where one crossing stands for a
        # piece of edge at most ~1.2 sample spacings long (a crossing of a shallow edge
        # stands for a long piece, along which the jump may change).
        m = jnp.maximum(jnp.abs(gx), jnp.abs(gy))
        a4, c4 = V.safe_div(ga, m) ** 4, V.safe_div(gc, m) ** 4
        wgt = V.safe_div(V.safe_div(a4, a4 + c4), jnp.abs(ga))  # weight / |g_a|
        coef = -df * (jnp.sign(ga) * wgt * (e_m + e_p))[:, None]
        coef = jnp.where(ok[:, None] & jnp.isfinite(coef), coef, 0.0)
        out = {
            "typ": ev.typ,
            "p1": ev.p1,
            "p2": ev.p2,
            "sign": ev.sign,
            "xs": xs,
            "coef": coef.T,
            "pix": pix,
            "wts": wts,
            "ok": ok,
        }
        if ns:
            # A sphere's silhouette: the first QUAD_SAMPLES inside samples of the row (at
            # t = k + phi spacings from the edge) are replaced by the integral of the
            # samples' derivative over [0, QUAD_SAMPLES - 1/2 + phi], by Gauss-Legendre
            # in u = sqrt(t): the 1/sqrt(t) singularity becomes smooth in u, and what
            # grows like sqrt(t - t_k) after a terminator's kink piecewise smooth. The
            # rows' weights and piece lengths are the edge term's; it goes to the inside
            # sample's pixel (a shift of at most QUAD_SAMPLES samples).
            T = QUAD_SAMPLES - 0.5 + phi
            xi, wi = (jnp.asarray(v, dt) for v in np.polynomial.legendre.leggauss(QUAD_NODES))
            xi, wi = 0.5 * (xi + 1.0), 0.5 * wi
            tq = T[None] * xi[:, None] ** 2  # (Q, E)
            wq = 2.0 * T[None] * (xi * wi)[:, None]
            tk = jnp.arange(QUAD_SAMPLES, dtype=dt)[:, None] + phi[None]
            ww = jnp.concatenate([wq, -jnp.ones_like(tk)])
            x0 = jnp.where(in_b[None], xb, xa)  # the first inside sample, exactly on the grid
            qx = jnp.concatenate(
                [
                    xs[:, None, :] + tq[None] * step_in[:, None, :],
                    x0[:, None, :] + (tk - phi[None])[None] * step_in[:, None, :],
                ],
                1,
            )  # (2, Q+K, E)
            scale = (V.safe_div(a4, a4 + c4) * (e_m + e_p) * h)[None]
            qw = jnp.where((ok & sil & jump_ok)[None] & jnp.isfinite(scale), ww * scale, 0.0)
            out["qx"], out["qw"], out["pin"] = qx, qw, _pixel_of(x0, width, height)
        return out

    def chunked(x):  # (..., K) -> (nc, ..., C)
        return jnp.moveaxis(x.reshape(x.shape[:-1] + (nc, C)), -2, 0)

    def solve_or_skip(c):
        shapes = jax.eval_shape(solve, c)
        return jax.lax.cond(
            jnp.any(c["live"]),
            solve,
            lambda _: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes),
            c,
        )

    res = jax.lax.map(solve_or_skip, {k: chunked(jax.lax.stop_gradient(v)) for k, v in inputs.items()})
    res = {k: jnp.moveaxis(v, 0, -2).reshape(v.shape[1:-1] + (K,)) for k, v in res.items()}
    ev = Events(res["typ"], level, chain, refr, res["p1"], res["p2"], k_ev, res["sign"])
    # The differentiable part: g at the (fixed) edge point, with the live scene.
    g = res["sign"].astype(dt) * edge_value(scene, P, ns, ev, res["xs"], width, height)
    g = jnp.where(res["ok"], g, 0.0)  # pyright: ignore
    term = res["coef"].T * g[:, None]  # (K, 3)
    img = jnp.zeros((height * width, 3), term.dtype)
    for j in range(3):
        img = img.at[res["pix"][j]].add(term * res["wts"][j][:, None])
    if "qx" in res:
        # The differentiable rays of the silhouette quadrature, live crossings first, in
        # chunks of C crossings; a chunk without one is skipped.
        live_q = jnp.any(res["qw"] != 0, 0)
        order = jnp.argsort(~live_q, stable=True)
        Q = res["qw"].shape[0]
        qx = jnp.moveaxis(res["qx"][:, :, order].reshape(2, Q, nc, C), 2, 0)  # (nc, 2, Q, C)
        qw = jnp.moveaxis(res["qw"][:, order].reshape(Q, nc, C), 1, 0)  # (nc, Q, C)

        def quad(args):
            x, w = args

            def run(_):
                f = radiance_grad(x.reshape(2, -1)).reshape(Q, C, 3)
                return jnp.sum(w[..., None] * f, 0)

            # Rematerialised in the backward pass: the residuals of every chunk's rays
            # would otherwise be kept (+50 % of the edge mode's memory).
            return jax.lax.cond(jnp.any(w != 0), jax.checkpoint(run), lambda _: jnp.zeros((C, 3), dt), None)

        img = img.at[res["pin"][order]].add(jax.lax.map(quad, (qx, qw)).reshape(K, 3))
    img = eqx.error_if(
        img,
        count > budget,
        f"edge_gradients: more sample pairs straddle an edge than "
        f"edge_budget={budget}; pass a larger edge_budget to render",
    )
    img = img - jax.lax.stop_gradient(img)
    return img.reshape(height, width, 3), count
