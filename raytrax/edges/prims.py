"""The scene's primitives as :mod:`raytrax.edges` sees them (every primitive a sphere
or a convex planar polygon, disks being round polygons), their global ids in kind
registry order, and per-primitive geometry: the miss function, the first surface
crossing along a line, and the specular step of a chain."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import vec as V
from ..intersect import offset_scale
from ..lights import LIGHTS
from ..materials import facing, interface, refract
from ..shapes import KINDS, sphere_roots_safe
from ..shapes.base import plane_distance

MAX_FACES = 6  # faces of the largest convex solid (a box)


class Prims(NamedTuple):
    """Every primitive as a sphere or a convex planar polygon (component-major).

    Global ids follow the kind registry (:data:`raytrax.shapes.KINDS`): spheres
    ``[0, ns)``, then every other kind's polygons in registry order (planes, quads,
    disks as round polygons, triangles, tetrahedron faces, mesh faces, box faces:
    6 per box, face ``2 axis + (side > 0)``); see :func:`id_offsets`. The tables of
    what the scene lacks are empty (``prad`` without disks; ``solid`` and ``nface``
    without boxes and tetrahedra), and :func:`miss`, :func:`first_t` and
    :func:`specular_step` then carry no code for it (nor for spheres when ``ns`` is 0):
    a simpler scene compiles a smaller program.
    """

    c: jax.Array  # (3, Ns) sphere centres
    r: jax.Array  # (Ns,)
    pp: jax.Array  # (3, Np) a point of the polygon's plane
    pn: jax.Array  # (3, Np) unit plane normal
    eo: jax.Array  # (4, 3, Np) edge origins
    em: jax.Array  # (4, 3, Np) unit in-plane edge normals pointing inside
    finite: jax.Array  # (Np,) False for infinite planes
    prad: jax.Array  # (Np,) > 0: a disk of that radius about pp (the edges are unused); (0,) if no disk
    solid: jax.Array  # (Np,) polygon index of the first face of its convex solid, -1: none; (0,) if no solid
    nface: jax.Array  # (Np,) faces of that solid (6 box, 4 tetrahedron, 0 none); (0,) if no solid
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
    ``solid`` table (polygon index of each polygon's solid's first face, -1: none)
    and the ``group`` table (polygon index of the first face of each polygon's
    object where the kind groups its faces, ``KindSpec.face_groups``; -1: none)."""
    dt = scene.dtype
    off = id_offsets(scene)
    ns = off["ns"]
    parts = []  # EdgePolygons per kind
    solids = []  # (first polygon index, faces per solid, number of solids)
    grouped = []  # (first polygon index, faces per object) of kinds whose faces occlude as one
    round_ = False  # some polygon is a disk
    for spec in KINDS:
        if spec.edge == "sphere":
            continue
        group = scene.prims[spec.field]
        n = spec.n_ids(group)
        if not n:
            continue
        round_ = round_ or spec.edge == "disk"
        if spec.solid_faces:
            solids.append((off[spec.name] - ns, spec.solid_faces, n // spec.solid_faces))
        sizes = spec.face_groups(group)
        if sizes:
            grouped.append((off[spec.name] - ns, sizes))
        parts.append(spec.edge_polygons(group))
    if parts:
        pp, pn, eo, em, fin, prad, pmat = (jnp.concatenate(x, 0) for x in zip(*parts, strict=True))
    else:  # one dummy polygon keeps the gathers well defined
        pp = pn = jnp.zeros((1, 3), dt)
        eo = em = jnp.zeros((1, 4, 3), dt)
        fin = jnp.zeros((1,), bool)
        prad = jnp.zeros((1,), dt)
        pmat = jnp.zeros((1,), jnp.int32)
    npoly = fin.shape[0] if solids else 0  # no convex solid: empty tables
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
    if not round_:
        prad = prad[:0]  # no disk: an empty table, and no disk code where it is read
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
    # The polygon index of the first face of each grouped face's object (a mesh's;
    # KindSpec.face_groups), -1 where the polygon is an object of its own.
    group = np.full((fin.shape[0] if parts else 0,), -1, np.int32)
    for start, sizes in grouped:
        for k in sizes:
            group[start : start + k] = start
            start += k
    return prims, dict(off, solid=solid, group=group)


def split_ids(P: Prims, ns, ids):
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
    is_s, si, pi = split_ids(P, ns, ids)
    n = P.pn[:, pi]
    t = plane_distance(P.pp[:, pi], n, o, d)
    p = o + t[None] * d
    s = jnp.stack([V.dot(p - P.eo[i][:, pi], P.em[i][:, pi]) for i in range(4)])
    gp = -jnp.min(s, 0)
    feat = jnp.argmin(s, 0).astype(jnp.int32)
    gp = jnp.where(P.finite[pi], gp, -1.0)
    if P.prad.shape[0]:
        # A disk: distance of the plane hit from its centre beyond the radius.
        disk = P.prad[pi] > 0
        gp = jnp.where(disk, V.norm(p - P.pp[:, pi]) - P.prad[pi], gp)
        feat = jnp.where(disk, 0, feat)
    if P.solid.shape[0]:
        # A face of a convex solid (box, tetrahedron): the solid's own miss function,
        # t_near - t_far over its face planes, so that a crease between two of its
        # faces is never mistaken for its silhouette.
        first = jnp.maximum(P.solid[pi], 0)
        big = jnp.asarray(1e30, o.dtype)
        # Every face slot at once, (MAX_FACES, E); slots past the solid's faces unused.
        j = jnp.arange(MAX_FACES, dtype=jnp.int32)[:, None]
        fj = jnp.clip(first[None] + j, 0, P.finite.shape[0] - 1)
        use = j < P.nface[pi][None]
        nj = P.pn[:, fj]  # (3, MAX_FACES, E)
        den = V.dot(d[:, None], nj)
        num = V.dot(P.pp[:, fj] - o[:, None], nj)
        t = V.safe_div(num, den)
        par = jnp.abs(den) <= 1e-30
        enter = jnp.where(par, jnp.where(num >= 0, -big, big), jnp.where(den < 0, t, -big))
        leave = jnp.where(par, jnp.where(num >= 0, big, -big), jnp.where(den > 0, t, big))
        # The entry (exit) plane: the first slot of the largest entry (smallest exit),
        # -big (big) and slot 0 when no face bounds it.
        tn = jnp.maximum(jnp.max(jnp.where(use, enter, -big), 0), -big)
        tf = jnp.minimum(jnp.min(jnp.where(use, leave, big), 0), big)
        jn = jnp.min(jnp.where(use & (enter == tn[None]) & (enter > -big), j, MAX_FACES), 0)
        jf = jnp.min(jnp.where(use & (leave == tf[None]) & (leave < big), j, MAX_FACES), 0)
        jn = jnp.where(jn == MAX_FACES, 0, jn)
        jf = jnp.where(jf == MAX_FACES, 0, jf)
        solid = P.solid[pi] >= 0
        gp = jnp.where(solid, tn - tf, gp)
        feat = jnp.where(solid, 8 * jn + jf, feat)
    if not ns:  # no sphere in the scene
        return gp, feat
    oc = P.c[:, si] - o
    x = V.cross(oc, d)
    gs = V.dot(x, x) - P.r[si] ** 2 * V.dot(d, d)
    return jnp.where(is_s, gs, gp), jnp.where(is_s, 0, feat)


def first_t(P: Prims, ns, ids, o, d):
    """Distance along unit ``d`` to the first crossing of primitive ``ids``'s surface
    (a sphere's first positive root, a polygon's plane)."""
    is_s, si, pi = split_ids(P, ns, ids)
    tp = plane_distance(P.pp[:, pi], P.pn[:, pi], o, d)
    if not ns:  # no sphere in the scene
        return tp
    t1, t2 = sphere_roots_safe(P.c[:, si], P.r[si], o, d)
    return jnp.where(is_s, jnp.where(t1 > 0, t1, t2), tp)


def specular_step(P: Prims, ns, ids, want_t, o, d):
    """The specular child of rays ``o, d (3, E)`` at their hit on primitive ``ids``:
    refracted where ``want_t`` (unless totally internally reflected), else
    reflected, from the same offset origins as the renderer's. Returns the child's
    origin and direction and whether it was refracted."""
    is_s, si, pi = split_ids(P, ns, ids)
    t = first_t(P, ns, ids, o, d)
    p = o + t[None] * d
    n = V.vsel(is_s, V.normalize(p - P.c[:, si]), P.pn[:, pi]) if ns else P.pn[:, pi]
    face = facing(d, n)
    n_s = face.n_s
    itf = interface(face, P.ior[P.mat[jnp.clip(ids, 0, P.mat.shape[0] - 1)]])
    refr = want_t & ~itf.tir
    eps = offset_scale(p)
    o2 = V.vsel(refr, p - eps[None] * n_s, p + eps[None] * n_s)
    d2 = V.vsel(refr, refract(d, n_s, itf.eta, itf.cos_t), V.reflect(d, n_s))
    return o2, d2, refr


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
