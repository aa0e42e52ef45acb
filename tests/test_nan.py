"""No NaN, no inf: every pixel and every gradient finite in degenerate configurations.

Each test sets scene parameters (through :func:`raytrax.with_parameters`, which
also lets us build geometry the builder rejects: zero-area triangles, zero
normals, inverted boxes) to one nasty case and checks that the image and the
reverse-mode gradient of a weighted image sum with respect to *every* named
parameter are finite; a few cases check forward mode too. The property tests
at the end do the same for random parameters (hypothesis).

The scenes are the structures of tests/test_gradients.py in float64 (a glass,
a mirror and an image-textured sphere over a checkered and a striped plane in
both shading models; a box, a tetrahedron, a triangle, a quad and a mesh on a
plane in classic shading), so that this file reuses their compiled programs:
a different structure would cost a compilation per test. A float32 test at the
end checks that the same cases stay finite in single precision.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import raytrax as rt
from raytrax.camera import primary_rays
from test_gradients import FLOOR, GLASS, H, MIRROR, PLANET, WALL, W, scene_g, setup_b

# B-scene object indices (see test_gradients.setup_b).
GROUND, BOX, TETRA, TRI, QUAD, MESH = range(6)

WEIGHTS = np.random.default_rng(7).uniform(0.5, 1.5, (H, W, 3))


def scene(which, dtype=jnp.float64):
    s = setup_b()[0] if which == "b" else scene_g(which)
    return s if dtype == jnp.float64 else s.astype(dtype)


@functools.lru_cache(maxsize=None)
def _fns(which, dtype=jnp.float64):
    s = scene(which, dtype)
    w = jnp.asarray(WEIGHTS, dtype)

    def img(q):
        return rt.render(rt.with_parameters(s, q))

    def loss(q):
        return jnp.mean(img(q) * w)

    return s, rt.parameters(s), img, loss, jax.grad(loss)


def full(which, overrides, dtype=jnp.float64):
    """The scene's full parameter dict with ``overrides`` applied (as arrays of the
    parameter's shape, so every call differentiates the same dict structure)."""
    _, p, *_ = _fns(which, dtype)
    q = dict(p)
    for k, v in overrides.items():
        assert k in p, k
        q[k] = jnp.broadcast_to(jnp.asarray(v, dtype), p[k].shape)
    return q


def check_finite(which, overrides, *, forward=False, dtype=jnp.float64):
    """Render and differentiate; fail with the offending pixels / parameter names."""
    s, p, img, loss, grad = _fns(which, dtype)
    q = full(which, overrides, dtype)
    im = np.asarray(img(q))
    bad_px = np.argwhere(~np.isfinite(im).all(-1))
    assert bad_px.size == 0, f"{which} {overrides}: non-finite pixels (row, col) {bad_px.tolist()[:10]}"
    g = grad(q)
    bad_g = [k for k, v in g.items() if not np.all(np.isfinite(np.asarray(v)))]
    assert not bad_g, f"{which} {overrides}: non-finite gradient of {bad_g}"
    if forward:
        _, f_jvp = jax.linearize(loss, q)
        rng = np.random.default_rng(3)
        t = {k: jnp.asarray(rng.normal(size=v.shape), dtype) for k, v in q.items()}
        jv = float(f_jvp(t))
        assert np.isfinite(jv), f"{which} {overrides}: non-finite jvp"
        # Forward and reverse mode agree on the same direction.
        rv = sum(float(jnp.sum(g[k] * t[k])) for k in q)
        assert jv == pytest.approx(rv, rel=1e-6, abs=1e-9 * max(1.0, abs(rv)))
    return im, g


def pixel_ray(which, row, col, camera_overrides=None):
    """Origin and unit direction (float64 NumPy) of the centre ray of pixel (row, col)."""
    s = scene(which)
    if camera_overrides:
        s = rt.with_parameters(s, camera_overrides)
    o, d, _ = primary_rays(s.camera, jnp.asarray([row * W + col]), W, H, 1)
    return np.asarray(o)[:, 0], np.asarray(d)[:, 0]


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------------------
# Rays that miss, graze, touch silhouettes or lie inside a surface.
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["classic", "physical", "b"])
def test_rays_that_miss_everything(which):
    # Looking up and back: away from every object (the wall leans back, the floor is below).
    cam = {"camera.position": (0.0, 0.3, 5.0), "camera.look_at": (0.0, 10.0, 8.0)}
    im, _ = check_finite(which, cam)
    bg = np.asarray(_fns(which)[1]["render.background"])
    np.testing.assert_allclose(im, np.broadcast_to(bg, im.shape))


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_ray_lying_in_a_plane(which):
    # The floor plane passes through the camera and contains the ray of pixel (4, 5):
    # its intersection is 0/0; the rays around it hit the plane from both sides.
    o, d = pixel_ray(which, 4, 5)
    n = unit(np.cross(d, [0.3, 1.0, 0.2]))
    check_finite(which, {f"object[{FLOOR}].point": o, f"object[{FLOOR}].normal": n}, forward=which == "classic")


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_ray_tangent_to_a_sphere(which):
    # A ray exactly at the silhouette of the mirror sphere (and of the glass sphere).
    o, d = pixel_ray(which, 3, 8)
    r = 0.7
    e = unit(np.cross(d, [0.0, 1.0, 0.0]))
    o2, d2 = pixel_ray(which, 5, 3)
    e2 = unit(np.cross(d2, [0.2, 1.0, 0.0]))
    check_finite(which, {f"object[{MIRROR}].center": o + 5.0 * d + r * e, f"object[{MIRROR}].radius": r,
                         f"object[{GLASS}].center": o2 + 4.0 * d2 + 0.9 * e2, f"object[{GLASS}].radius": 0.9},
                 forward=which == "classic")


def test_rays_through_vertices_edges_and_faces_edge_on():
    o, d = pixel_ray("b", 3, 4)
    q = o + 5.0 * d
    o2, d2 = pixel_ray("b", 6, 7)
    q2 = o2 + 6.0 * d2
    # Triangle: vertex 0 on one ray; the mesh: an edge along another ray (edge-on face).
    tri = np.array([q, q + [1.0, 0.0, 0.0], q + [0.0, 1.0, 0.0]])
    mesh = np.array([q2, q2 + 1.5 * d2, q2 + [0.0, 1.0, 0.0], q2 + [1.0, 0.0, 0.3]])
    # Box corner exactly on a third ray (axis-aligned box).
    o3, d3 = pixel_ray("b", 2, 9)
    c = o3 + 5.5 * d3
    check_finite("b", {f"object[{TRI}].vertices": tri, f"object[{MESH}].vertices": mesh,
                       f"object[{BOX}].min": c - 1.0, f"object[{BOX}].max": c,
                       f"object[{BOX}].rotation": (0.0, 0.0, 0.0)})


def test_ray_parallel_to_box_faces():
    # Rotate the box about y so that two faces are parallel to the ray of pixel (4, 6), and
    # shift it so that the ray lies in one of those faces.
    o, d = pixel_ray("b", 4, 6)
    theta = np.arctan2(d[0], d[2])  # local x axis (cos t, 0, -sin t) is perpendicular to d
    ax = np.array([np.cos(theta), 0.0, -np.sin(theta)])
    h = 0.6
    c = o + 5.0 * d - h * ax  # the face x_local = +h contains the ray
    check_finite("b", {f"object[{BOX}].min": c - h, f"object[{BOX}].max": c + h,
                       f"object[{BOX}].rotation": (0.0, np.degrees(theta), 0.0)})


# ---------------------------------------------------------------------------
# Refraction: total internal reflection, the critical angle, ior = 1.
# ---------------------------------------------------------------------------


def _inside_glass(which):
    """Camera inside the glass sphere, looking sideways: rays meet the surface from
    inside at every angle up to grazing."""
    s = scene(which)
    c = np.asarray(s.spheres.center[0])  # the glass sphere is the first sphere
    return c, {"camera.position": c + [0.0, 0.1, 0.75], "camera.look_at": c + [3.0, 0.3, 0.75]}


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_total_internal_reflection(which):
    _, cam = _inside_glass(which)
    check_finite(which, {**cam, "material.glass.ior": 2.4}, forward=which == "classic")


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_critical_angle_from_inside_a_sphere(which):
    c, cam = _inside_glass(which)
    o, d = pixel_ray(which, 2, 4, cam)
    oc = o - c
    b = d @ oc
    t = -b + np.sqrt(b * b - (oc @ oc - 0.9 ** 2))
    n = (o + t * d - c) / 0.9
    sin_i = np.linalg.norm(np.cross(d, n))
    ior = 1.0 / sin_i  # exactly critical for this ray
    assert 1.0 < ior < 3.0
    check_finite(which, {**cam, "material.glass.ior": ior})


def test_critical_angle_in_a_box():
    # A glass box entered through its top face; the refracted ray meets the back face
    # (normal -z) at exactly the critical angle when ior = sqrt(1 + d_z^2).
    o, d = pixel_ray("b", 6, 6)
    y_top = -0.2
    q = o + (y_top - o[1]) / d[1] * d
    lo = np.array([q[0] - 1.0, y_top - 3.0, q[2] - 0.3])
    hi = np.array([q[0] + 1.0, y_top, q[2] + 1.0])
    check_finite("b", {f"object[{BOX}].min": lo, f"object[{BOX}].max": hi, f"object[{BOX}].rotation": 0.0,
                       "material.red.transparency": 1.0, "material.red.ior": np.sqrt(1.0 + d[2] ** 2)})
    check_finite("b", {f"object[{BOX}].min": lo, f"object[{BOX}].max": hi, f"object[{BOX}].rotation": 0.0,
                       "material.red.transparency": 1.0, "material.red.ior": 2.0})  # TIR


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_ior_one_and_pure_materials(which):
    # ior = 1 (no bending, F = 0), a fully transparent and a fully reflective material,
    # shininess 0.
    check_finite(which, {"material.glass.ior": 1.0, "material.glass.transparency": 1.0,
                         "material.glass.reflectivity": 0.0, "material.mirror.reflectivity": 1.0,
                         "material.mirror.shininess": 0.0, "material.planet.shininess": 0.0})


# ---------------------------------------------------------------------------
# Lights.
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["classic", "physical", "b"])
def test_zero_intensity_lights(which):
    im, g = check_finite(which, {"light[0].intensity": 0.0, "light[1].intensity": 0.0})
    assert np.all(np.asarray(g["light[0].position"]) == 0.0)


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_light_inside_objects_and_on_surfaces(which):
    s = scene(which)
    glass_c = np.asarray(s.spheres.center[0])
    mirror_c = np.asarray(s.spheres.center[1])
    check_finite(which, {"light[0].position": glass_c, "light[1].position": mirror_c}, forward=which == "classic")
    # Exactly on the glass sphere's surface and on the floor plane.
    check_finite(which, {"light[0].position": glass_c + [0.0, 0.9, 0.0], "light[1].position": (0.5, -1.2, 0.3)})


def test_light_inside_box_and_tetrahedron():
    s = scene("b")
    box_c = 0.5 * (np.asarray(s.boxes.lo[0]) + np.asarray(s.boxes.hi[0]))
    check_finite("b", {"light[0].position": box_c, "light[1].position": np.asarray(s.tetrahedra.center[0])})


# ---------------------------------------------------------------------------
# Degenerate geometry and zero vectors.
# ---------------------------------------------------------------------------


def test_degenerate_triangles_quads_boxes_tetrahedra():
    p = _fns("b")[1]
    v = np.asarray(p[f"object[{TRI}].vertices"])
    cases = [
        {f"object[{TRI}].vertices": np.repeat(v[:1], 3, 0)},                       # a point
        {f"object[{TRI}].vertices": np.array([v[0], v[1], 2 * v[1] - v[0]])},       # collinear
        {f"object[{MESH}].vertices": np.zeros((4, 3))},                             # every face a point
        {f"object[{QUAD}].corners": np.zeros((4, 3))},                              # zero quad
        {f"object[{QUAD}].corners": np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]])},  # a segment
        {f"object[{QUAD}].corners": np.array([[-1, -1, 0], [1, -1, 0.5], [1, 1, 0], [-1, 1, 0.5]])},  # not planar
        {f"object[{TETRA}].size": 0.0},
        {f"object[{BOX}].min": (0.0, 0.0, 0.0), f"object[{BOX}].max": (0.0, 0.0, 0.0)},        # a point
        {f"object[{BOX}].min": (0.5, -1.0, -1.0), f"object[{BOX}].max": (-0.5, 0.0, 0.0)},     # inverted
        {f"object[{GROUND}].normal": (0.0, 0.0, 0.0)},                              # zero normal
    ]
    for case in cases:
        check_finite("b", case)


@pytest.mark.parametrize("which", ["classic", "physical"])
def test_zero_vectors_and_degenerate_spheres(which):
    check_finite(which, {f"object[{WALL}].normal": 0.0, f"object[{GLASS}].radius": 0.0,
                         f"object[{MIRROR}].radius": -0.5})
    # Stripes with a zero direction, texture scale 0, an all-zero image.
    check_finite(which, {"material.floor.texture.direction": 0.0, "material.wall.texture.scale": 0.0,
                         "material.planet.texture.image": np.zeros((4, 4, 3))})


@pytest.mark.parametrize("which", ["classic", "b"])
def test_degenerate_cameras(which):
    cases = [
        {"camera.up": 0.0},                                                     # zero up vector
        {"camera.up": (0.0, -0.3, -5.0)},                                       # up parallel to the view
        {"camera.look_at": (0.0, 0.3, 5.0), "camera.position": (0.0, 0.3, 5.0)},  # zero view vector
        {"camera.fov": 1e-3},
        {"camera.fov": 179.0},
    ]
    for case in cases:
        check_finite(which, case)


# ---------------------------------------------------------------------------
# Single precision: the same kind of cases in float32 (one more compilation).
# ---------------------------------------------------------------------------


def test_float32_degenerate_cases():
    c, cam = _inside_glass("classic")
    o, d = pixel_ray("classic", 4, 5)
    cases = [
        {},
        {**cam, "material.glass.ior": 2.4},
        {f"object[{FLOOR}].point": o, f"object[{FLOOR}].normal": unit(np.cross(d, [0.3, 1.0, 0.2]))},
        {"light[0].position": c, "light[1].intensity": 0.0, f"object[{WALL}].normal": 0.0},
        {f"object[{GLASS}].radius": 0.0, "camera.up": 0.0, "material.floor.texture.direction": 0.0},
        {"camera.fov": 179.0, "material.glass.ior": 1.0},
    ]
    for case in cases:
        check_finite("classic", case, dtype=jnp.float32)


# ---------------------------------------------------------------------------
# Property tests: random parameters of the same structures.
# ---------------------------------------------------------------------------

PROPS = settings(max_examples=10, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def num(lo, hi, special=()):
    s = st.floats(lo, hi, allow_nan=False, allow_infinity=False, width=32)
    return st.one_of(st.sampled_from(list(special)), s) if special else s


def vec(lo, hi, n=3, special=()):
    return st.lists(num(lo, hi, special), min_size=n, max_size=n)


def g_params(shading):
    big = 50.0 if shading == "physical" else 1.5
    return st.fixed_dictionaries({
        "camera.position": vec(-5, 5),
        "camera.look_at": vec(-2, 2),
        "camera.fov": num(1, 170),
        "light[0].position": vec(-4, 4, special=(0.0,)),
        "light[1].position": vec(-4, 4, special=(0.0,)),
        "light[0].intensity": vec(0, big, special=(0.0,)),
        "material.glass.ior": num(1, 3, special=(1.0,)),
        "material.glass.transparency": num(0, 1, special=(0.0, 1.0)),
        "material.mirror.reflectivity": vec(0, 1, special=(0.0, 1.0)),
        "material.planet.shininess": num(0, 100, special=(0.0,)),
        "material.wall.texture.scale": num(0, 10, special=(0.0,)),
        f"object[{GLASS}].center": vec(-2, 2),
        f"object[{GLASS}].radius": num(0, 2, special=(0.0,)),
        f"object[{MIRROR}].center": vec(-2, 2),
        f"object[{PLANET}].radius": num(0, 2, special=(0.0,)),
        f"object[{FLOOR}].normal": vec(-1, 1, special=(0.0,)),
    })


@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_random_spheres_and_planes_are_finite(shading):
    @PROPS
    @given(g_params(shading))
    def prop(overrides):
        check_finite(shading, overrides)

    prop()


@PROPS
@given(st.fixed_dictionaries({
    "camera.position": vec(-5, 5),
    "light[0].position": vec(-3, 3, special=(0.0,)),
    "light[1].intensity": vec(0, 2, special=(0.0,)),
    "material.red.transparency": num(0, 1, special=(0.0, 1.0)),
    "material.red.ior": num(1, 3, special=(1.0,)),
    f"object[{BOX}].min": vec(-2, 1, special=(0.0,)),
    f"object[{BOX}].max": vec(-1, 2, special=(0.0,)),
    f"object[{BOX}].rotation": vec(-180, 180, special=(0.0, 90.0)),
    f"object[{TETRA}].center": vec(-2, 2),
    f"object[{TETRA}].size": num(0, 2, special=(0.0,)),
    f"object[{TRI}].vertices": st.lists(vec(-2, 2, special=(0.0,)), min_size=3, max_size=3),
    f"object[{QUAD}].corners": st.lists(vec(-2, 2, special=(0.0,)), min_size=4, max_size=4),
    f"object[{MESH}].vertices": st.lists(vec(-2, 2, special=(0.0,)), min_size=4, max_size=4),
}))
def test_random_boxes_tetrahedra_triangles_quads_meshes_are_finite(overrides):
    check_finite("b", overrides)
