"""Primitive intersections against analytic values: hit and miss, distance,
outward normal, rays starting inside, grazing rays, surface coordinates (u, v).

Two levels are tested: the stop-gradient distance kernels of
:mod:`raytrax.shapes` (``*_t``) and the full closest-hit query of
:mod:`raytrax.intersect` (which recomputes t, normal and uv differentiably) on
scenes built with :class:`raytrax.SceneBuilder` in float64.
"""

from __future__ import annotations

import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt
from raytrax import shapes as S
from raytrax.intersect import closest_hit, prepare

F64 = jnp.float64
INF = np.inf


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------


@eqx.filter_jit
def _hits(scene, o, d):
    return closest_hit(prepare(scene), o, d)


def hits(scene, o, d):
    """Closest hits of rays ``o, d (n, 3)`` (d normalised here) as numpy arrays:
    valid (n,), t (n,), normal (n, 3), uv (n, 2)."""
    o = np.atleast_2d(np.asarray(o, np.float64))
    d = np.atleast_2d(np.asarray(d, np.float64))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = len(o)
    o, d = _pad(o), _pad(d)
    h = _hits(scene, jnp.asarray(o.T), jnp.asarray(d.T))
    return (np.asarray(h.valid)[:n], np.asarray(h.t)[:n], np.asarray(h.normal).T[:n], np.asarray(h.uv).T[:n])


NRAYS = 320  # every query is padded to this many rays: one compilation per scene structure


def _pad(a):
    assert len(a) <= NRAYS
    return np.concatenate([a, np.repeat(a[-1:], NRAYS - len(a), 0)], 0)


def kernel_t(tfun, soa, o, d, tmin=0.0):
    """Run a stop-gradient distance kernel on rays ``o, d (n, 3)``; returns (n, N)."""
    o = np.atleast_2d(np.asarray(o, np.float64))
    d = np.atleast_2d(np.asarray(d, np.float64))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = len(o)
    o, d = _pad(o), _pad(d)
    ray = tuple(jnp.asarray(a)[:, None] for a in (o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2]))
    P = {k: jnp.asarray(v)[None, :] for k, v in soa.items()}
    return np.asarray(_jitted(tfun)(ray, P, jnp.asarray(tmin, F64)))[:n]


_JIT = {}


def _jitted(f):
    if f not in _JIT:
        _JIT[f] = jax.jit(f)
    return _JIT[f]


def builder():
    b = rt.SceneBuilder("classic", width=8, height=8)
    b.material("m", color=(0.5, 0.5, 0.5))
    return b


def rng_dirs(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rot_np(deg):
    """Independent Euler rotation (x first, then y, then z) in numpy."""
    ax, ay, az = np.deg2rad(deg)
    Rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    Ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    Rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def sphere_ref(o, d, c, r):
    """Numpy ray/sphere: nearest t > 0 (inf on a miss), d unit."""
    oc = o - c
    b = (d * oc).sum(1)
    cc = (oc * oc).sum(1) - r * r
    disc = b * b - cc
    sq = np.sqrt(np.maximum(disc, 0))
    t1, t2 = -b - sq, -b + sq
    t = np.where(t1 > 0, t1, np.where(t2 > 0, t2, INF))
    return np.where(disc >= 0, t, INF)


def box_ref(o, d, lo, hi):
    """Numpy slab test for an axis-aligned box: (t, outward normal)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    tn_ax, tf_ax = np.minimum(t1, t2), np.maximum(t1, t2)
    tn, tf = tn_ax.max(1), tf_ax.min(1)
    entering = tn > 0
    t = np.where(entering, tn, tf)
    ok = (tn <= tf) & (tf > 0)
    ax = np.where(entering, tn_ax.argmax(1), tf_ax.argmin(1))
    sgn = np.sign(d[np.arange(len(d)), ax])
    n = np.zeros_like(o)
    n[np.arange(len(d)), ax] = np.where(entering, -sgn, sgn)
    return np.where(ok, t, INF), n


def cube_mesh(lo, hi, R=None):
    """A box as 12 outward-wound triangles (vertices (8, 3), faces (12, 3)),
    optionally rotated by R about its centre."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    # vertex index = 4*ix + 2*iy + iz
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    c = 0.5 * (lo + hi)
    for q in quads:
        a, b_, cc, d = q
        for tri in ((a, b_, cc), (a, cc, d)):
            n = np.cross(v[tri[1]] - v[tri[0]], v[tri[2]] - v[tri[0]])
            if np.dot(n, v[list(tri)].mean(0) - c) < 0:
                tri = (tri[0], tri[2], tri[1])
            faces.append(tri)
    if R is not None:
        v = (v - c) @ R.T + c
    return v, np.asarray(faces, np.int32)


# ----------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------

C_S = np.array([1.0, 2.0, -3.0])
R_S = 2.0


@pytest.fixture(scope="module")
def sphere_scene():
    b = builder()
    b.sphere(C_S, R_S, "m")
    return b.build(F64)


def test_sphere_hit_from_outside(sphere_scene):
    o = C_S + np.array([[0, 0, 10.0], [0, 7.0, 0], [-5.0, 0, 0]])
    d = C_S - o
    valid, t, n, _ = hits(sphere_scene, o, d)
    assert valid.all()
    np.testing.assert_allclose(t, np.linalg.norm(C_S - o, axis=1) - R_S, rtol=1e-12)
    np.testing.assert_allclose(n, -d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-12)


def test_sphere_miss_and_behind(sphere_scene):
    o = np.array([C_S + [0, 0, 10.0], C_S + [0, 0, 10.0], C_S + [R_S + 0.01, 0, 10.0]])
    d = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 0, -1.0]])  # away, sideways, just beside
    valid, t, _, _ = hits(sphere_scene, o, d)
    assert not valid.any()
    assert np.all(np.isfinite(t))


def test_sphere_ray_starting_inside_hits_far_side_outward_normal(sphere_scene):
    rng = np.random.default_rng(0)
    d = rng_dirs(rng, 16)
    o = np.tile(C_S + [0.3, -0.2, 0.1], (16, 1))
    valid, t, n, _ = hits(sphere_scene, o, d)
    assert valid.all()
    np.testing.assert_allclose(t, sphere_ref(o, d, C_S, R_S), rtol=1e-10)
    p = o + t[:, None] * d
    np.testing.assert_allclose(np.linalg.norm(p - C_S, axis=1), R_S, rtol=1e-12)
    np.testing.assert_allclose(n, (p - C_S) / R_S, atol=1e-10)
    assert np.all((n * d).sum(1) > 0)  # outward normal, ray leaving


def test_sphere_grazing_rays():
    P = S.sphere_soa(rt.Spheres(jnp.asarray([C_S]), jnp.asarray([R_S]), jnp.asarray([0])))
    eps = 1e-6
    o = np.array([C_S + [R_S, 0, 10], C_S + [R_S * (1 + eps), 0, 10], C_S + [R_S * (1 - eps), 0, 10]])
    d = np.tile([0, 0, -1.0], (3, 1))
    t = kernel_t(S.sphere_t, P, o, d)[:, 0]
    assert t[0] == pytest.approx(10.0, abs=1e-6)  # tangent: touches at the equator
    assert t[1] == INF
    # just inside the silhouette: enters close to the tangent point
    assert t[2] == pytest.approx(10.0 - R_S * math.sqrt(2 * eps), abs=1e-6)


def test_sphere_distance_matches_reference_random_rays(sphere_scene):
    rng = np.random.default_rng(1)
    o = C_S + 6 * rng_dirs(rng, 64)
    d = (C_S + rng.uniform(-3, 3, (64, 3))) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ref = sphere_ref(o, d, C_S, R_S)
    assert 10 < np.isfinite(ref).sum() < 60  # both hits and misses
    valid, t, n, _ = hits(sphere_scene, o, d)
    np.testing.assert_array_equal(valid, np.isfinite(ref))
    np.testing.assert_allclose(t[valid], ref[valid], rtol=1e-10)
    p = o + t[:, None] * d
    np.testing.assert_allclose(n[valid], ((p - C_S) / R_S)[valid], atol=1e-9)
    # tmin: the kernel ignores hits at t <= tmin (so the far root is reported)
    P = S.sphere_soa(rt.Spheres(jnp.asarray([C_S]), jnp.asarray([R_S]), jnp.asarray([0])))
    k = np.flatnonzero(valid)[0]
    t_far = kernel_t(S.sphere_t, P, o[k : k + 1], d[k : k + 1], tmin=float(t[k]) + 1e-9)[0, 0]
    oc = o[k] - C_S
    b = oc @ d[k]
    assert t_far == pytest.approx(-b + math.sqrt(b * b - oc @ oc + R_S**2), rel=1e-10)


def test_sphere_uv_of_known_points(sphere_scene):
    # u: longitude about +y, 0.5 facing +z, 0.75 facing +x; v: 0 at -y, 1 at +y
    dirs = np.array(
        [
            [0, 0, 1.0],
            [1.0, 0, 0],
            [-1.0, 0, 0],
            [0, 1.0, 0.001],
            [0, -1.0, 0.001],
            [0, math.sin(math.radians(30)), math.cos(math.radians(30))],
        ]
    )
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = C_S + 10 * dirs
    valid, t, n, uv = hits(sphere_scene, o, -dirs)
    assert valid.all()
    np.testing.assert_allclose(n, dirs, atol=1e-10)
    np.testing.assert_allclose(uv[:3, 0], [0.5, 0.75, 0.25], atol=1e-10)
    np.testing.assert_allclose(uv[[0, 1, 2, 5], 1], [0.5, 0.5, 0.5, 0.5 + 30 / 180], atol=1e-10)
    assert uv[3, 1] == pytest.approx(1.0, abs=1e-3) and uv[4, 1] == pytest.approx(0.0, abs=1e-3)
    # general points: v = 0.5 + asin(n_y)/pi, u = 0.5 + atan2(n_x, n_z)/(2 pi)
    rng = np.random.default_rng(2)
    dd = rng_dirs(rng, 8)
    _, _, n2, uv2 = hits(sphere_scene, C_S + 10 * dd, -dd)
    np.testing.assert_allclose(uv2[:, 1], 0.5 + np.arcsin(dd[:, 1]) / np.pi, atol=1e-9)
    np.testing.assert_allclose(uv2[:, 0], 0.5 + np.arctan2(dd[:, 0], dd[:, 2]) / (2 * np.pi), atol=1e-9)


# ----------------------------------------------------------------------------
# infinite plane
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def plane_scene():
    b = builder()
    b.plane((0.0, -1.0, 0.0), (0.0, 2.0, 0.0), "m")  # un-normalised normal on purpose
    return b.build(F64)


def test_plane_hit_both_sides_parallel_and_away(plane_scene):
    o = np.array([[0.3, 5.0, 0.7], [2.0, -4.0, -1.0], [0.0, 5.0, 0.0], [0.0, 5.0, 0.0], [1.0, 0.0, 0.0]])
    d = np.array([[0, -1.0, 0], [0, 1.0, 0], [1.0, 0, 0], [0, 1.0, 0], [3.0, -4.0, 0]])
    valid, t, n, _ = hits(plane_scene, o, d)
    np.testing.assert_array_equal(valid, [True, True, False, False, True])
    np.testing.assert_allclose(t[[0, 1, 4]], [6.0, 3.0, 1.25], rtol=1e-12)
    # the geometric normal is the plane's (normalised) normal, whichever side the ray comes from
    np.testing.assert_allclose(n[[0, 1, 4]], np.tile([0, 1.0, 0], (3, 1)), atol=1e-12)


def test_plane_grazing_ray_is_a_miss_without_nan():
    P = S.plane_soa(rt.Planes(jnp.asarray([[0.0, 0, 0]]), jnp.asarray([[0.0, 1, 0]]), jnp.asarray([0])))
    t = kernel_t(
        S.plane_t, P, [[0, 0.0, 0], [0, 1e-3, 0], [0, 1.0, 0]], [[1.0, 0, 0], [1.0, -1e-3, 0], [1.0, -1e-14, 0]]
    )
    assert t[0, 0] == INF  # in the plane
    d1 = np.array([1.0, -1e-3, 0])
    d1 /= np.linalg.norm(d1)
    assert t[1, 0] == pytest.approx(1e-3 / -d1[1], rel=1e-9)
    assert t[2, 0] == INF  # |d.n| below the kernel's threshold: parallel
    assert not np.isnan(t).any()


def test_plane_uv_are_world_lengths(plane_scene):
    rng = np.random.default_rng(3)
    pts = np.stack([rng.uniform(-5, 5, 6), np.full(6, -1.0), rng.uniform(-5, 5, 6)], 1)
    o = pts + [0.0, 3.0, 0.0]
    valid, t, _, uv = hits(plane_scene, o, np.tile([0, -1.0, 0], (6, 1)))
    assert valid.all()
    # u along +x (x projected on the plane), v along the other tangent (-z here)
    np.testing.assert_allclose(uv[:, 0], pts[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.abs(uv[:, 1]), np.abs(pts[:, 2]), atol=1e-12)
    duv = np.linalg.norm(uv[:, None] - uv[None], axis=-1)
    dp = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    np.testing.assert_allclose(duv, dp, atol=1e-12)


# ----------------------------------------------------------------------------
# quad (bounded, convex, inside test as the seed's Plane)
# ----------------------------------------------------------------------------

TRAPEZOID = np.array([[0.0, 0, 1], [2.0, 0, 1], [1.5, 1, 1], [0.5, 1, 1]])  # normal +z


@pytest.fixture(scope="module")
def quad_scene():
    b = builder()
    b.quad(TRAPEZOID, "m")
    return b.build(F64)


def test_quad_inside_test_matches_trapezoid(quad_scene):
    xs = np.linspace(-0.23, 2.21, 23)
    ys = np.linspace(-0.17, 1.19, 13)
    X, Y = np.meshgrid(xs, ys)
    x, y = X.ravel(), Y.ravel()
    inside = (y >= 0) & (y <= 1) & (x >= 0.5 * y) & (x <= 2 - 0.5 * y)
    # keep away from the edges (a hair either side is tested below)
    margin = np.minimum.reduce([np.abs(y), np.abs(1 - y), np.abs(x - 0.5 * y), np.abs(2 - 0.5 * y - x)])
    keep = margin > 1e-3
    o = np.stack([x, y, np.full_like(x, 4.0)], 1)[keep]
    valid, t, n, _ = hits(quad_scene, o, np.tile([0, 0, -1.0], (len(o), 1)))
    np.testing.assert_array_equal(valid, inside[keep])
    np.testing.assert_allclose(t[valid], 3.0, rtol=1e-12)
    np.testing.assert_allclose(n[valid], np.tile([0, 0, 1.0], (valid.sum(), 1)), atol=1e-12)


def test_quad_edges_a_hair_inside_and_outside():
    P = S.quad_soa(rt.Quads(jnp.asarray([TRAPEZOID]), jnp.asarray([0])))
    eps = 1e-7
    mids = [
        (1.0, 0.0, (0, -1)),
        (1.75, 0.5, (2, 1)),
        (1.0, 1.0, (0, 1)),
        (0.25, 0.5, (-2, 1)),
    ]  # edge midpoints, outward dirs
    o, want = [], []
    for x, y, (ex, ey) in mids:
        nrm = np.array([ex, ey]) / math.hypot(ex, ey)
        for s, w in ((-eps, True), (eps, False)):
            o.append([x + s * nrm[0], y + s * nrm[1], 2.0])
            want.append(w)
    t = kernel_t(S.quad_t, P, o, np.tile([0, 0, -1.0], (len(o), 1)))[:, 0]
    np.testing.assert_array_equal(np.isfinite(t), want)


def test_quad_back_side_and_uv_of_rectangle():
    # a tilted rectangle: corners c0, c0+a, c0+a+b, c0+b
    c0 = np.array([1.0, -1.0, 2.0])
    a = np.array([2.0, 0.0, 1.0])
    bvec = np.array([0.0, 3.0, 0.0])
    corners = np.array([c0, c0 + a, c0 + a + bvec, c0 + bvec])
    b = builder()
    b.quad(corners, "m")
    sc = b.build(F64)
    nrm = np.cross(a, bvec) / np.linalg.norm(np.cross(a, bvec))
    st = np.array([[0.25, 0.5], [0.9, 0.1], [0.01, 0.99], [0.5, 0.5]])
    pts = c0 + st[:, :1] * a + st[:, 1:] * bvec
    side = np.array([1, 1, -1, -1])[:, None]  # two from the front, two from the back
    o = pts + 3 * side * nrm
    valid, t, n, uv = hits(sc, o, -side * nrm)
    assert valid.all()
    np.testing.assert_allclose(t, 3.0, rtol=1e-12)
    np.testing.assert_allclose(n, np.tile(nrm, (4, 1)), atol=1e-12)  # right-hand rule, either side
    np.testing.assert_allclose(uv, st, atol=1e-12)


# ----------------------------------------------------------------------------
# triangle
# ----------------------------------------------------------------------------

TRI = np.array([[0.0, 0, 0], [3.0, 0, 1], [0.5, 2.0, -1]])


@pytest.fixture(scope="module")
def tri_scene():
    b = builder()
    b.triangle(TRI, "m")
    return b.build(F64)


def test_triangle_barycentric_hit_and_miss(tri_scene):
    e1, e2 = TRI[1] - TRI[0], TRI[2] - TRI[0]
    nrm = np.cross(e1, e2)
    nrm /= np.linalg.norm(nrm)
    ab = np.array([[0.2, 0.3], [0.01, 0.98], [0.6, 0.1], [0.7, 0.4], [-0.05, 0.5], [0.5, -0.02], [0.3, 0.3]])
    inside = (ab[:, 0] >= 0) & (ab[:, 1] >= 0) & (ab.sum(1) <= 1)
    pts = TRI[0] + ab[:, :1] * e1 + ab[:, 1:] * e2
    dirs = np.array([-nrm + [0.3, 0.1, 0.0]] * len(ab))  # oblique rays
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = pts - 5.0 * dirs
    o[-1] = pts[-1] + 5.0 * nrm * -1  # last one from behind
    dirs[-1] = nrm
    valid, t, n, uv = hits(tri_scene, o, dirs)
    np.testing.assert_array_equal(valid, inside)
    np.testing.assert_allclose(t[inside], 5.0, rtol=1e-12)
    np.testing.assert_allclose(n[inside], np.tile(nrm, (inside.sum(), 1)), atol=1e-12)
    np.testing.assert_allclose(uv[inside], ab[inside], atol=1e-12)


def test_triangle_ray_in_its_plane_misses_without_nan():
    P = S.tri_soa(jnp.asarray(TRI[:1]), jnp.asarray(TRI[1:2]), jnp.asarray(TRI[2:3]))
    e1 = TRI[1] - TRI[0]
    t = kernel_t(S.tri_t, P, [TRI[0] - e1], [e1])
    assert t[0, 0] == INF


# ----------------------------------------------------------------------------
# tetrahedron
# ----------------------------------------------------------------------------

TET_C = np.array([0.5, 1.0, -2.0])
TET_A = 2.0


@pytest.fixture(scope="module")
def tet_tris():
    tet = rt.Tetrahedra(jnp.asarray([TET_C]), jnp.asarray([TET_A]), jnp.asarray([0]))
    tris, mats = tet.triangles()
    return np.asarray(tris), np.asarray(mats)


def test_tetrahedron_is_regular_with_apex_up(tet_tris):
    tris, mats = tet_tris
    assert tris.shape == (4, 3, 3) and mats.shape == (4,)
    verts = np.unique(np.round(tris.reshape(-1, 3), 12), axis=0)
    assert len(verts) == 4
    np.testing.assert_allclose(verts.mean(0), TET_C, atol=1e-12)  # centroid at the centre
    dists = [np.linalg.norm(p - q) for p, q in itertools.combinations(verts, 2)]
    np.testing.assert_allclose(dists, TET_A, rtol=1e-12)  # six edges of the given size
    top = verts[verts[:, 1].argmax()]
    np.testing.assert_allclose(top, TET_C + [0, TET_A * math.sqrt(6) / 4, 0], atol=1e-12)
    base = verts[verts[:, 1] < top[1] - 1e-9]
    np.testing.assert_allclose(base[:, 1], TET_C[1] - TET_A * math.sqrt(6) / 12, atol=1e-12)  # horizontal base


def test_tetrahedron_face_normals_point_outward(tet_tris):
    tris, _ = tet_tris
    r_in = TET_A / math.sqrt(24)
    for v in tris:
        n = np.cross(v[1] - v[0], v[2] - v[0])
        n /= np.linalg.norm(n)
        # outward: the face plane lies at +inradius from the centre along n
        assert np.dot(v.mean(0) - TET_C, n) == pytest.approx(r_in, rel=1e-12)


def test_tetrahedron_faces_close_up(tet_tris):
    """Watertight: every directed edge appears once and its reverse once."""
    tris, _ = tet_tris
    key = lambda p: tuple(np.round(p, 9))
    directed = [(key(v[i]), key(v[(i + 1) % 3])) for v in tris for i in range(3)]
    assert len(set(directed)) == 12
    for a, b in directed:
        assert (b, a) in directed


def test_tetrahedron_rays_from_inside_hit_once_through_hit_twice(tet_tris):
    tris, _ = tet_tris
    P = S.tri_soa(jnp.asarray(tris[:, 0]), jnp.asarray(tris[:, 1]), jnp.asarray(tris[:, 2]))
    rng = np.random.default_rng(4)
    d = rng_dirs(rng, 64)
    t_in = kernel_t(S.tri_t, P, np.tile(TET_C, (64, 1)), d)
    np.testing.assert_array_equal(np.isfinite(t_in).sum(1), 1)
    t_min = np.min(t_in, 1)
    R = TET_A * math.sqrt(6) / 4
    assert np.all(t_min >= TET_A / math.sqrt(24) - 1e-12) and np.all(t_min <= R + 1e-12)
    # from outside, straight through the centre: one entry and one exit
    o = TET_C - 5 * d
    t_out = kernel_t(S.tri_t, P, o, d)
    np.testing.assert_array_equal(np.isfinite(t_out).sum(1), 2)


def test_tetrahedron_in_scene_matches_its_triangles(tet_tris):
    tris, _ = tet_tris
    b1 = builder()
    b1.tetrahedron(TET_C, TET_A, "m")
    # the same four faces as a mesh, padded to the cube mesh's shapes below (8 vertices,
    # 12 faces: each face three times) so that both mesh queries share one compilation
    _, first = np.unique(np.round(tris.reshape(-1, 3), 9), axis=0, return_index=True)
    verts = tris.reshape(-1, 3)[first]  # exact vertex values
    faces = np.array([[np.argmin(np.linalg.norm(verts - p, axis=1)) for p in tri] for tri in tris])
    b2 = builder()
    b2.mesh(np.concatenate([verts, verts]), np.tile(faces, (3, 1)), "m")
    rng = np.random.default_rng(5)
    o = TET_C + 4 * rng_dirs(rng, 48)
    d = TET_C + rng.uniform(-1, 1, (48, 3)) - o
    h1 = hits(b1.build(F64), o, d)
    h2 = hits(b2.build(F64), o, d)
    assert 10 < h1[0].sum() < 48
    for x, y in zip(h1, h2):
        np.testing.assert_allclose(x, y, atol=1e-12)
    # outward normal on entry: facing against the ray
    assert np.all((h1[2][h1[0]] * d[h1[0]]).sum(1) < 0)


# ----------------------------------------------------------------------------
# box (axis-aligned and rotated) and mesh
# ----------------------------------------------------------------------------

LO = np.array([-1.0, -2.0, -3.0])
HI = np.array([1.0, 2.0, 3.0])
SHIFT = np.array([0.5, -0.25, 1.0])
ROT = np.array([30.0, 45.0, 60.0])


@pytest.fixture(scope="module")
def box_scene():
    b = builder()
    b.box(LO + SHIFT, HI + SHIFT, "m")
    return b.build(F64)


def test_box_axis_rays_from_outside_and_inside(box_scene):
    c = SHIFT
    o = np.array([c + [10, 0, 0], c + [0, -10, 0], c + [0, 0, 10], c, c, c + [0.5, 0.5, 0.5]])
    d = np.array([[-1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0], [0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
    valid, t, n, _ = hits(box_scene, o, d)
    assert valid.all()
    np.testing.assert_allclose(t, [9.0, 8.0, 7.0, 3.0, 1.0, 2.5], rtol=1e-12)
    want_n = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
    np.testing.assert_allclose(n, want_n, atol=1e-12)


def test_box_random_rays_match_slab_reference(box_scene):
    rng = np.random.default_rng(6)
    o = SHIFT + 8 * rng_dirs(rng, 64)
    o[:8] = SHIFT + rng.uniform(-0.9, 0.9, (8, 3))  # some start inside
    d = SHIFT + rng.uniform(-3, 3, (64, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_ref, n_ref = box_ref(o, d, LO + SHIFT, HI + SHIFT)
    assert 10 < np.isfinite(t_ref).sum() < 60
    valid, t, n, _ = hits(box_scene, o, d)
    np.testing.assert_array_equal(valid, np.isfinite(t_ref))
    np.testing.assert_allclose(t[valid], t_ref[valid], rtol=1e-10)
    np.testing.assert_allclose(n[valid], n_ref[valid], atol=1e-12)


def test_box_grazing_rays():
    bx = rt.Boxes(jnp.asarray([LO]), jnp.asarray([HI]), jnp.zeros((1, 3), F64), jnp.asarray([0]))
    P = S.box_soa(bx)
    eps = 1e-9
    o = np.array([[-5, 2 + eps, 0.0], [-5, 2 - eps, 0.0], [-5, 2 + eps, 3 + eps], [-5, 2.0, 0.0]])
    d = np.tile([1.0, 0, 0], (4, 1))
    t = kernel_t(S.box_t, P, o, d)[:, 0]
    assert t[0] == INF and t[2] == INF
    assert t[1] == pytest.approx(4.0, rel=1e-12)
    assert not np.isnan(t[3])  # along a face: either a hit at 4 or a miss, never NaN
    assert t[3] == INF or t[3] == pytest.approx(4.0)
    # Shadow segments of length 20 along the same rays: through the box (2 crossings) only
    # inside the slab; along the face 0 or 2, never NaN.
    n = kernel_t(S.box_crossings, P, o, d, tmin=20.0)[:, 0]
    assert n[0] == 0 and n[1] == 2 and n[2] == 0
    assert n[3] in (0, 2)


def test_box_uv_on_faces(box_scene):
    c = SHIFT
    # +z face: u along x, v along y (the two axes after z), scaled to [0, 1]
    o = np.array([c + [0.5, 1.0, 10.0], c + [10.0, -1.0, 1.5], c + [-0.5, 10.0, -1.5]])
    d = np.array([[0, 0, -1.0], [-1.0, 0, 0], [0, -1.0, 0]])
    valid, _, _, uv = hits(box_scene, o, d)
    assert valid.all()
    np.testing.assert_allclose(uv[0], [(0.5 + 1) / 2, (1 + 2) / 4], atol=1e-12)  # (x, y)
    np.testing.assert_allclose(uv[1], [(-1 + 2) / 4, (1.5 + 3) / 6], atol=1e-12)  # +x face: (y, z)
    np.testing.assert_allclose(uv[2], [(-1.5 + 3) / 6, (-0.5 + 1) / 2], atol=1e-12)  # +y face: (z, x)


def test_euler_matrix_matches_independent_rotation():
    R = np.asarray(S.euler_matrix(jnp.asarray([ROT, [90.0, 0, 0], [0, 0, 90.0]])))
    np.testing.assert_allclose(R[0], rot_np(ROT), atol=1e-12)
    np.testing.assert_allclose(R[1] @ [0, 1.0, 0], [0, 0, 1.0], atol=1e-12)  # x-rotation: y -> z
    np.testing.assert_allclose(R[2] @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)  # z-rotation: x -> y


def test_rotated_box_equals_transforming_the_ray_by_hand():
    lo, hi = LO + SHIFT, HI + SHIFT
    rot = rt.Boxes(jnp.asarray([lo]), jnp.asarray([hi]), jnp.asarray([ROT]), jnp.asarray([0]))
    aa = rt.Boxes(jnp.asarray([lo]), jnp.asarray([hi]), jnp.zeros((1, 3), F64), jnp.asarray([0]))
    R = rot_np(ROT)
    rng = np.random.default_rng(7)
    o = SHIFT + 8 * rng_dirs(rng, 64)
    d = SHIFT + rng.uniform(-3, 3, (64, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_rot = kernel_t(S.box_t, S.box_soa(rot), o, d)[:, 0]
    # world -> box frame: p' = c + R^T (p - c)
    o_l = SHIFT + (o - SHIFT) @ R
    d_l = d @ R
    t_aa = kernel_t(S.box_t, S.box_soa(aa), o_l, d_l)[:, 0]
    t_ref, _ = box_ref(o_l, d_l, lo, hi)
    assert 10 < np.isfinite(t_ref).sum() < 60
    np.testing.assert_array_equal(np.isfinite(t_rot), np.isfinite(t_ref))
    ok = np.isfinite(t_ref)
    np.testing.assert_allclose(t_rot[ok], t_ref[ok], rtol=1e-10)
    np.testing.assert_allclose(t_aa[ok], t_ref[ok], rtol=1e-10)


@pytest.mark.parametrize("rotation", [(0.0, 0.0, 0.0), tuple(ROT)])
def test_cube_mesh_of_12_triangles_matches_box(rotation):
    lo, hi = LO + SHIFT, HI + SHIFT
    R = rot_np(np.asarray(rotation))
    v, f = cube_mesh(lo, hi, R)
    b1 = builder()
    b1.box(lo, hi, "m", rotation=rotation)
    b2 = builder()
    b2.mesh(v, f, "m")
    sb, sm = b1.build(F64), b2.build(F64)
    rng = np.random.default_rng(8)
    o = SHIFT + 9 * rng_dirs(rng, 96)
    o[:16] = SHIFT + rng.uniform(-0.8, 0.8, (16, 3))  # from inside: far face, outward normal
    d = SHIFT + rng.uniform(-3, 3, (96, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    vb, tb, nb, _ = hits(sb, o, d)
    vm, tm, nm, _ = hits(sm, o, d)
    assert vb[:16].all() and 20 < vb.sum() < 90
    np.testing.assert_array_equal(vb, vm)
    np.testing.assert_allclose(tb[vb], tm[vb], rtol=1e-9)
    np.testing.assert_allclose(nb[vb], nm[vb], atol=1e-9)
    # normals are the rotated axis normals, outward
    np.testing.assert_allclose(np.abs(nb[vb] @ R).max(1), 1.0, atol=1e-9)
    inside = np.zeros(96, bool)
    inside[:16] = True
    dn = (nb * d).sum(1)
    assert np.all(dn[inside] > 0) and np.all(dn[vb & ~inside] < 0)


def test_mesh_faces_index_vertices():
    v, f = cube_mesh(LO, HI)
    m = rt.Mesh(jnp.asarray(v), jnp.asarray(f), jnp.asarray(0, jnp.int32))
    tris, mats = m.triangles()
    np.testing.assert_array_equal(np.asarray(tris), v[f])
    assert mats.shape == (12,)
