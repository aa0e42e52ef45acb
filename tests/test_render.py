"""End-to-end renders: the unroll depth semantics with mirrors (against a numpy
reference), the branch budget chosen by the builder, and a small scene with every
primitive kind and texture (finite, conventions, feature pixels)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import camera_rays_np, ray_sphere_np

import raytrax as rt

F64 = jnp.float64

# ============================================================================
# depth semantics: a mirror facing a diffuse wall and a second mirror
# (the wall's geometric normal points away from the rays that reach it: diffuse
# surfaces are two-sided, so it is lit from the viewer's side all the same)
# ============================================================================

MI_CAM = dict(position=(0.0, 0.0, 5.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=30.0)
MI_W = MI_H = 9
MI_BG = np.array([0.1, 0.2, 0.3])
MI_R1 = np.array([0.9, 0.6, 0.3])  # mirror at z = 0, seen by the camera
MI_R2 = np.array([0.5, 0.4, 0.25])  # mirror at z = 10 (x > 0.5), behind the camera
MI_ALB = np.array([0.5, 0.8, 0.7])  # diffuse wall at z = 10 (x < 0.5), behind the camera
MI_LIGHT = np.array([0.0, 0.0, 8.0])
MI_I = np.array([8.0, 8.0, 8.0])


def _square(x0, x1, y0, y1, z):
    return [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]


@pytest.fixture(scope="module")
def mirror_scene():
    b = rt.SceneBuilder("physical", width=MI_W, height=MI_H, spp=1, max_depth=1, background=MI_BG)
    b.camera(**MI_CAM)
    b.light(MI_LIGHT, intensity=MI_I)
    b.material("mirror1", color=(0.0, 0.0, 0.0), reflectivity=MI_R1)
    b.material("mirror2", color=(0.0, 0.0, 0.0), reflectivity=MI_R2)
    b.material("wall", color=MI_ALB)
    b.quad(_square(-1.0, 1.0, -1.0, 1.0, 0.0), "mirror1")
    b.quad(_square(-6.0, 0.5, -6.0, 6.0, 10.0), "wall")
    b.quad(_square(0.5, 6.0, -6.0, 6.0, 10.0), "mirror2")
    return b.build(F64)


@pytest.fixture(scope="module")
def mirror_images(mirror_scene):
    return {k: np.asarray(rt.render(mirror_scene, max_depth=k)) for k in (0, 1)}


def mirror_reference(max_depth):
    o = np.asarray(MI_CAM["position"])
    d = camera_rays_np(o, MI_CAM["look_at"], MI_CAM["up"], MI_CAM["fov"], MI_W, MI_H)
    p = o + (o[2] / -d[:, 2])[:, None] * d
    on_mirror = np.all(np.abs(p[:, :2]) < 1.0, axis=1)
    ambiguous = np.any(np.abs(np.abs(p[:, :2]) - 1.0) < 1e-3, axis=1)
    r = d * [1.0, 1.0, -1.0]
    q = p + (10.0 / r[:, 2])[:, None] * r  # where the reflected ray meets z = 10
    wall = q[:, 0] < 0.5
    ambiguous |= np.abs(q[:, 0] - 0.5) < 1e-3
    Lv = MI_LIGHT - q
    dist = np.linalg.norm(Lv, axis=1)
    L_wall = MI_ALB / math.pi * MI_I * (2.0 / dist**3)[:, None]  # cos = 2 / dist, I cos / r^2
    if max_depth == 0:
        seen = np.tile(MI_BG, (len(d), 1))  # the reflected ray takes the background
    else:
        seen = np.where(wall[:, None], L_wall, MI_R2 * MI_BG)  # one more specular hit: background
    img = np.where(on_mirror[:, None], MI_R1 * seen, MI_BG)
    return (
        img.reshape(MI_H, MI_W, 3),
        ~ambiguous.reshape(MI_H, MI_W),
        on_mirror.reshape(MI_H, MI_W),
        wall.reshape(MI_H, MI_W),
    )


def test_mirror_scene_uses_one_branch(mirror_scene):
    assert mirror_scene.settings.branches == 1


def test_builder_branches_two_only_with_a_transparent_material():
    def build(transparency):
        b = rt.SceneBuilder("physical")
        b.material("a", reflectivity=0.5)
        b.material("b", transparency=transparency, ior=1.5)
        b.sphere((0.0, 0.0, -3.0), 1.0, "a")
        return b.build()

    assert build(0.0).settings.branches == 1
    assert build(0.3).settings.branches == 2


def test_max_depth_0_mirror_shows_background(mirror_images):
    ref, ok, on_mirror, _ = mirror_reference(0)
    assert on_mirror.sum() >= 16 and (~on_mirror).sum() >= 16
    img = mirror_images[0]
    np.testing.assert_allclose(img[ok], ref[ok], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(img[MI_H // 2, MI_W // 2], MI_R1 * MI_BG, rtol=1e-9)


def test_max_depth_1_mirror_shows_the_diffuse_wall_it_faces(mirror_images):
    ref, ok, on_mirror, wall = mirror_reference(1)
    img = mirror_images[1]
    assert (on_mirror & wall & ok).sum() >= 8 and (on_mirror & ~wall & ok).sum() >= 8
    # rtol: shadow rays start ~1e-3 off the wall (the integrator's relative offset)
    np.testing.assert_allclose(img[ok], ref[ok], rtol=2e-3, atol=1e-12)
    # centre pixel by hand: reflected straight back to (0, 0, 10), 2 units from the light
    np.testing.assert_allclose(img[MI_H // 2, MI_W // 2], MI_R1 * MI_ALB / math.pi * MI_I / 4.0, rtol=2e-3)
    # the second mirror is one specular hit too many: background through two mirrors
    sel = on_mirror & ~wall & ok
    np.testing.assert_allclose(img[sel], np.broadcast_to(MI_R1 * MI_R2 * MI_BG, (sel.sum(), 3)), rtol=1e-9)


def test_deeper_unroll_changes_only_mirror_pixels(mirror_images):
    _, _, on_mirror, _ = mirror_reference(1)
    diff = np.abs(mirror_images[1] - mirror_images[0]).max(-1)
    assert np.all(diff[~on_mirror] == 0)
    assert np.all(diff[on_mirror] > 0)


# ============================================================================
# every primitive kind in one small classic scene
# ============================================================================

E_W, E_H = 63, 47  # odd: the centre pixel looks at the plain sphere's centre
E_CAM = dict(position=(0.0, 4.0, 16.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), fov=40.0)
E_BG = np.array([0.1, 0.2, 0.4])
E_AMB = np.array([0.2, 0.2, 0.2])
E_LIGHTS = [((10.0, 20.0, 10.0), (0.6, 0.6, 0.6)), ((-10.0, 20.0, 10.0), (0.4, 0.4, 0.4))]
E_RED = dict(color=(0.8, 0.2, 0.2), ambient=1.0, diffuse=1.0, specular=0.5, shininess=20.0)


def _texture_image():
    rng = np.random.default_rng(0)
    return rng.uniform(0.2, 1.0, size=(8, 16, 3)).astype(np.float32)


@pytest.fixture(scope="module")
def every_kind_scene():
    b = rt.SceneBuilder("classic", width=E_W, height=E_H, spp=1, max_depth=3, background=E_BG, ambient=E_AMB)
    b.camera(**E_CAM)
    for p, i in E_LIGHTS:
        b.light(p, intensity=i)
    b.material("floor", color=(0.9, 0.9, 0.9), texture=rt.Checker(color2=(0.1, 0.1, 0.1), scale=1.0))
    b.material("red", **E_RED)
    b.material("stripes", color=(0.1, 0.8, 0.1), texture=rt.Stripes(color2=(0.0, 0.0, 0.0), scale=8.0))
    b.material("planet", color=(1.0, 1.0, 1.0), texture=rt.ImageTexture(_texture_image()))
    b.material("mirror", color=(0.05, 0.05, 0.08), reflectivity=0.8, specular=0.3)
    b.material("glass", color=(0.9, 0.9, 1.0), transparency=0.8, ior=1.5, specular=0.5)
    b.material("blue", color=(0.2, 0.3, 0.9))
    b.material("yellow", color=(0.9, 0.8, 0.1))
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere((0.0, 1.0, 0.0), 1.0, "red")
    b.sphere((-3.5, 1.0, -1.0), 1.0, "stripes")
    b.sphere((3.5, 1.0, -1.0), 1.0, "planet")
    b.sphere((-2.0, 2.5, -7.0), 2.5, "mirror")
    b.sphere((2.0, 0.8, 3.0), 0.8, "glass")
    b.box((4.0, 0.0, -7.0), (6.0, 2.0, -5.0), "blue", rotation=(0.0, 30.0, 0.0))
    b.tetrahedron((-5.5, 0.8, 2.0), 1.6, "yellow")
    b.triangle([(5.0, 0.0, 2.0), (7.0, 0.0, 2.0), (6.0, 2.0, 1.0)], "yellow")
    b.quad([(-8.0, 0.0, -4.0), (-6.0, 0.0, -4.0), (-6.0, 3.0, -4.0), (-8.0, 3.0, -4.0)], "blue")
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 1.2 + [1.0, 0.0, -3.5]
    b.mesh(v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], "blue")
    return b.build()


@pytest.fixture(scope="module")
def every_kind_image(every_kind_scene):
    return np.asarray(rt.render(every_kind_scene))


def test_every_kind_scene_structure(every_kind_scene):
    kinds = {k for k, _ in every_kind_scene.object_index}
    assert kinds == {"sphere", "plane", "quad", "triangle", "tetrahedron", "box", "mesh"}
    assert every_kind_scene.settings.branches == 2


def test_every_kind_render_is_finite_float32_and_nonnegative(every_kind_image):
    img = every_kind_image
    assert img.shape == (E_H, E_W, 3) and img.dtype == np.float32
    assert np.all(np.isfinite(img)) and img.min() >= 0.0
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 200  # a real picture, not a constant


def test_every_kind_background_pixels(every_kind_image):
    # top row: rays point above everything in the scene
    o = np.asarray(E_CAM["position"])
    d = camera_rays_np(o, E_CAM["look_at"], E_CAM["up"], E_CAM["fov"], E_W, E_H)
    assert np.all(d[:E_W, 1] > 0.05)
    top = every_kind_image[0]
    np.testing.assert_array_equal(top, np.broadcast_to(E_BG.astype(np.float32), top.shape))


def test_every_kind_plain_sphere_centre_pixel(every_kind_image):
    """Classic shading by hand at the point of the red sphere facing the camera."""
    o = np.asarray(E_CAM["position"])
    c = np.array([0.0, 1.0, 0.0])
    v = (o - c) / np.linalg.norm(o - c)
    p = c + v  # hit point; normal n = v
    C = np.array(E_RED["color"])
    want = E_AMB * E_RED["ambient"] * C
    for lp, I in E_LIGHTS:
        l = (np.asarray(lp) - p) / np.linalg.norm(np.asarray(lp) - p)
        ndl = v @ l
        r = -l + 2 * ndl * v
        want = want + np.asarray(I) * (
            E_RED["diffuse"] * C * max(ndl, 0) + E_RED["specular"] * max(r @ v, 0) ** E_RED["shininess"]
        )
    np.testing.assert_allclose(every_kind_image[E_H // 2, E_W // 2], want, rtol=1e-3)


def test_every_kind_checker_floor_and_textures(every_kind_image):
    lum = every_kind_image.mean(-1)
    bottom = lum[-3:]  # floor right in front of the camera
    assert bottom.max() > 3 * bottom.min()  # light and dark checker cells
    # striped sphere: along its vertical centre line, alternating green and black bands
    o = np.asarray(E_CAM["position"])
    d = camera_rays_np(o, E_CAM["look_at"], E_CAM["up"], E_CAM["fov"], E_W, E_H)
    hits = np.isfinite(ray_sphere_np(o, d, np.array([-3.5, 1.0, -1.0]), 1.0)).reshape(E_H, E_W)
    col = np.argmax(hits.sum(0))
    g = every_kind_image[hits[:, col], col, 1]
    assert g.max() > 2 * g.min() + 0.05
    # image-textured sphere: not a flat colour
    hits = np.isfinite(ray_sphere_np(o, d, np.array([3.5, 1.0, -1.0]), 1.0)).reshape(E_H, E_W)
    assert hits.sum() > 10
    px = every_kind_image[hits]
    assert np.std(px[:, 0] / np.maximum(px.mean(-1), 1e-6)) > 0.02


def test_every_kind_mirror_sphere_reflects(every_kind_image):
    """Pixels of the dark mirror sphere are far brighter than its own dark colour
    would make them: they show the scene (0.8 x traced colour)."""
    o = np.asarray(E_CAM["position"])
    d = camera_rays_np(o, E_CAM["look_at"], E_CAM["up"], E_CAM["fov"], E_W, E_H)
    t = ray_sphere_np(o, d, np.array([-2.0, 2.5, -7.0]), 2.5)
    hits = np.isfinite(t).reshape(E_H, E_W)
    # the upper part of the mirror reflects the sky: 0.8 x background (+ its own dim local term)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    n = (p - [-2.0, 2.5, -7.0]) / 2.5
    r = d - 2 * (d * n).sum(1, keepdims=True) * n
    sky = (hits.ravel() & (r[:, 1] > 0.5)).reshape(E_H, E_W)
    assert sky.sum() >= 5
    px = every_kind_image[sky]
    assert np.all(px[:, 2] > 0.8 * E_BG[2] - 1e-6)  # at least the reflected sky's blue
    assert np.all(px[:, 2] > px[:, 0])  # blueish like the sky


def test_a_scene_that_never_reflects_or_refracts_renders_as_depth_0():
    """Every transparency and reflectivity a concrete zero: ``render`` compiles the
    depth-0 program (camera hits only) whatever ``max_depth`` says. Against the full
    depth loop (the same scene passed into a ``jax.jit``, where the materials are traced
    and nothing is assumed of them): the same image, and the same gradient with respect
    to the light and the sphere."""
    import jax

    from raytrax.materials import never_specular

    b = rt.SceneBuilder("physical", width=8, height=6, spp=4, max_depth=3, background=(0.2, 0.3, 0.4))
    b.camera(position=(0, 1, 5), look_at=(0, 0.4, 0), fov=45)
    b.light((2, 4, 3), intensity=(20, 20, 20))
    b.material("floor", (0.7, 0.6, 0.5))
    b.material("ball", (0.2, 0.4, 0.8))
    b.plane((0, 0, 0), (0, 1, 0), "floor")
    b.sphere((0.2, 0.6, 0), 0.6, "ball")
    s = b.build(jnp.float64)
    assert never_specular(s.materials)
    assert not never_specular(rt.with_parameters(s, {"material.ball.reflectivity": jnp.full(3, 0.5)}).materials)
    assert not jax.jit(lambda s: jnp.asarray(never_specular(s.materials)))(s)  # traced: nothing assumed
    full = jax.jit(rt.render)  # the scene is an argument: its materials are traced, the depth loop compiled
    np.testing.assert_allclose(np.asarray(rt.render(s)), np.asarray(full(s)), rtol=1e-12, atol=1e-14)
    p = rt.parameters(s)
    q0 = {k: p[k] for k in ("light[0].position", "object[1].center")}

    def loss(q, s, render):
        return jnp.mean(render(rt.with_parameters(s, q)) ** 2)

    g_short = jax.grad(lambda q: loss(q, s, rt.render))(q0)
    g_full = jax.jit(jax.grad(lambda q, s: loss(q, s, rt.render)))(q0, s)
    for k in q0:
        assert np.all(np.asarray(g_short[k]) != 0), k
        np.testing.assert_allclose(np.asarray(g_short[k]), np.asarray(g_full[k]), rtol=1e-10, atol=1e-14, err_msg=k)
