"""Textures: box-filtered checker and stripes against the hard pattern and exact
area fractions; bilinear image lookup; spherical (u, v) mapping."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

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
