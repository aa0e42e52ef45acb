"""Directional lights (``[[light]] type = "directional"``: ``direction``, the way the
light travels, and ``irradiance``).

* known answer: a floor and a sphere under one directional light, against numpy:
  physical ``albedo / pi * E cos`` (no falloff: the same on the whole lit floor),
  classic ``ambient + E diffuse color cos``;
* the hard shadow of the sphere, cast along the direction (numpy ray-sphere tests
  from each floor point towards the light): only ambient (classic) or zero (physical);
* scene files: a directional and a point light round trip in their order, errors
  name the bad key;
* gradients: plain AD w.r.t. the direction and irradiance against central finite
  differences (float64), and edge gradients of the shadow boundary against central
  differences of jittered high-sample renders, where plain AD misses the boundary term.

Compilations: one float32 render per shading model (32 x 24), one float64 render
and one float64 gradient (32 x 24), one small render for the round trip, and at
8 x 6 one edge gradient, one plain gradient and one jittered high-sample render.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import camera_rays_np, jit_grad, ray_sphere_np

import raytrax as rt
from raytrax.testing import check_gradients, jittered_central_differences, smooth_weights

F64 = jnp.float64

W, H = 32, 24
CAM = dict(position=(0.0, 12.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, -1.0), fov=40.0)
DIRECTION = np.array([1.2, -1.0, 0.5])  # not unit length
E = np.array([3.0, 2.5, 2.0])
FLOOR = np.array([0.8, 0.7, 0.6])
BALL = np.array([0.3, 0.6, 0.9])
BALL_C, BALL_R = np.array([-0.5, 1.5, 0.4]), 1.2
DIFFUSE, MAT_AMBIENT = 0.9, 0.5  # classic
AMBIENT = np.array([0.2, 0.3, 0.4])


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@functools.cache
def sun_scene(shading, dtype=jnp.float32):
    """A floor (y = 0) seen from above and a sphere over it, one directional light; the
    camera sees the floor in every pixel but those of the sphere."""
    b = rt.SceneBuilder(shading, width=W, height=H, spp=1, max_depth=0, background=(0.0, 0.0, 0.0), ambient=AMBIENT)
    b.camera(**CAM)
    b.directional_light(DIRECTION, irradiance=E)
    b.material("floor", color=FLOOR, diffuse=DIFFUSE, ambient=MAT_AMBIENT, specular=0.0)
    b.material("ball", color=BALL, diffuse=DIFFUSE, ambient=MAT_AMBIENT, specular=0.0)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere(BALL_C, BALL_R, "ball")
    return b.build(dtype)


def sun_reference(direction=DIRECTION):
    """Numpy float64, pixel-centre rays. Returns the physical image, the classic image
    without ambient, the ambient-only classic image (per unit of ``render.ambient``),
    masks of floor / ball / shadowed floor pixels, and a mask of pixels near a
    silhouette, a shadow boundary or the ball's terminator (not compared)."""
    o = np.asarray(CAM["position"], np.float64)
    d = camera_rays_np(o, CAM["look_at"], CAM["up"], CAM["fov"], W, H)
    O = np.tile(o, (len(d), 1))
    l = _unit(-np.asarray(direction, np.float64))  # towards the light
    L = np.tile(l, (len(d), 1))
    ts = ray_sphere_np(O, d, BALL_C, BALL_R)
    tf = -o[1] / d[:, 1]
    ball = ts < tf
    t = np.where(ball, ts, tf)
    p = o + t[:, None] * d
    n = np.where(ball[:, None], _unit(p - BALL_C), np.array([0.0, 1.0, 0.0]))
    cos = (n * l).sum(1)
    # a floor point is in shadow when its ray towards the light meets the ball
    pf = o + tf[:, None] * d
    shadow = ~ball & np.isfinite(ray_sphere_np(pf, L, BALL_C, BALL_R))
    # about a pixel (0.36 world units on the floor) either side of every edge
    near = np.zeros(len(d), bool)
    for m in (-0.4, 0.4):
        near |= np.isfinite(ray_sphere_np(O, d, BALL_C, BALL_R + m)) != np.isfinite(ray_sphere_np(O, d, BALL_C, BALL_R))
        near |= ~ball & (
            np.isfinite(ray_sphere_np(pf, L, BALL_C, BALL_R + m)) != np.isfinite(ray_sphere_np(pf, L, BALL_C, BALL_R))
        )
    near |= ball & (np.abs(cos) < 0.1)
    albedo = np.where(ball[:, None], BALL, FLOOR)
    lit = np.where(shadow, 0.0, np.maximum(cos, 0.0))[:, None]
    phys = albedo / math.pi * E * lit
    classic = E * DIFFUSE * albedo * lit
    amb = MAT_AMBIENT * albedo
    r = lambda a: a.reshape((H, W) + a.shape[1:])
    return r(phys), r(classic), r(amb), r(~ball), r(ball), r(shadow), r(near)


def _compare(img, ref, floor, ok):
    """Floor pixels to 1e-5 (float32 rounding); ball pixels to 2e-4: in float32 the
    ray-sphere discriminant ``b^2 - c`` (``b^2 ~ 110`` here) loses about 1e-5 of the
    hit point, and the normal with it (a terminator within 0.1 of the light is excluded).
    Measured: at most 8.6e-8 on the floor and 1.7e-5 on the ball."""
    np.testing.assert_allclose(img[floor & ok], ref[floor & ok], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(img[~floor & ok], ref[~floor & ok], rtol=2e-4, atol=1e-7)


@pytest.fixture(scope="module")
def physical_image():
    return np.asarray(rt.render(sun_scene("physical")))


@pytest.fixture(scope="module")
def classic_images():
    s = sun_scene("classic")
    out = {}
    for label, amb in (("no ambient", np.zeros(3)), ("ambient", AMBIENT)):
        out[label] = np.asarray(rt.render(rt.with_parameters(s, {"render.ambient": jnp.asarray(amb, jnp.float32)})))
    return out


def test_physical_floor_and_ball_match_numpy(physical_image):
    phys, _, _, floor, ball, shadow, near = sun_reference()
    ok = ~near
    lit_floor = floor & ~shadow & ok
    assert lit_floor.sum() > 400 and (ball & ok).sum() > 10 and (shadow & ok).sum() > 10
    assert physical_image.dtype == np.float32
    _compare(physical_image, phys, floor, ok)
    # No falloff: the lit floor is one value, albedo / pi * E cos with cos = 1 / |direction|.
    want = FLOOR / math.pi * E / np.linalg.norm(DIRECTION)
    np.testing.assert_allclose(physical_image[lit_floor], np.broadcast_to(want, (lit_floor.sum(), 3)), rtol=1e-6)


def test_physical_shadow_is_black(physical_image):
    _, _, _, floor, _, shadow, near = sun_reference()
    m = shadow & ~near
    np.testing.assert_array_equal(physical_image[m], 0.0)
    # and it is a shadow: the rest of the floor is lit
    lit = floor & ~shadow & ~near
    assert physical_image[lit].sum(-1).min() > 0.1


@pytest.mark.parametrize("label", ["no ambient", "ambient"])
def test_classic_diffuse_and_shadow_match_numpy(classic_images, label):
    _, classic, amb, floor, _, shadow, near = sun_reference()
    img = classic_images[label]
    ok = ~near
    want = classic + (AMBIENT if label == "ambient" else 0.0) * amb
    _compare(img, want, floor, ok)
    # in the shadow only the ambient term is left (zero without ambient light)
    m = shadow & ok
    np.testing.assert_allclose(img[m], want[m], rtol=1e-6, atol=0)
    if label == "no ambient":
        np.testing.assert_array_equal(img[m], 0.0)
    # the lit floor: E diffuse colour cos, the same everywhere (no falloff)
    lit_floor = floor & ~shadow & ok
    cos = 1 / np.linalg.norm(DIRECTION)
    want_floor = E * DIFFUSE * FLOOR * cos + (AMBIENT if label == "ambient" else 0.0) * MAT_AMBIENT * FLOOR
    np.testing.assert_allclose(img[lit_floor], np.broadcast_to(want_floor, (lit_floor.sum(), 3)), rtol=1e-6)


def test_shadow_moves_with_the_direction():
    # The same compiled render with the light coming from the other side: the shadow
    # follows (numpy reference with the new direction).
    d2 = np.array([-1.0, -1.0, -0.6])
    img = np.asarray(
        rt.render(rt.with_parameters(sun_scene("physical"), {"light[0].direction": jnp.asarray(d2, jnp.float32)}))
    )
    phys, _, _, floor, _, shadow, near = sun_reference(d2)
    _, _, _, _, _, shadow0, _ = sun_reference()
    assert (shadow & ~near & ~shadow0).sum() > 5  # a new shadow region
    _compare(img, phys, floor, ~near)


# ---------------------------------------------------------------------------
# Scene files.
# ---------------------------------------------------------------------------


def _two_light_scene():
    b = rt.SceneBuilder("physical", width=8, height=6, spp=1, max_depth=0)
    b.camera(**CAM)
    b.directional_light((0.6, -1.0, 0.3), irradiance=(3.0, 2.5, 2.0))
    b.light((1.0, 4.0, 2.0), intensity=(9.0, 8.0, 7.0))
    b.material("floor", color=FLOOR)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere(BALL_C, BALL_R, "floor")
    return b.build()


def test_save_load_round_trip_keeps_the_light_order(tmp_path):
    s = _two_light_scene()
    p = rt.parameters(s)
    names = [k for k in p if k.startswith("light")]
    assert names == ["light[0].direction", "light[0].irradiance", "light[1].position", "light[1].intensity"]
    path = rt.save_scene(s, tmp_path / "sun.toml")
    text = open(path).read()
    first, second = text.split("[[light]]")[1:3]
    assert 'type = "directional"' in first and "direction" in first and "position" not in first
    assert "position" in second and "directional" not in second
    s2 = rt.load_scene(path)
    p2 = rt.parameters(s2)
    assert list(p2) == list(p)
    for k in p:
        np.testing.assert_array_equal(np.asarray(p2[k]), np.asarray(p[k]), err_msg=k)
    np.testing.assert_array_equal(np.asarray(rt.render(s2)), np.asarray(rt.render(s)))
    # the point light is really there: turning it off darkens the image
    dark = np.asarray(rt.render(rt.with_parameters(s2, {"light[1].intensity": jnp.zeros(3, jnp.float32)})))
    assert dark.sum() < np.asarray(rt.render(s2)).sum()


SUN_TOML = """\
shading = "physical"
[camera]
position = [0.0, 12.0, 0.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 0.0, -1.0]
[render]
width = 8
height = 6
[[light]]
{light}
[material.floor]
color = [0.8, 0.7, 0.6]
[[object]]
type = "plane"
material = "floor"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
"""


@pytest.mark.parametrize(
    "light, where",
    [
        ('type = "directional"\ndirection = [0.0, 0.0, 0.0]', r"light\[0\]\.direction"),
        ('type = "directional"\nirradiance = [1.0, 1.0, 1.0]', r"light\[0\]: missing key 'direction'"),
        ('type = "spot"\ndirection = [0.0, -1.0, 0.0]', r"light\[0\]\.type"),
    ],
    ids=["zero direction", "missing direction", "unknown type"],
)
def test_scene_file_errors_name_the_key(tmp_path, light, where):
    f = tmp_path / "bad.toml"
    f.write_text(SUN_TOML.format(light=light))
    with pytest.raises(rt.SceneError, match=where) as e:
        rt.load_scene(f)
    assert "bad.toml" in str(e.value)
    f.write_text(SUN_TOML.format(light='type = "directional"\ndirection = [0.0, -1.0, 0.0]'))
    np.testing.assert_array_equal(np.asarray(rt.parameters(rt.load_scene(f))["light[0].direction"]), [0.0, -1.0, 0.0])


# ---------------------------------------------------------------------------
# Plain AD against finite differences (float64), away from every edge.
# ---------------------------------------------------------------------------


def test_plain_gradients_of_direction_and_irradiance_match_finite_differences():
    *_, shadow, near = sun_reference()
    w = jnp.asarray(smooth_weights(H, W) * (~near)[..., None])
    s = sun_scene("physical", F64)
    p = rt.parameters(s)
    q = {k: p[k] for k in ("light[0].direction", "light[0].irradiance")}

    def loss(q):
        return jnp.sum(w * rt.render(rt.with_parameters(s, q)))

    rep = check_gradients(loss, q, rtol=1e-4, forward_mode=False)
    print(rep)  # measured: max relative error 1.7e-10
    # The loss is linear in the irradiance, and does not change with the direction's length:
    # its direction gradient is perpendicular to the direction.
    fd = {(r.name, r.index): r.fd for r in rep.rows}
    g_d = np.array([fd["light[0].direction", i] for i in range(3)])
    big = np.abs(g_d).max()
    assert big > 1.0 and abs(g_d @ _unit(DIRECTION)) < 1e-6 * big, rep
    f0 = float(loss(q))
    g_e = np.array([fd["light[0].irradiance", i] for i in range(3)])
    np.testing.assert_allclose(g_e @ E, f0, rtol=1e-8)


# ---------------------------------------------------------------------------
# Edge gradients of the shadow boundary.
# ---------------------------------------------------------------------------

EW, EH = 8, 6
EDGE_SPP = 64
REF_SPP = 4096
REF_KEYS = 32
STEP = 0.04
EDGE_RTOL = 0.05


@functools.cache
def shadow_scene():
    """The floor seen from 10 above, one world unit per pixel (8 x 6 units); a ball
    outside the view casts its shadow (an ellipse about 6.7 x 3 pixels) into it
    under a directional light. Only the shadow edge moves with the parameters. The
    shadow's extreme points in the image (columns 0.65 and 7.35, rows 1.48 and 4.52)
    are 0.35 pixel or more from pixel boundaries (see tests/test_disk.py: with them
    0.05-0.1 pixel from one, references at steps 0.01 and 0.04 were 4 % apart in the
    direction's z)."""
    b = rt.SceneBuilder("physical", width=EW, height=EH, spp=EDGE_SPP, max_depth=0)
    b.camera(
        position=(0.0, 10.0, 0.0),
        look_at=(0.0, 0.0, 0.0),
        up=(0.0, 0.0, -1.0),
        fov=math.degrees(2 * math.atan(EH / 2 / 10)),
    )
    b.directional_light((2.0, -1.0, 0.15), irradiance=(3.0, 2.5, 2.0))
    b.material("floor", color=(0.8, 0.7, 0.6))
    b.material("ball", color=(0.3, 0.3, 0.3))
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere((-6.0, 3.0, -0.45), 1.5, "ball")
    return b.build(F64)


def test_shadow_edge_gradients_match_finite_differences():
    """Parameters: the light's direction and the ball's centre. Reference: central
    differences (step 0.04, the same key on both sides) of jittered spp 4096 renders
    averaged over 32 keys (see tests/test_disk.py); steps 0.01, 0.02 and 0.04 agree
    within their standard errors, at 0.04 0.08, 0.04, 0.4, 0.5, 0.3, 0.7 % of
    (direction x, y, z, centre x, y, z).

    Plain AD gets the floor's ``cos`` term (most of the direction's x and y
    components) but not the moving shadow edge: it is 0 for the ball's centre, has
    the wrong sign for the direction's z (-139 %) and is 10 and 8 % off in x and y.
    Tolerance 5 % of each component (measured at spp 64: -0.4, -0.4, -1.1, +0.9,
    +0.3, +1.6 %), and 10 % for the boundary term alone, edge minus plain against
    reference minus plain (measured -4.6, -5.6, -0.8 % for the direction)."""
    s0 = shadow_scene()
    w = jnp.asarray(smooth_weights(EH, EW))
    p0 = rt.parameters(s0)
    q0 = jnp.concatenate([p0["light[0].direction"], p0["object[1].center"]])

    def loss(q, **kw):
        s = rt.with_parameters(s0, {"light[0].direction": q[:3], "object[1].center": q[3:]})
        return jnp.mean(w * rt.render(s, **kw))

    ref, se = jittered_central_differences(loss, q0, STEP, REF_SPP, REF_KEYS)
    g_edge = np.asarray(jax.grad(lambda q: loss(q, edge_gradients=True))(q0))
    g_plain = np.asarray(jit_grad(loss)(q0))
    bnd_ref, bnd_edge = ref - g_plain, g_edge - g_plain
    text = (
        f"(direction x, y, z, centre x, y, z)\nreference {ref} +- {se} ({se / np.abs(ref)})\n"
        f"edge {g_edge} ({(g_edge - ref) / np.abs(ref)})\nplain {g_plain} ({(g_plain - ref) / np.abs(ref)})\n"
        f"boundary term: reference - plain {bnd_ref}, edge - plain {bnd_edge} ({(bnd_edge - bnd_ref) / np.abs(bnd_ref)})"
    )
    print(text)  # shown with pytest -s
    assert np.all(se < 0.02 * np.abs(ref)), text
    assert np.all(np.abs(g_edge - ref) <= EDGE_RTOL * np.abs(ref)), text
    assert np.all(np.abs(bnd_edge - bnd_ref) <= 0.1 * np.abs(bnd_ref)), text
    # plain AD misses the boundary term: it is 0 for the centre, and large everywhere
    np.testing.assert_array_equal(g_plain[3:], 0.0)
    assert np.all(np.abs(bnd_ref) > 20 * se), text
    assert np.abs(g_plain[2] - ref[2]) > 0.5 * np.abs(ref[2]), text
