"""Boundary terms of the image derivative: silhouettes and hard shadows.

A pixel is the integral of the radiance ``f(x, theta)`` over its area. Where
``f`` jumps along a curve that moves with ``theta`` (an object's silhouette, the
line where two surfaces cross, a crease between two faces, the edge of a hard
shadow), the derivative of that integral has a *boundary* term besides the
integral of ``df/dtheta`` that automatic differentiation of the samples gives:

    dI/dtheta = int_P df/dtheta dA  +  int_(edges in P) (f_minus - f_plus) v_n dl

with ``v_n`` the speed of the edge along its normal (pointing to the ``plus``
side). This module estimates the second term; :func:`raytrax.render` adds it
when called with ``edge_gradients=True``.

Method (analytic edge functions found between neighbouring samples; see
``docs/gradients.md`` for why this and not edge sampling or reparameterisation):

1. A stop-gradient pass traces a regular ``n x n`` grid of samples per pixel and
   records, per sample, which primitive the camera ray hits first (a box face or
   a triangle counts as its own primitive) and, for every light, the first and
   last occluder on the shadow segment from the hit point to the light.
2. Two neighbouring samples (horizontal or vertical) whose records differ
   bracket an edge. For each such pair an *edge function* ``g(x, theta)`` of the
   image position ``x`` is chosen, negative on the first sample's side and zero
   on the edge, and smooth in both arguments:

   * the first sample's primitive is missed by the second ray: ``g`` is that
     primitive's miss function (a sphere's ``|oc x d|^2 - r^2``, a polygon's
     signed distance from the ray's plane hit to its boundary), and the same
     the other way round;
   * both rays hit both primitives: ``g = t_A - t_B``, the depth difference,
     whose zero set is where the two surfaces cross;
   * same primitive, different shadow record for light ``k``: ``g`` is the
     occluder's miss function on the line from the hit point ``p(x)`` to the
     light, so it moves with the light, the occluder and the receiver.

3. The edge point ``x_s`` is found by bisection between the two samples, and
   the implicit function theorem gives the edge's displacement
   ``dx_s/dtheta = -g_theta / g_x``. Rows of samples estimate the boundary
   integral by Fubini (``int dy sum_crossings (f_a - f_b) dx_s/dtheta``), columns
   likewise; weighting the two by ``|g_x|`` and ``|g_y|`` over ``|g_x| + |g_y|``
   keeps every term bounded however the edge is oriented. Each crossing adds

       c * g(x_s, theta),   c = -(f_a - f_b) (1/n) sign(g_dir) / (|g_x| + |g_y|)

   to the pixel that contains ``x_s``, with ``c`` and ``x_s`` held constant:
   its value is ``0`` (``g(x_s) = 0``) and its derivative is the boundary term.
   ``f_a - f_b`` is the jump of the whole sample radiance for visibility edges
   and of that light's direct term for shadow edges.

The estimate converges to the derivative of the pixel integral as ``n`` grows
(the error is ``O(1/n)`` from the jump measured at the samples rather than at
the edge, and from pairs that straddle two edges). What it does not include:
edges seen *through* mirrors and glass (reflected or refracted silhouettes and
shadows), edges of procedural textures (use ``filter_textures=True``, which
makes them continuous), the horizon of an infinite plane, and the terminator
of a surface lit at grazing angles (there the jump is zero anyway).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _vec as V
from .camera import rays_through
from .intersect import _closest_kind, prepare
from .shapes import euler_matrix

BISECTION_STEPS = 14
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
    solid: jax.Array  # (Np,) polygon index of the first face of its convex solid, -1: none
    nface: jax.Array  # (Np,) faces of that solid (6 box, 4 tetrahedron, 0 none)
    light: jax.Array  # (3, L)


def _unit(x):
    n2 = jnp.sum(x * x, -1, keepdims=True)
    ok = n2 > 1e-30
    return jnp.where(ok, x / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0)


def _polys_from_edges(origins, dirs, normal):
    """``origins, dirs (N, 4, 3)``, ``normal (N, 3)`` -> (pp, pn, eo, em)."""
    n = _unit(normal)
    m = _unit(jnp.cross(n[:, None, :], dirs))
    return origins[:, 0], n, origins, m


def _quad_polys(corners):
    c = corners
    e = jnp.roll(c, -1, axis=1) - c
    n = jnp.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1])
    return _polys_from_edges(c, e, n)


def _face_signs():
    """``(6, 4, 3)`` corner signs of the unit box's faces, face ``2 axis + (side > 0)``."""
    out = []
    for a in range(3):
        u, v = (a + 1) % 3, (a + 2) % 3
        for s in (-1.0, 1.0):
            face = []
            order = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
            for su, sv in (order if s > 0 else order[::-1]):  # counter-clockwise seen from outside
                c = [0.0, 0.0, 0.0]
                c[a], c[u], c[v] = s, su, sv
                face.append(c)
            out.append(face)
    return out


def _box_faces(boxes):
    """Box faces as quads ``(6 N, 4, 3)``, face ``2 axis + (side > 0)`` of each box."""
    R = euler_matrix(boxes.rotation)  # (N, 3, 3)
    c = 0.5 * (boxes.lo + boxes.hi)
    h = 0.5 * jnp.abs(boxes.hi - boxes.lo)
    loc = jnp.asarray(_face_signs(), c.dtype)[None] * h[:, None, None, :]  # (N, 6, 4, 3)
    world = c[:, None, None, :] + jnp.einsum("nij,nfkj->nfki", R, loc)
    return world.reshape(-1, 4, 3)


def build_prims(scene) -> tuple[Prims, dict]:
    """The :class:`Prims` of ``scene`` (differentiable) and the id offsets per kind."""
    dt = scene.dtype
    parts = []  # (pp, pn, eo, em, finite)
    off = {}
    ns = scene.spheres.center.shape[0]
    count = ns
    pl = scene.planes
    off["plane"] = count
    if pl.point.shape[0]:
        N = pl.point.shape[0]
        z = jnp.zeros((N, 4, 3), dt)
        parts.append((pl.point, _unit(pl.normal), z, z, jnp.zeros((N,), bool)))
        count += N
    off["quad"] = count
    if scene.quads.corners.shape[0]:
        q = _quad_polys(scene.quads.corners)
        parts.append(q + (jnp.ones((q[0].shape[0],), bool),))
        count += q[0].shape[0]
    off["triangle"] = count
    solids = []  # (first polygon index, faces per solid, number of solids)
    if scene.tetrahedra.center.shape[0]:
        solids.append((count - off["plane"] + scene.triangles.vertices.shape[0], 4, scene.tetrahedra.center.shape[0]))
    T = scene.merged_triangles()[0]
    if T.shape[0]:
        v0, v1, v2 = T[:, 0], T[:, 1], T[:, 2]
        origins = jnp.stack([v0, v1, v2, v2], 1)
        dirs = jnp.stack([v1 - v0, v2 - v1, v0 - v2, v0 - v2], 1)
        q = _polys_from_edges(origins, dirs, jnp.cross(v1 - v0, v2 - v0))
        parts.append(q + (jnp.ones((T.shape[0],), bool),))
        count += T.shape[0]
    off["box"] = count
    if scene.boxes.lo.shape[0]:
        solids.append((count - off["plane"], 6, scene.boxes.lo.shape[0]))
        q = _quad_polys(_box_faces(scene.boxes))
        parts.append(q + (jnp.ones((q[0].shape[0],), bool),))
        count += q[0].shape[0]
    off["total"] = count
    if parts:
        pp, pn, eo, em, fin = (jnp.concatenate(x, 0) for x in zip(*parts))
    else:  # one dummy polygon keeps the gathers well defined
        pp = pn = jnp.zeros((1, 3), dt)
        eo = em = jnp.zeros((1, 4, 3), dt)
        fin = jnp.zeros((1,), bool)
    npoly = fin.shape[0]
    solid = np.full((npoly,), -1, np.int32)
    nface = np.zeros((npoly,), np.int32)
    for start, k, m in solids:
        idx = start + np.arange(k * m)
        solid[idx] = start + (np.arange(k * m) // k) * k
        nface[idx] = k
    if ns:
        c, r = scene.spheres.center.T, scene.spheres.radius
    else:
        c, r = jnp.zeros((3, 1), dt), jnp.zeros((1,), dt)
    L = scene.lights.position.T if scene.lights.position.shape[0] else jnp.zeros((3, 1), dt)
    prims = Prims(c, r, pp.T, pn.T, jnp.transpose(eo, (1, 2, 0)), jnp.transpose(em, (1, 2, 0)), fin,
                  jnp.asarray(solid), jnp.asarray(nface), L)
    return prims, dict(off, ns=ns, solid=solid)


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
    line misses it, ``< 0`` when it hits, zero on its silhouette."""
    is_s, si, pi = _split(P, ns, ids)
    oc = P.c[:, si] - o
    x = V.cross(oc, d)
    gs = V.dot(x, x) - P.r[si] ** 2 * V.dot(d, d)
    n = P.pn[:, pi]
    t = V.safe_div(V.dot(P.pp[:, pi] - o, n), V.dot(d, n))
    p = o + t[None] * d
    s = [V.dot(p - P.eo[i][:, pi], P.em[i][:, pi]) for i in range(4)]
    gp = -jnp.minimum(jnp.minimum(s[0], s[1]), jnp.minimum(s[2], s[3]))
    gp = jnp.where(P.finite[pi], gp, -1.0)
    if P.solid.shape[0] and MAX_FACES:
        # A face of a convex solid (box, tetrahedron): the solid's own miss function,
        # t_near - t_far over its face planes, so that a crease between two of its
        # faces is never mistaken for its silhouette.
        first = jnp.maximum(P.solid[pi], 0)
        big = jnp.asarray(1e30, o.dtype)
        tn, tf = -big, big
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
            tn = jnp.where(use, jnp.maximum(tn, enter), tn)
            tf = jnp.where(use, jnp.minimum(tf, leave), tf)
        gp = jnp.where(P.solid[pi] >= 0, tn - tf, gp)
    return jnp.where(is_s, gs, gp)


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


MISS, DEPTH, SHADOW = 0, 1, 2


class Events(NamedTuple):
    typ: jax.Array  # (E,) MISS, DEPTH or SHADOW
    p1: jax.Array  # (E,) primitive missed (MISS), A (DEPTH), receiver (SHADOW)
    p2: jax.Array  # (E,) B (DEPTH), occluder (SHADOW)
    light: jax.Array  # (E,) light index (SHADOW)
    sign: jax.Array  # (E,) +-1: g = sign * G is <= 0 on the first sample's side


def edge_value(scene, P: Prims, ns, ev: Events, xy, width, height):
    """``G(x)`` of each event at image positions ``xy (2, E)`` (before ``sign``)."""
    o, d = rays_through(scene.camera, xy, width, height)
    ta = first_t(P, ns, ev.p1, o, d)
    tb = first_t(P, ns, ev.p2, o, d)
    shadow = ev.typ == SHADOW
    p = o + ta[None] * d
    L = P.light[:, jnp.clip(ev.light, 0, P.light.shape[1] - 1)]
    o2 = V.vsel(shadow, p, o)
    d2 = V.vsel(shadow, V.normalize(L - p), d)
    m = miss(P, ns, jnp.where(ev.typ == MISS, ev.p1, ev.p2), o2, d2)
    return jnp.where(ev.typ == DEPTH, ta - tb, m)


# ----------------------------------------------------------------------------
# The stop-gradient sample records.
# ----------------------------------------------------------------------------


def _box_face_index(scene, idx, o, d, t):
    """Face ``2 axis + (side > 0)`` of box ``idx`` where ray ``o + t d`` meets it."""
    bx = scene.boxes
    R = euler_matrix(bx.rotation)[idx]  # (n, 3, 3)
    c = (0.5 * (bx.lo + bx.hi))[idx].T
    h = (0.5 * jnp.abs(bx.hi - bx.lo))[idx].T
    p = o + t[None] * d
    loc = jnp.einsum("nji,jn->in", R, p - c)  # R^T (p - c)
    rel = jnp.abs(loc) / jnp.maximum(h, 1e-30)
    ax = jnp.argmax(rel, 0)
    side = jnp.take_along_axis(loc, ax[None], 0)[0] > 0
    return 2 * ax.astype(jnp.int32) + side.astype(jnp.int32)


def _search(scene, kinds, off, o, d, tmax=None):
    """Global id (-1: none) and distance of the first primitive along rays ``o, d``
    (closer than ``tmax`` when given)."""
    n = o.shape[1]
    ray = (o[0], o[1], o[2], d[0], d[1], d[2])
    best_t = jnp.full((n,), jnp.inf, o.dtype)
    best_id = jnp.full((n,), -1, jnp.int32)
    for k in kinds:
        t, idx = _closest_kind(k, ray, 0.0)
        if k.name == "sphere":
            gid = idx
        elif k.name == "box":
            gid = off["box"] + 6 * idx + _box_face_index(scene, idx, o, d, jnp.where(jnp.isfinite(t), t, 0.0))
        else:
            gid = off[k.name] + idx
        better = t < best_t
        best_t = jnp.where(better, t, best_t)
        best_id = jnp.where(better, gid, best_id)
    if tmax is not None:
        best_id = jnp.where(best_t < tmax, best_id, -1)
    return best_id, best_t


def id_offsets(scene) -> dict:
    """First global id of each kind (see :class:`Prims`), ``ns`` and ``total``."""
    ns = scene.spheres.center.shape[0]
    off = {"ns": ns, "plane": ns}
    off["quad"] = off["plane"] + scene.planes.point.shape[0]
    off["triangle"] = off["quad"] + scene.quads.corners.shape[0]
    nt = scene.triangles.vertices.shape[0] + 4 * scene.tetrahedra.center.shape[0]
    nt += sum(m.faces.shape[0] for m in scene.meshes)
    off["box"] = off["triangle"] + nt
    off["total"] = off["box"] + 6 * scene.boxes.lo.shape[0]
    return off


def primary_ids(scene, xy, width, height):
    """Global id (-1: background) of the first primitive seen through image
    positions ``xy (2, M)`` (no gradient)."""
    scene = jax.lax.stop_gradient(scene)
    o, d = rays_through(scene.camera, xy, width, height)
    return _search(scene, prepare(scene), id_offsets(scene), o, d)[0]


def sample_records(scene, width, height, n):
    """Records of the ``(height n) x (width n)`` sample grid (no gradient):
    primary primitive ``(S,)`` and, per light, first and last occluder ``(L, S)``,
    plus the sample positions ``(2, S)`` in pixels."""
    scene = jax.lax.stop_gradient(scene)
    kinds = prepare(scene)
    off = id_offsets(scene)
    Gw, Gh = width * n, height * n
    dt = scene.dtype
    jj, ii = jnp.meshgrid(jnp.arange(Gw), jnp.arange(Gh), indexing="xy")
    xy = jnp.stack([(jj.ravel().astype(dt) + 0.5) / n, (ii.ravel().astype(dt) + 0.5) / n])
    o, d = rays_through(scene.camera, xy, width, height)
    prim, t = _search(scene, kinds, off, o, d)
    hit = prim >= 0
    p = o + jnp.where(hit, t, 0.0)[None] * d
    L = scene.lights.position.shape[0]
    if L:
        eps = 1e-4 * (1.0 + jnp.max(jnp.abs(p), 0))

        def occluders(Lpos):
            Lp = Lpos[:, None]
            Lv = Lp - p
            dist = V.norm(Lv)
            ld = V.normalize(Lv)
            f, _ = _search(scene, kinds, off, p + eps[None] * ld, ld, dist - 2 * eps)
            la, _ = _search(scene, kinds, off, jnp.broadcast_to(Lp, p.shape), -ld, dist - 2 * eps)
            return jnp.where(hit, f, -1), jnp.where(hit, la, -1)

        first, last = jax.lax.map(occluders, scene.lights.position)
    else:
        first = last = jnp.zeros((0, prim.shape[0]), jnp.int32)
    return xy, prim, first, last


@dataclasses.dataclass(frozen=True)
class EdgeOptions:
    """Static options of the boundary term: ``samples`` per pixel side (``n``) and
    ``budget``, the most sample pairs with an edge between them (``None``: a
    quarter of all samples)."""

    samples: int = 4
    budget: int | None = None


def _pairs(Gw, Gh):
    j = jnp.arange(Gw)
    i = jnp.arange(Gh)
    a_h = (i[:, None] * Gw + j[None, :-1]).ravel()
    a_v = (i[:-1, None] * Gw + j[None, :]).ravel()
    a = jnp.concatenate([a_h, a_v]).astype(jnp.int32)
    b = jnp.concatenate([a_h + 1, a_v + Gw]).astype(jnp.int32)
    horiz = jnp.concatenate([jnp.ones_like(a_h, bool), jnp.zeros_like(a_v, bool)])
    return a, b, horiz


def edge_term(scene, width, height, eo: EdgeOptions, radiance_at, lights_at, f_grid, _debug=False):
    """The boundary term as an ``(height, width, 3)`` image whose *value* is zero and
    whose derivative with respect to ``scene`` is the edge contribution, and the
    number of sample pairs with an edge between them.

    ``radiance_at(xy (2, M)) -> (M, 3)``: radiance of camera rays through image
    positions ``xy``; ``lights_at(xy) -> (L, M, 3)``: each light's direct term at
    their first hit; ``f_grid (S, 3)``: the radiance of the grid samples. All
    are treated as constants. The jump ``f_minus - f_plus`` is measured just on
    either side of the edge point (``1/256`` of the sample spacing away for
    visibility edges, 0.03 pixel for shadow edges), where the probes see the same
    primitives as the two samples (else at the samples).
    """
    n = eo.samples
    Gw, Gh = width * n, height * n
    S = Gw * Gh
    xy, prim, first, last = sample_records(scene, width, height, n)
    f_grid = jax.lax.stop_gradient(f_grid)
    L = first.shape[0]
    a, b, horiz = _pairs(Gw, Gh)
    P, off = build_prims(scene)
    P_sg = jax.lax.stop_gradient(P)
    ns = off["ns"]
    # Object keys: the faces of one convex solid are one occluder.
    key = jnp.asarray(np.concatenate([np.arange(ns), ns + np.where(off["solid"] >= 0, off["solid"],
                                                                   np.arange(off["solid"].shape[0]))]))

    def okey(g):
        return jnp.where(g >= 0, key[jnp.clip(g, 0, key.shape[0] - 1)], -1)

    pa, pb = prim[a], prim[b]
    act = [pa != pb]
    same = (pa == pb) & (pa >= 0)
    # Shadow slots: light k, candidate occluder j (last / first occluder of either
    # sample's shadow segment), each distinct occluding object once.
    for k in range(L):
        differ = same & ((first[k, a] != first[k, b]) | (last[k, a] != last[k, b]))
        cands = [last[k, a], first[k, a], last[k, b], first[k, b]]
        keys = [okey(c) for c in cands]
        for j in range(4):
            new = differ & (cands[j] >= 0) & (keys[j] != okey(pa))
            for i in range(j):
                new = new & (keys[j] != keys[i])
            act.append(new)
    nslot = 1 + 4 * L
    act = jnp.stack(act, 1).ravel()  # (npairs * nslot,) pair-major
    K = eo.budget if eo.budget is not None else max(4096, S // 4)
    K = min(K, act.shape[0])
    count = jnp.sum(act)
    (flat,) = jnp.nonzero(act, size=K, fill_value=0)
    flat = flat.astype(jnp.int32)
    live = jnp.arange(K) < count
    pair = flat // nslot
    slot = flat % nslot
    ea, eb = a[pair], b[pair]
    eh = horiz[pair]
    xa, xb = xy[:, ea], xy[:, eb]

    sg = jax.lax.stop_gradient(scene)
    A, B = prim[ea], prim[eb]
    k_ev = jnp.maximum(slot - 1, 0) // 4
    j_ev = jnp.maximum(slot - 1, 0) % 4
    zeros = jnp.zeros_like(A)
    E = A.shape[0]
    if L:
        occ = jnp.where(j_ev == 0, last[k_ev, ea], jnp.where(j_ev == 1, first[k_ev, ea],
                                                             jnp.where(j_ev == 2, last[k_ev, eb], first[k_ev, eb])))
    else:
        occ = zeros

    def G(ev, x):
        return edge_value(sg, P_sg, ns, ev, x, width, height)

    def cat(*evs):
        return Events(*(jnp.concatenate(f) for f in zip(*evs)))

    # One batched evaluation (one compiled copy of G) classifies every event:
    # primary visibility (which edge function separates the two samples?) and
    # shadows (is the occluder hit by one shadow segment and missed by the other?).
    ev_d = Events(zeros + DEPTH, A, B, zeros, zeros)
    ev_s = Events(zeros + SHADOW, A, occ, k_ev, zeros)
    evs = [Events(zeros + MISS, A, B, zeros, zeros), Events(zeros + MISS, B, A, zeros, zeros), ev_d, ev_d,
           ev_s, ev_s]
    vals = G(cat(*evs), jnp.concatenate([xb, xa, xa, xb, xa, xb], 1)).reshape(len(evs), E)
    mAb, mBa = vals[0], vals[1]
    case1 = (A >= 0) & (mAb > 0)
    case2 = ~case1 & (B >= 0) & (mBa > 0)
    # Depth crossings: t_A - t_B changes sign between the samples. Where two
    # surfaces cross, the nearer one is seen (t_A < t_B at a); at a crease of a
    # convex solid, the face seen is the one whose plane is hit *last*.
    up = (vals[2] <= 0) & (vals[3] >= 0)
    down = (vals[2] >= 0) & (vals[3] <= 0)
    case3 = ~case1 & ~case2 & (A >= 0) & (B >= 0) & (up | down)
    typ_v = jnp.where(case1 | case2, MISS, DEPTH)
    p1_v = jnp.where(case2, B, A)
    sign_v = jnp.where(case2 | (case3 & ~up), -1, 1)
    ok_v = case1 | case2 | case3
    ma, mb = vals[4], vals[5]
    ok_s = (occ >= 0) & ((ma <= 0) != (mb <= 0))
    sgn_s = jnp.where(ma <= 0, 1, -1)

    vis = slot == 0
    ev = Events(jnp.where(vis, typ_v, SHADOW), jnp.where(vis, p1_v, A), jnp.where(vis, B, occ), k_ev,
                jnp.where(vis, sign_v, sgn_s))
    sgn = ev.sign.astype(xy.dtype)
    ok = live & jnp.where(vis, ok_v, ok_s)
    ev2 = cat(ev, ev)
    sgn2 = jnp.concatenate([sgn, sgn])

    def g_sg(x):
        return sgn2 * G(ev2, x)

    # Bisection on the doubled batch (two copies of each bracket; the second copy
    # is differentiated along y below).
    xa2, xb2 = jnp.concatenate([xa, xa], 1), jnp.concatenate([xb, xb], 1)

    def bisect(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        neg = g_sg(xa2 + mid[None] * (xb2 - xa2)) <= 0
        return jnp.where(neg, mid, lo), jnp.where(neg, hi, mid)

    lo, hi = jax.lax.fori_loop(0, BISECTION_STEPS, bisect, (jnp.zeros_like(sgn2), jnp.ones_like(sgn2)))
    xs2 = xa2 + (0.5 * (lo + hi))[None] * (xb2 - xa2)
    # d g / d x and d g / d y in one forward-mode pass over the doubled batch.
    tang = jnp.concatenate([jnp.zeros_like(xa).at[0].set(1.0), jnp.zeros_like(xa).at[1].set(1.0)], 1)
    _, gxy = jax.jvp(g_sg, (xs2,), (tang,))
    gx, gy = gxy[:E], gxy[E:]
    xs = xs2[:, :E]
    den = jnp.abs(gx) + jnp.abs(gy)
    ok = ok & (den > 0) & jnp.isfinite(den)
    gdir = jnp.where(eh, gx, gy)
    # The jump, measured on either side of the edge point.
    # Probes sit 1/256 of the sample spacing from a visibility edge (camera rays are
    # exact there). The renderer offsets shadow rays from the surface (by 1e-4 of
    # the scene's scale), which moves its shadow edges by ~1e-3 pixel; shadow
    # probes keep 0.03 pixel (at most 0.45 of the spacing) from the edge so that
    # they fall on the two sides of the renderer's own shadow edge.
    frac = jnp.where(vis, 1.0 / 256.0, jnp.maximum(1.0 / 256.0, jnp.minimum(0.45, 0.03 * n)))
    u = (xb - xa) * frac[None]
    probes = jax.lax.stop_gradient(jnp.concatenate([xs - u, xs + u], 1))
    pid = primary_ids(sg, probes, width, height)
    same_m = pid[:E] == jnp.where(vis, A, A)
    same_p = pid[E:] == jnp.where(vis, B, A)
    fr = jax.lax.stop_gradient(radiance_at(probes))
    df_vis = jnp.where((same_m & same_p)[:, None], fr[:E] - fr[E:], f_grid[ea] - f_grid[eb])  # (E, 3)
    if L:
        fl = jax.lax.stop_gradient(lights_at(probes))  # (L, 2E, 3)
        kk = jnp.concatenate([k_ev, k_ev])
        fl = jnp.take_along_axis(fl, kk[None, :, None], 0)[0]
        df_sh = jnp.where((same_m & same_p)[:, None], fl[:E] - fl[E:], 0.0)
        df = jnp.where(vis[:, None], df_vis, df_sh)
    else:
        df = df_vis
    if _debug:  # intermediate values, for tests and diagnosis
        return dict(ok=ok, vis=vis, ev=ev, xs=xs, den=den, gdir=gdir, df=df, count=count)
    coef = -df * (jnp.sign(gdir) * V.safe_div(1.0, den) / n)[:, None]
    coef = jnp.where(ok[:, None] & jnp.isfinite(coef), coef, 0.0)
    coef = jax.lax.stop_gradient(coef)
    xs = jax.lax.stop_gradient(xs)

    # The differentiable part: g at the (fixed) edge point, with the live scene.
    g = sgn * edge_value(scene, P, ns, ev, xs, width, height)
    g = jnp.where(ok, g, 0.0)
    term = coef * g[:, None]  # (E, 3)
    px = jnp.clip(jnp.floor(xs[0]).astype(jnp.int32), 0, width - 1)
    py = jnp.clip(jnp.floor(xs[1]).astype(jnp.int32), 0, height - 1)
    img = jnp.zeros((height * width, 3), term.dtype).at[py * width + px].add(term)
    img = eqx.error_if(img, count > K, f"edge_gradients: more sample pairs straddle an edge than "
                                       f"edge_budget={K}; pass a larger edge_budget to render")
    img = img - jax.lax.stop_gradient(img)
    return img.reshape(height, width, 3), count
