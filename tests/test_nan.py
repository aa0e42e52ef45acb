"""No NaN, no inf: every pixel and every gradient finite in degenerate configurations.

Each test sets scene parameters (through :func:`raytrax.with_parameters`, which
also lets us build geometry the builder rejects: zero-area triangles, zero
normals, inverted boxes) to one nasty case and checks that the image and the
reverse-mode gradient of a weighted image sum with respect to *every* named
parameter are finite. The property tests at the end do the same for random
parameters (hypothesis). Forward mode in degenerate cases is checked in
tests/test_gradients.py (``test_forward_mode_in_degenerate_cases``), which has the
forward-mode program compiled already.

The scenes are those of tests/test_gradients.py (every primitive kind, every
texture kind, glass, a mirror, two lights; one per shading model) in float32,
the precision users render in: one compiled program per shading model serves
every case here (a different structure would cost a compilation per test).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_gradients import BOX, FLOOR, GLASS, MESH, MIRROR, PLANET, QUAD, TETRA, TRI, WALL, H, W, scene_g

import raytrax as rt
from raytrax.camera import primary_rays

DT = jnp.float32
WEIGHTS = np.random.default_rng(7).uniform(0.5, 1.5, (H, W, 3))
BOTH = ["classic", "physical"]


@functools.cache
def _fns(which):
    s = scene_g(which).astype(DT)
    w = jnp.asarray(WEIGHTS, DT)

    def img(q):
        return rt.render(rt.with_parameters(s, q))

    def image_and_grad(q):
        """The image and the gradient of ``mean(image * w)``: one forward pass (the
        image comes with the gradient's, no forward-only program is compiled)."""
        im, vjp = jax.vjp(img, q)
        return im, vjp(w / w.size)[0]

    return s, rt.parameters(s), image_and_grad


def scene(which):
    return _fns(which)[0]


def full(which, overrides):
    """The scene's full parameter dict with ``overrides`` applied (as arrays of the
    parameter's shape, so every call differentiates the same dict structure)."""
    p = _fns(which)[1]
    q = dict(p)
    for k, v in overrides.items():
        assert k in p, k
        q[k] = jnp.broadcast_to(jnp.asarray(v, DT), p[k].shape)
    return q


def check_finite(which, overrides):
    """Render and differentiate; fail with the offending pixels / parameter names."""
    q = full(which, overrides)
    im, g = _fns(which)[2](q)
    im = np.asarray(im)
    bad_px = np.argwhere(~np.isfinite(im).all(-1))
    assert bad_px.size == 0, f"{which} {overrides}: non-finite pixels (row, col) {bad_px.tolist()[:10]}"
    bad_g = [k for k, v in g.items() if not np.all(np.isfinite(np.asarray(v)))]
    assert not bad_g, f"{which} {overrides}: non-finite gradient of {bad_g}"
    return im, g


def pixel_ray(which, row, col, camera_overrides=None):
    """Origin and unit direction (float64 NumPy) of the centre ray of pixel (row, col)."""
    s = scene_g(which)
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


@pytest.mark.parametrize("which", BOTH)
def test_rays_that_miss_everything(which):
    # Looking up and back: away from every object (the wall leans back, the floor is below).
    im, _ = check_finite(which, {"camera.position": (0.0, 0.3, 5.0), "camera.look_at": (0.0, 10.0, 8.0)})
    bg = np.asarray(_fns(which)[1]["render.background"])
    np.testing.assert_allclose(im, np.broadcast_to(bg, im.shape))


@pytest.mark.parametrize("which", BOTH)
def test_ray_lying_in_a_plane(which):
    # The floor plane passes through the camera and contains the ray of pixel (6, 7):
    # its intersection is 0/0; the rays around it hit the plane from both sides.
    o, d = pixel_ray(which, 6, 7)
    n = unit(np.cross(d, [0.3, 1.0, 0.2]))
    check_finite(which, {f"object[{FLOOR}].point": o, f"object[{FLOOR}].normal": n})


@pytest.mark.parametrize("which", BOTH)
def test_ray_tangent_to_a_sphere(which):
    # Rays exactly at the silhouettes of the mirror and the glass sphere.
    o, d = pixel_ray(which, 4, 11)
    e = unit(np.cross(d, [0.0, 1.0, 0.0]))
    o2, d2 = pixel_ray(which, 7, 4)
    e2 = unit(np.cross(d2, [0.2, 1.0, 0.0]))
    check_finite(
        which,
        {
            f"object[{MIRROR}].center": o + 3.0 * d + 0.7 * e,
            f"object[{MIRROR}].radius": 0.7,
            f"object[{GLASS}].center": o2 + 3.0 * d2 + 0.5 * e2,
            f"object[{GLASS}].radius": 0.5,
        },
    )


@pytest.mark.parametrize("which", BOTH)
def test_rays_through_vertices_edges_and_corners(which):
    # Triangle: vertex 0 on one ray; the mesh: an edge along another ray (an edge-on face);
    # the (axis-aligned) box: a corner exactly on a third ray.
    o, d = pixel_ray(which, 3, 5)
    q = o + 3.0 * d
    o2, d2 = pixel_ray(which, 9, 10)
    q2 = o2 + 3.0 * d2
    o3, d3 = pixel_ray(which, 2, 2)
    c = o3 + 3.0 * d3
    check_finite(
        which,
        {
            f"object[{TRI}].vertices": np.array([q, q + [1.0, 0.0, 0.0], q + [0.0, 1.0, 0.0]]),
            f"object[{MESH}].vertices": np.array([q2, q2 + 1.5 * d2, q2 + [0.0, 1.0, 0.0], q2 + [1.0, 0.0, 0.3]]),
            f"object[{BOX}].min": c - 0.5,
            f"object[{BOX}].max": c,
            f"object[{BOX}].rotation": 0.0,
        },
    )


@pytest.mark.parametrize("which", BOTH)
def test_ray_inside_a_box_face(which):
    # Rotate the box about y so that two faces are parallel to the ray of pixel (5, 9), and
    # shift it so that the ray lies in one of those faces.
    o, d = pixel_ray(which, 5, 9)
    theta = np.arctan2(d[0], d[2])  # the local x axis (cos t, 0, -sin t) is perpendicular to d
    ax = np.array([np.cos(theta), 0.0, -np.sin(theta)])
    h = 0.4
    c = o + 3.0 * d - h * ax  # the face x_local = +h contains the ray
    check_finite(
        which,
        {
            f"object[{BOX}].min": c - h,
            f"object[{BOX}].max": c + h,
            f"object[{BOX}].rotation": (0.0, np.degrees(theta), 0.0),
        },
    )


# ---------------------------------------------------------------------------
# Refraction: total internal reflection, the critical angle, ior = 1.
# ---------------------------------------------------------------------------


def _inside_glass(which):
    """Camera inside the glass sphere, looking sideways: rays meet the surface from
    inside at every angle up to grazing."""
    c = np.asarray(scene_g(which).spheres.center[0])  # the glass sphere is the first sphere
    return c, {"camera.position": c + [0.0, 0.1, 0.75], "camera.look_at": c + [3.0, 0.3, 0.75]}


@pytest.mark.parametrize("which", BOTH)
def test_total_internal_reflection(which):
    _, cam = _inside_glass(which)
    check_finite(which, {**cam, "material.glass.ior": 2.4})


@pytest.mark.parametrize("which", BOTH)
def test_critical_angle_from_inside_a_sphere(which):
    c, cam = _inside_glass(which)
    o, d = pixel_ray(which, 3, 6, cam)
    oc = o - c
    b = d @ oc
    t = -b + np.sqrt(b * b - (oc @ oc - 0.9**2))
    n = (o + t * d - c) / 0.9
    ior = 1.0 / np.linalg.norm(np.cross(d, n))  # exactly critical for this ray
    assert 1.0 < ior < 3.0
    check_finite(which, {**cam, "material.glass.ior": ior})


@pytest.mark.parametrize("which", BOTH)
def test_critical_angle_in_a_glass_box(which):
    # A glass box entered through its top face; the refracted ray meets the back face
    # (normal -z) at exactly the critical angle when ior = sqrt(1 + d_z^2); ior 2: TIR.
    o, d = pixel_ray(which, 10, 8)
    y_top = -0.5
    q = o + (y_top - o[1]) / d[1] * d
    box = {
        f"object[{BOX}].min": [q[0] - 1.0, y_top - 3.0, q[2] - 0.3],
        f"object[{BOX}].max": [q[0] + 1.0, y_top, q[2] + 1.0],
        f"object[{BOX}].rotation": 0.0,
        "material.red.transparency": 1.0,
        "material.red.reflectivity": 0.0,
    }
    check_finite(which, {**box, "material.red.ior": np.sqrt(1.0 + d[2] ** 2)})
    check_finite(which, {**box, "material.red.ior": 2.0})


@pytest.mark.parametrize("which", BOTH)
def test_ior_one_and_pure_materials(which):
    # ior = 1 (no bending, F = 0), a fully transparent and a fully reflective material,
    # shininess 0.
    check_finite(
        which,
        {
            "material.glass.ior": 1.0,
            "material.glass.transparency": 1.0,
            "material.glass.reflectivity": 0.0,
            "material.mirror.reflectivity": 1.0,
            "material.mirror.shininess": 0.0,
            "material.planet.shininess": 0.0,
        },
    )


# ---------------------------------------------------------------------------
# Lights.
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("which", BOTH)
def test_zero_intensity_lights(which):
    _, g = check_finite(which, {"light[0].intensity": 0.0, "light[1].intensity": 0.0})
    assert np.all(np.asarray(g["light[0].position"]) == 0.0)


@pytest.mark.parametrize("which", BOTH)
def test_light_inside_objects_and_on_surfaces(which):
    s = scene(which)
    glass_c, mirror_c = np.asarray(s.spheres.center[0]), np.asarray(s.spheres.center[1])
    box_c = 0.5 * (np.asarray(s.boxes.lo[0]) + np.asarray(s.boxes.hi[0]))
    check_finite(which, {"light[0].position": glass_c, "light[1].position": mirror_c})
    check_finite(which, {"light[0].position": box_c, "light[1].position": np.asarray(s.tetrahedra.center[0])})
    # Exactly on the glass sphere's surface and on the floor plane.
    check_finite(which, {"light[0].position": glass_c + [0.0, 0.9, 0.0], "light[1].position": (0.5, -1.2, 0.3)})


# ---------------------------------------------------------------------------
# Degenerate geometry and zero vectors.
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("which", BOTH)
def test_degenerate_triangles_quads_boxes_tetrahedra(which):
    v = np.asarray(_fns(which)[1][f"object[{TRI}].vertices"], np.float64)
    cases = [
        {f"object[{TRI}].vertices": np.repeat(v[:1], 3, 0)},  # a point
        {f"object[{TRI}].vertices": np.array([v[0], v[1], 2 * v[1] - v[0]])},  # collinear
        {f"object[{MESH}].vertices": np.zeros((4, 3))},  # every face a point
        {f"object[{QUAD}].corners": np.zeros((4, 3))},  # zero quad
        {f"object[{QUAD}].corners": np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]])},  # a segment
        {f"object[{QUAD}].corners": np.array([[-1, -1, 0], [1, -1, 0.5], [1, 1, 0], [-1, 1, 0.5]])},  # not planar
        {f"object[{TETRA}].size": 0.0},
        {f"object[{BOX}].min": (0.0, 0.0, 0.0), f"object[{BOX}].max": (0.0, 0.0, 0.0)},  # a point
        {f"object[{BOX}].min": (0.5, -1.0, -1.0), f"object[{BOX}].max": (-0.5, 0.0, 0.0)},  # inverted
    ]
    for case in cases:
        check_finite(which, case)


@pytest.mark.parametrize("which", BOTH)
def test_zero_vectors_and_degenerate_spheres(which):
    check_finite(
        which,
        {
            f"object[{WALL}].normal": 0.0,
            f"object[{FLOOR}].normal": 0.0,
            f"object[{GLASS}].radius": 0.0,
            f"object[{MIRROR}].radius": -0.5,
        },
    )
    # Stripes with a zero direction, texture scale 0, an all-zero image.
    check_finite(
        which,
        {
            "material.floor.texture.direction": 0.0,
            "material.wall.texture.scale": 0.0,
            "material.planet.texture.image": np.zeros((4, 4, 3)),
        },
    )


@pytest.mark.parametrize("which", BOTH)
def test_degenerate_cameras(which):
    cases = [
        {"camera.up": 0.0},  # zero up vector
        {"camera.up": (0.0, -0.3, -5.0)},  # up parallel to the view
        {"camera.look_at": (0.0, 0.3, 5.0), "camera.position": (0.0, 0.3, 5.0)},  # every ray direction zero
        {"camera.fov": 1e-3},
        {"camera.fov": 179.0},
    ]
    for case in cases:
        check_finite(which, case)


# ---------------------------------------------------------------------------
# Property tests: random parameters of the same scenes.
# ---------------------------------------------------------------------------

PROPS = settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def num(lo, hi, special=()):
    s = st.floats(lo, hi, allow_nan=False, allow_infinity=False, width=32)
    return st.one_of(st.sampled_from(list(special)), s) if special else s


def vec(lo, hi, n=3, special=()):
    return st.lists(num(lo, hi, special), min_size=n, max_size=n)


def random_params(shading):
    big = 50.0 if shading == "physical" else 1.5
    return st.fixed_dictionaries(
        {},
        optional={
            "camera.position": vec(-5, 5),
            "camera.look_at": vec(-2, 2),
            "camera.fov": num(1, 170),
            "light[0].position": vec(-4, 4, special=(0.0,)),
            "light[1].position": vec(-4, 4, special=(0.0,)),
            "light[0].intensity": vec(0, big, special=(0.0,)),
            "material.glass.ior": num(1, 3, special=(1.0,)),
            "material.glass.transparency": num(0, 1, special=(0.0, 1.0)),
            "material.mirror.reflectivity": vec(0, 1, special=(0.0, 1.0)),
            "material.red.transparency": num(0, 1, special=(0.0, 1.0)),
            "material.red.ior": num(1, 3, special=(1.0,)),
            "material.planet.shininess": num(0, 100, special=(0.0,)),
            "material.wall.texture.scale": num(0, 10, special=(0.0,)),
            f"object[{GLASS}].center": vec(-2, 2),
            f"object[{GLASS}].radius": num(0, 2, special=(0.0,)),
            f"object[{MIRROR}].center": vec(-2, 2),
            f"object[{PLANET}].radius": num(0, 2, special=(0.0,)),
            f"object[{FLOOR}].normal": vec(-1, 1, special=(0.0,)),
            f"object[{BOX}].min": vec(-2, 1, special=(0.0,)),
            f"object[{BOX}].max": vec(-1, 2, special=(0.0,)),
            f"object[{BOX}].rotation": vec(-180, 180, special=(0.0, 90.0)),
            f"object[{TETRA}].center": vec(-2, 2),
            f"object[{TETRA}].size": num(0, 2, special=(0.0,)),
            f"object[{TRI}].vertices": st.lists(vec(-2, 2, special=(0.0,)), min_size=3, max_size=3),
            f"object[{QUAD}].corners": st.lists(vec(-2, 2, special=(0.0,)), min_size=4, max_size=4),
            f"object[{MESH}].vertices": st.lists(vec(-2, 2, special=(0.0,)), min_size=4, max_size=4),
        },
    )


@pytest.mark.parametrize("shading", BOTH)
def test_random_scenes_are_finite(shading):
    @PROPS
    @given(random_params(shading))
    def prop(overrides):
        check_finite(shading, overrides)

    prop()
