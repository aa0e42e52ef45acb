"""Textures: box-filtered checker and stripes against the hard pattern and exact
area fractions; bilinear image lookup; spherical (u, v) mapping."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt
from raytrax import shapes as S
from raytrax import textures as tx

F64 = jnp.float64

checker = jax.jit(tx.checker, static_argnums=3)
stripes = jax.jit(tx.stripes, static_argnums=4)
bilinear = jax.jit(tx.bilinear)


def hard_checker_np(u, v, scale):
    return np.mod(np.floor(u * scale) + np.floor(v * scale), 2.0)


def _uv_away_from_edges(rng, n, scale, margin):
    """Random (u, v) at least ``margin`` (pattern units) from any cell edge."""
    out = []
    while len(out) < n:
        p = rng.uniform(-3, 3, 2)
        f = p * scale - np.floor(p * scale)
        if np.all((f > margin) & (f < 1 - margin)):
            out.append(p)
    return np.asarray(out)


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_filtered_checker_tends_to_hard_checker(scale):
    rng = np.random.default_rng(0)
    uv = _uv_away_from_edges(rng, 64, scale, 1e-3)
    hard = hard_checker_np(uv[:, 0], uv[:, 1], scale)
    assert 10 < hard.sum() < 54
    sc = jnp.full((64,), scale, F64)
    hard_tx = np.asarray(checker(jnp.asarray(uv.T), jnp.zeros((2, 64), F64), sc, False))
    np.testing.assert_array_equal(hard_tx, hard)
    errs = []
    for w in (0.3, 0.03, 1e-3 / scale, 1e-5 / scale):
        f = np.asarray(checker(jnp.asarray(uv.T), jnp.full((2, 64), w, F64), sc, True))
        errs.append(np.abs(f - hard).max())
    assert errs[0] > 0.05  # wide footprints really blur
    assert errs[1] < errs[0]
    np.testing.assert_allclose(errs[2:], 0.0, atol=1e-9)  # footprint inside one cell: exact


def test_filtered_checker_is_half_on_an_edge_and_in_0_1():
    u = jnp.asarray([1.0, 2.0, 0.0, 3.0], F64)
    v = jnp.asarray([0.3, 0.7, 0.5, 0.2], F64)
    w = jnp.full((2, 4), 0.2, F64)
    f = np.asarray(checker(jnp.stack([u, v]), w, jnp.ones(4, F64), True))
    np.testing.assert_allclose(f, 0.5, atol=1e-12)
    rng = np.random.default_rng(1)
    uv = jnp.asarray(rng.uniform(-5, 5, (2, 256)))
    ww = jnp.asarray(rng.uniform(0, 3, (2, 256)))
    f = np.asarray(checker(uv, ww, jnp.full((256,), 1.7, F64), True))
    assert np.all((f >= -1e-12) & (f <= 1 + 1e-12))


def _box_average(fun, u, v, wu, wv, n=1200):
    """Midpoint-rule average of ``fun(u, v)`` over the footprint box."""
    s = (np.arange(n) + 0.5) / n - 0.5
    U, Vv = np.meshgrid(u + s * wu, v + s * wv, indexing="ij")
    return fun(U, Vv).mean()


@pytest.mark.parametrize(
    "u,v,wu,wv,scale",
    [
        (0.3, 0.4, 0.5, 0.5, 1.0),
        (0.95, 1.02, 0.3, 0.1, 1.0),
        (-0.2, 2.6, 1.7, 0.8, 1.0),
        (0.1, 0.12, 0.2, 0.45, 3.0),
        (5.0, 5.0, 2.5, 2.5, 0.5),
    ],
)
def test_filtered_checker_equals_area_fraction(u, v, wu, wv, scale):
    f = float(checker(jnp.asarray([[u], [v]], F64), jnp.asarray([[wu], [wv]], F64), jnp.asarray([scale], F64), True)[0])
    ref = _box_average(lambda a, b: hard_checker_np(a, b, scale), u, v, wu, wv)
    assert f == pytest.approx(ref, abs=3e-3)


@pytest.mark.parametrize("s,w,scale", [(0.3, 0.5, 1.0), (1.9, 0.25, 1.0), (0.0, 3.3, 2.0), (7.1, 0.05, 1.0)])
def test_filtered_stripes_equal_length_fraction(s, w, scale):
    uv = jnp.asarray([[s], [0.37]], F64)
    wid = jnp.asarray([[w], [0.9]], F64)  # v footprint is irrelevant for stripes along u
    f = float(stripes(uv, wid, jnp.asarray([scale], F64), jnp.asarray([[1.0], [0.0]], F64), True)[0])
    x = s + ((np.arange(100000) + 0.5) / 100000 - 0.5) * w
    ref = np.mod(np.floor(x * scale), 2.0).mean()
    assert f == pytest.approx(ref, abs=1e-4)
    hard = float(stripes(uv, wid, jnp.asarray([scale], F64), jnp.asarray([[1.0], [0.0]], F64), False)[0])
    assert hard == np.mod(np.floor(s * scale), 2.0)


def test_filtered_checker_has_nonzero_gradient_near_an_edge():
    def f(u, filtered):
        uv = jnp.stack([u, jnp.full_like(u, 0.25)])
        return jnp.sum(tx.checker(uv, jnp.full((2, 3), 0.1, F64), jnp.ones(3, F64), filtered))

    u = jnp.asarray([0.98, 1.0, 1.03], F64)
    grad = jax.jit(jax.grad(f), static_argnums=1)
    g = np.asarray(grad(u, True))
    # crossing u = 1 at v = 0.25 goes from colour 1 to colour 2 cells: d frac / du = 1 / w inside the blur
    np.testing.assert_allclose(g, 10.0, rtol=1e-9)
    np.testing.assert_array_equal(np.asarray(grad(u, False)), 0.0)


# ----------------------------------------------------------------------------
# image textures
# ----------------------------------------------------------------------------

H_IMG, W_IMG = 4, 5


@pytest.fixture(scope="module")
def image():
    return np.random.default_rng(2).uniform(size=(H_IMG, W_IMG, 3))


def test_bilinear_exact_at_texel_centres(image):
    i, j = np.meshgrid(np.arange(H_IMG), np.arange(W_IMG), indexing="ij")
    uv = np.stack([(j.ravel() + 0.5) / W_IMG, 1 - (i.ravel() + 0.5) / H_IMG])
    out = np.asarray(bilinear(jnp.asarray(image), jnp.asarray(uv))).T
    np.testing.assert_allclose(out, image.reshape(-1, 3), atol=1e-12)


def test_bilinear_interpolates_wraps_u_and_clamps_v(image):
    uv = np.array(
        [
            [(1 + 0.5) / W_IMG + 0.5 / W_IMG, 1 - 2.5 / H_IMG],  # halfway between texels (2,1) and (2,2)
            [0.0, 1 - 0.5 / H_IMG],  # u = 0: halfway between the last and first column
            [0.3 / W_IMG + 0.5 / W_IMG, 1.0],  # v = 1: clamped to the top row
            [(3 + 0.5) / W_IMG, -0.2],  # v < 0: clamped to the bottom row
            [(1 + 0.5) / W_IMG + 1.0, 1 - 1.5 / H_IMG],  # u + 1 wraps to the same texel
        ]
    ).T
    out = np.asarray(bilinear(jnp.asarray(image), jnp.asarray(uv))).T
    np.testing.assert_allclose(out[0], 0.5 * (image[2, 1] + image[2, 2]), atol=1e-12)
    np.testing.assert_allclose(out[1], 0.5 * (image[0, W_IMG - 1] + image[0, 0]), atol=1e-12)
    np.testing.assert_allclose(out[2], 0.7 * image[0, 0] + 0.3 * image[0, 1], atol=1e-12)
    np.testing.assert_allclose(out[3], image[H_IMG - 1, 3], atol=1e-12)
    np.testing.assert_allclose(out[4], image[1, 1], atol=1e-12)


def test_bilinear_gradient_wrt_texels_is_the_weights(image):
    u, v = (1.5 + 0.25) / W_IMG, 1 - (2.5 + 0.75) / H_IMG  # fx = 0.25, fy = 0.75 from texel (2, 1)
    uv = jnp.asarray([[u], [v]], F64)
    g = np.asarray(jax.jit(jax.grad(lambda im: tx.bilinear(im, uv)[0, 0]))(jnp.asarray(image)))
    want = np.zeros_like(image)
    want[2, 1, 0], want[2, 2, 0], want[3, 1, 0], want[3, 2, 0] = 0.75 * 0.25, 0.25 * 0.25, 0.75 * 0.75, 0.25 * 0.75
    np.testing.assert_allclose(g, want, atol=1e-12)


def test_spherical_mapping_of_known_points_addresses_the_right_texels(image):
    """u, v from the sphere hit of known points, then the image lookup there."""
    c = np.array([0.0, 0.0, 0.0])
    pts = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 0.5, math.sqrt(0.75)]])
    o = (2 * pts).T
    d = -pts.T
    t, n, uv, rate = jax.jit(S.sphere_hit)(
        jnp.asarray(np.tile(c[:, None], (1, 3))), jnp.ones(3, F64), jnp.asarray(o), jnp.asarray(d), jnp.ones(3, F64)
    )
    uv = np.asarray(uv)
    np.testing.assert_allclose(np.asarray(t), 1.0, atol=1e-12)
    np.testing.assert_allclose(uv[:, 0], [0.5, 0.5], atol=1e-12)  # facing +z: image centre
    np.testing.assert_allclose(uv[:, 1], [0.75, 0.5], atol=1e-12)  # facing +x: three quarters along u
    np.testing.assert_allclose(uv[:, 2], [0.5, 0.5 + 30 / 180], atol=1e-12)  # 30 deg latitude
    # the texel rate is 1/(2 pi r) along u and 1/(pi r) along v
    np.testing.assert_allclose(np.asarray(rate)[:, 0], [1 / (2 * math.pi), 1 / math.pi], rtol=1e-12)
    col = np.asarray(bilinear(jnp.asarray(image), jnp.asarray(uv))).T
    ref = np.asarray(bilinear(jnp.asarray(image), jnp.asarray([[0.5, 0.75], [0.5, 0.5]], F64))).T
    np.testing.assert_allclose(col[:2], ref, atol=1e-12)


# ----------------------------------------------------------------------------
# anisotropic footprints
# ----------------------------------------------------------------------------


class _Hit(NamedTuple):
    """A kind's ``(t, normal, uv, rate)`` with the field names of a Hit."""

    t: jax.Array
    normal: jax.Array
    uv: jax.Array
    rate: jax.Array


def _floor_hit(o, d):
    """The floor y = 0 (plane kind: u along x, v along -z) hit by rays ``o, d (3, n)``."""
    n = o.shape[1]
    pt = jnp.zeros((3, n), o.dtype)
    nr = jnp.zeros((3, n), o.dtype).at[1].set(1.0)
    return _Hit(*S.plane_hit(pt, nr, o, d, jnp.ones(n, o.dtype)))


def _grazing_rays(cos, phi):
    """Rays from above the floor (normal +y) meeting it with ``|d.n| = cos`` at azimuth
    ``phi`` (from -z towards +x): origins and unit directions ``(3, n)``."""
    sin = np.sqrt(1.0 - cos * cos)
    d = np.stack([sin * np.sin(phi), -cos, -sin * np.cos(phi)])
    return np.stack([np.zeros_like(cos), np.ones_like(cos), np.zeros_like(cos)]), d


def _floor_widths(o, d, w):
    hit, shifts = tx.hit_with_uv_shifts(lambda o_: _floor_hit(o_, d), o, d, True)
    assert shifts is not None
    return tx.footprint_widths(shifts, d, hit.normal, w)


@pytest.mark.parametrize("phi", [0.0, 0.4, math.pi / 4, math.pi / 2, 2.5])
def test_footprint_widths_are_the_box_of_the_cone_ellipse(phi):
    """Widths on the floor from the ray differentials against the ellipse's box: long
    axis ``w / cos`` along the view (capped at ``w / MIN_COS``), short axis ``w``."""
    cos = np.array([1.0, 0.7, 0.2, 0.05, 0.02, 0.01, 1e-4])
    o, d = _grazing_rays(cos, np.full_like(cos, phi))
    w = np.linspace(0.01, 0.3, cos.size)
    got = np.asarray(jax.jit(_floor_widths)(jnp.asarray(o), jnp.asarray(d), jnp.asarray(w)))
    c = np.maximum(cos, tx.MIN_COS)
    s, k = np.sin(phi), np.cos(phi)
    # a = (sin, 0, -cos phi) = (du, dv) (sin, cos phi); b = n x a = (-cos, 0, -sin phi) = (du, dv) (-cos, sin phi)
    want_u = w * np.sqrt((s / c) ** 2 + k**2)
    want_v = w * np.sqrt((k / c) ** 2 + s**2)
    np.testing.assert_allclose(got, np.stack([want_u, want_v]), rtol=1e-9)
    # Seen from below (the back side, the same ellipse):
    o2, d2 = o * [[1.0], [-1.0], [1.0]], d * [[1.0], [-1.0], [1.0]]
    back = np.asarray(jax.jit(_floor_widths)(jnp.asarray(o2), jnp.asarray(d2), jnp.asarray(w)))
    np.testing.assert_allclose(back, got, rtol=1e-9)


def test_footprint_widths_gradient_is_finite_at_grazing_and_normal_incidence():
    """Values and gradients (with respect to the rays and the cone width) finite down
    to rays parallel to the floor, and along its normal."""
    cos = np.array([1.0, 0.5, 0.02, 1e-3, 1e-9, 0.0, 1.0])
    o, d = _grazing_rays(cos, np.linspace(0.0, 2.0, cos.size))
    o[:, -1], d[:, -1] = [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]  # along the normal, from below

    def f(o, d, w):
        return jnp.sum(_floor_widths(o, d, w))

    args = (jnp.asarray(o), jnp.asarray(d), jnp.full((cos.size,), 0.1, F64))
    assert np.isfinite(float(jax.jit(f)(*args)))
    for g in jax.jit(jax.grad(f, argnums=(0, 1, 2)))(*args):
        assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize("kind", ["plane", "sphere", "quad"])
def test_uv_shifts_are_the_ray_differentials_of_uv(kind):
    """``duv`` of :func:`hit_with_uv_shifts` against central differences of the uv of
    rays shifted across themselves (the kinds' own hit functions: no per-kind code)."""
    rng = np.random.default_rng(3)
    m = 6
    o = np.tile(np.array([[0.3], [2.0], [4.0]]), (1, m))
    if kind == "plane":
        target = np.stack([rng.uniform(-3, 3, m), np.zeros(m), rng.uniform(-8, -1, m)])

        def hit(o_, d):
            pt = jnp.zeros((3, m), F64)
            nr = jnp.tile(jnp.asarray([[0.1], [1.0], [0.2]], F64), (1, m))
            return _Hit(*S.plane_hit(pt, nr, o_, d, jnp.ones(m, F64)))

    elif kind == "sphere":
        dirs = rng.normal(size=(3, m))
        dirs[2] = np.abs(dirs[2])  # the side facing the rays
        target = 1.5 * dirs / np.linalg.norm(dirs, axis=0)

        def hit(o_, d):
            t0 = jnp.asarray(np.linalg.norm(target - o, axis=0))
            return _Hit(*S.sphere_hit(jnp.zeros((3, m), F64), jnp.full((m,), 1.5, F64), o_, d, t0))

    else:
        c = [np.array(v, np.float64)[:, None].repeat(m, 1) for v in ((-2, 0, 0), (2, 0, -1), (2, 1, -5), (-2, 1, -4))]
        a, b = rng.uniform(0.1, 0.9, (2, m))
        target = c[0] + a * (c[1] - c[0]) + b * (c[3] - c[0])

        def hit(o_, d):
            c0, c1, c2, c3 = (jnp.asarray(x) for x in c)
            return _Hit(*S.quad_hit(c0, c1, c2, c3, o_, d, jnp.ones(m, F64)))

    d = (target - o) / np.linalg.norm(target - o, axis=0)
    dj, oj = jnp.asarray(d), jnp.asarray(o)
    h0, shifts = tx.hit_with_uv_shifts(lambda o_: hit(o_, dj), oj, dj, True)
    assert shifts is not None
    e, duv = (np.asarray(x) for x in shifts)
    np.testing.assert_allclose(np.einsum("kin,lin->kln", e, e), np.eye(2)[:, :, None].repeat(m, 2), atol=1e-12)
    np.testing.assert_allclose(np.einsum("kin,in->kn", e, d), 0.0, atol=1e-12)
    eps = 1e-6
    for k in range(2):
        fd = (np.asarray(hit(oj + eps * e[k], dj).uv) - np.asarray(hit(oj - eps * e[k], dj).uv)) / (2 * eps)
        np.testing.assert_allclose(duv[k], fd, rtol=1e-6, atol=1e-8)
    assert np.abs(duv).max() > 0.01
    h1, none = tx.hit_with_uv_shifts(lambda o_: hit(o_, dj), oj, dj, False)
    assert none is None
    np.testing.assert_array_equal(np.asarray(h1.uv), np.asarray(h0.uv))


# A textured floor seen from a low camera looking 12 degrees down (32-degree field of
# view, 40 x 40 pixels, spp 1): the horizon lies at row 5.17, rows 0-4 see the sky.
GZ_C1, GZ_C2 = (0.9, 0.8, 0.7), (0.1, 0.2, 0.3)
GZ_W, GZ_H = 40, 40
GZ_HORIZON = 4


def _grazing_scene(dtype, texture, azimuth=0.0, height=GZ_H, down=12.0):
    """``azimuth`` (degrees) turns the view from -z towards +x; the floor's u runs along
    x, v along -z."""

    b = rt.SceneBuilder(
        "classic", width=GZ_W, height=height, spp=1, max_depth=1, background=(0.0, 0.0, 0.0), ambient=(1.0, 1.0, 1.0)
    )
    a = math.radians(azimuth)
    look = (math.sin(a), 1.0 - math.tan(math.radians(down)), -math.cos(a))
    b.camera(position=(0.0, 1.0, 0.0), look_at=look, fov=32.0)
    b.material("floor", color=GZ_C1, ambient=1.0, diffuse=0.0, specular=0.0, texture=texture)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    return b.build(dtype)


@pytest.fixture(scope="module")
def grazing_images():

    chk = _grazing_scene(F64, tx.Checker(color2=GZ_C2, scale=1.0), azimuth=45.0)
    stp = _grazing_scene(F64, tx.Stripes(color2=GZ_C2, scale=1.0, direction=(1.0, 0.0)))
    return dict(
        checker=np.asarray(rt.render(chk)),
        checker_hard=np.asarray(rt.render(chk, filter_textures=False)),
        stripes=np.asarray(rt.render(stp)),
    )


def test_grazing_checker_fades_to_its_mean_far_away_and_stays_sharp_near(grazing_images):
    """A checker seen diagonally (45 degrees from its axes): far away the footprint is
    stretched along u and v alike, so the pixels take the checker's mean colour (the
    isotropic footprint of before, ``w / max(cos, 1/4)``, aliased here: up to 0.13 off
    on rows 8-9); near the camera the pattern is the hard checker's."""
    img, hard = grazing_images["checker"], grazing_images["checker_hard"]
    assert np.all(img[: GZ_HORIZON + 1] == 0.0) and np.all(img[GZ_HORIZON + 1 :] > 0.05)
    mean = 0.5 * (np.asarray(GZ_C1) + np.asarray(GZ_C2))
    far = slice(GZ_HORIZON + 1, GZ_HORIZON + 6)  # rows 5-9: under 1/20 of a cell per pixel along the view
    assert np.abs(hard[far] - mean).max() > 0.3  # the point-sampled pattern aliases there
    np.testing.assert_allclose(img[far], np.broadcast_to(mean, img[far].shape), atol=0.02)
    # Near floor (the bottom rows, several pixels per cell): the pattern itself, equal
    # to the hard checker except on the pixels a cell edge crosses.
    near = img[-12:]
    on_c1 = np.abs(near - GZ_C1).max(-1) < 1e-9
    on_c2 = np.abs(near - GZ_C2).max(-1) < 1e-9
    assert on_c1.mean() > 0.25 and on_c2.mean() > 0.25 and (on_c1 | on_c2).mean() > 0.75
    np.testing.assert_allclose(near[on_c1 | on_c2], hard[-12:][on_c1 | on_c2], atol=1e-9)


def test_grazing_stripes_along_the_view_stay_sharp(grazing_images):
    """Stripes of constant u seen along -z run along the view: the footprint is long
    along them but only a pixel wide across them, so far rows keep their full
    contrast (the isotropic footprint blurred rows 6-8 to a contrast of 0.1-0.5)."""
    img = grazing_images["stripes"]
    contrast = np.ptp(img[GZ_HORIZON + 2 : GZ_HORIZON + 5, :, 0], axis=1)  # rows 6-8
    assert contrast.min() > 0.7, contrast


def test_grazing_checker_gradient_is_finite():
    """float32 (as users render), looking level with the floor at an odd height: the
    middle row's ray runs exactly parallel to the floor and the rows around it meet it
    at a vanishing angle. Every gradient is finite."""

    h = GZ_H + 1
    s = _grazing_scene(jnp.float32, tx.Checker(color2=GZ_C2, scale=1.0), azimuth=30.0, height=h, down=0.0)
    p = rt.parameters(s)
    wgt = jnp.asarray(np.random.default_rng(4).uniform(0.5, 1.5, (h, GZ_W, 3)), jnp.float32)

    def loss(q):
        return jnp.sum(wgt * rt.render(rt.with_parameters(s, q)))

    val, g = jax.jit(jax.value_and_grad(loss))(p)
    assert np.isfinite(float(val))
    bad = [k for k, v in g.items() if not np.all(np.isfinite(np.asarray(v)))]
    assert not bad, bad
    assert abs(float(g["material.floor.texture.scale"])) > 0


def test_a_curved_mirror_widens_the_reflected_footprint():
    """A cone of width ``w`` at a mirror of radius ``R`` leaves with its spread grown by
    ``2 w / R`` (the normal turns by ``1 / R`` per unit of surface, a reflected direction
    by twice that); a flat mirror and the refracted cone keep the spread."""
    from raytrax.intersect import prepare
    from raytrax.renderer.options import RenderOptions
    from raytrax.renderer.whitted import shade

    R = 1.5
    b = rt.SceneBuilder("physical", width=4, height=4, spp=1, max_depth=1)
    b.material("mirror", color=(0.0, 0.0, 0.0), reflectivity=0.9)
    b.sphere((0.0, 0.0, 0.0), R, "mirror")
    b.plane((0.0, -4.0, 0.0), (0.0, 1.0, 0.0), "mirror")
    s = b.build(F64)
    # one ray onto the sphere head on, one onto the plane (from below the sphere)
    o = jnp.asarray([[0.0, 3.0], [0.0, -2.0], [5.0, 0.0]], F64)
    d = jnp.asarray([[0.0, 0.0], [0.0, -1.0], [-1.0, 0.0]], F64)
    cw, spread = jnp.asarray([0.01, 0.01], F64), jnp.asarray([0.002, 0.003], F64)
    _, kids = shade(s, prepare(s), o, d, jnp.ones((3, 2), F64), cw, spread, RenderOptions(s.settings), False)
    cw_hit, spread_r, spread_t = (np.asarray(x) for x in kids[-3:])
    np.testing.assert_allclose(cw_hit, [0.01 + 0.002 * (5.0 - R), 0.01 + 0.003 * 2.0], rtol=1e-12)
    np.testing.assert_allclose(spread_r, [0.002 + 2.0 * cw_hit[0] / R, 0.003], rtol=1e-12)
    np.testing.assert_allclose(spread_t, [0.002, 0.003], rtol=1e-12)


# ----------------------------------------------------------------------------
# reverse mode through an image texture
# ----------------------------------------------------------------------------


def _shapes_in(jaxpr, out):
    """Every variable shape of ``jaxpr`` and of the jaxprs in its equations' parameters."""
    for eqn in jaxpr.eqns:
        out.extend(tuple(v.aval.shape) for v in eqn.outvars if hasattr(v.aval, "shape"))
        for p in eqn.params.values():
            for q in p if isinstance(p, (list, tuple)) else (p,):
                inner = getattr(q, "jaxpr", q)
                if hasattr(inner, "eqns"):
                    _shapes_in(inner, out)
    return out


def test_reverse_mode_keeps_the_rays_texels_not_the_image():
    """The value_and_grad of a render with an image texture larger than a batch of rays
    (a 96 x 96 image; 48 x 32 rays per batch, three depths of a mirror scene) keeps the
    texels each ray read, not the image: no stacked copy of the image (one per batch of
    rays and depth) appears anywhere in the program (for the seed scene's 512 x 512
    texture at 256 x 256 such copies are 75 MB a call). Checked on the traced program
    (no compilation)."""
    texels = np.random.default_rng(3).uniform(0.1, 0.9, (96, 96, 3))
    b = rt.SceneBuilder("classic", width=48, height=32, spp=1, max_depth=2)
    b.camera(position=(0, 1, 5), look_at=(0, 0.5, 0), fov=40)
    b.light((3, 5, 4), intensity=(0.8, 0.8, 0.8))
    b.material("planet", texture=rt.ImageTexture(texels))
    b.material("mirror", color=(0.1, 0.1, 0.1), reflectivity=0.7)
    b.sphere((-0.6, 0.6, 0), 0.6, "planet")
    b.sphere((0.7, 0.6, -0.5), 0.6, "mirror")
    b.plane((0, 0, 0), (0, 1, 0), "mirror")
    s = b.build()

    def loss(pos):
        return jnp.mean(rt.render(rt.with_parameters(s, {"light[0].position": pos})))

    shapes = _shapes_in(jax.make_jaxpr(jax.value_and_grad(loss))(jnp.asarray([3.0, 5.0, 4.0])).jaxpr, [])
    # The image as the lookup reads it, (96 * 96, 3) texel rows, or as it is, (96, 96, 3).
    image = [sh for sh in shapes if sh[-2:] == (96 * 96, 3) or sh[-3:] == (96, 96, 3)]
    assert image, "the walk over the program did not reach the texture lookup"
    stacked = sorted({sh for sh in image if len(sh) > (2 if sh[-2:] == (96 * 96, 3) else 3)})
    assert not stacked, f"reverse mode keeps stacked copies of the image: {stacked}"


def test_gradients_through_a_texture_larger_than_a_batch_match_finite_differences():
    """Where the image has more texels (16 x 16) than a batch has rays (8 x 6), reverse
    mode keeps the rays' texels instead of recomputing the lookup from the image: the
    light's position, the tint and the texels the image shows, through a mirror too,
    against central differences (float64)."""
    from raytrax.testing import check_gradients

    texels = np.random.default_rng(4).uniform(0.1, 0.9, (16, 16, 3))
    b = rt.SceneBuilder("classic", width=8, height=6, spp=1, max_depth=2)
    b.camera(position=(0, 1, 5), look_at=(0, 0.5, 0), fov=40)
    b.light((3, 5, 4), intensity=(0.8, 0.8, 0.8))
    b.material("planet", color=(1.0, 0.9, 0.8), specular=0.3, texture=rt.ImageTexture(texels))
    b.material("mirror", color=(0.1, 0.1, 0.1), reflectivity=0.7)
    b.sphere((-0.5, 0.6, 0), 0.7, "planet")
    b.sphere((0.8, 0.6, -0.5), 0.6, "mirror")
    b.plane((0, 0, 0), (0, 1, 0), "mirror")
    s = b.build(jnp.float64)
    names = ("light[0].position", "material.planet.color", "material.planet.texture.image")
    p = {k: v for k, v in rt.parameters(s).items() if k in names}

    def loss(q):
        return jnp.mean(rt.render(rt.with_parameters(s, q)) ** 2)

    g = np.abs(np.asarray(jax.grad(loss)(p)["material.planet.texture.image"])).ravel()
    seen = [int(i) for i in np.argsort(g)[-4:]]  # texels the image shows
    assert g[seen].min() > 0, "no texel of the image is seen"
    report = check_gradients(
        loss, p, names={names[0]: [0, 1, 2], names[1]: [0, 1, 2], names[2]: seen}, forward_mode=False
    )
    assert report.ok, report
