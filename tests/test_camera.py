"""Pinhole camera (orientation, field of view, pixel mapping, jitter) and
anti-aliasing by stratified supersampling, against exact pixel coverage."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt
from raytrax.camera import Camera, frame, primary_rays, rays_through

F64 = jnp.float64

_rays = jax.jit(primary_rays, static_argnums=(2, 3, 4))


def cam(position, look_at, up=(0.0, 1.0, 0.0), fov=28.0725):
    f = lambda x: jnp.asarray(np.asarray(x, np.float64))
    return Camera(f(position), f(look_at), f(up), f(fov))


def basis_np(position, look_at, up):
    fwd = np.asarray(look_at, float) - np.asarray(position, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    return fwd, right, np.cross(right, fwd)


def rays(camera, W, H, spp=1, key=None):
    pix = jnp.arange(W * H, dtype=jnp.int32)
    o, d, spread = _rays(camera, pix, W, H, spp, key)
    return np.asarray(o).T, np.asarray(d).T, float(spread)


def image_coords(d, camera, W, H):
    """Back-project unit directions (n, 3) to continuous pixel coordinates (col, row)."""
    fwd, right, up = basis_np(camera.position, camera.look_at, camera.up)
    half_h = math.tan(math.radians(float(camera.fov)) / 2)
    half_w = half_h * W / H
    x = (d @ right) / (d @ fwd) / half_w
    y = (d @ up) / (d @ fwd) / half_h
    return (x + 1) / 2 * W, (1 - y) / 2 * H


POS, AT, UP = (1.0, 2.0, 3.0), (-2.0, 0.5, -4.0), (0.0, 1.0, 0.0)


def test_centre_ray_is_forward_and_origins_at_camera():
    c = cam(POS, AT, UP, fov=50)
    W, H = 9, 7
    o, d, _ = rays(c, W, H)
    fwd, right, up = basis_np(POS, AT, UP)
    np.testing.assert_allclose(o, np.tile(POS, (W * H, 1)), atol=0)
    np.testing.assert_allclose(d[(H // 2) * W + W // 2], fwd, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_rays_from_a_frame_equal_rays_from_the_camera():
    # The integrator computes the frame once per trace and makes its rays from it.
    c = cam(POS, AT, UP, fov=50)
    W, H = 9, 7
    xy = jnp.asarray(np.random.default_rng(0).uniform(0, 7, (2, 40)))
    o1, d1 = rays_through(c, xy, W, H)
    o2, d2 = rays_through(frame(c, W, H), xy, W, H)
    np.testing.assert_array_equal(np.asarray(o1), np.asarray(o2))
    np.testing.assert_array_equal(np.asarray(d1), np.asarray(d2))
    f = frame(c, W, H)
    fwd, right, up = basis_np(POS, AT, UP)
    np.testing.assert_allclose(np.stack([f.fwd, f.right, f.up]), np.stack([fwd, right, up]), atol=1e-12)
    np.testing.assert_allclose(float(f.half_w) / float(f.half_h), W / H, rtol=1e-12)


def test_row_zero_is_top_and_x_increases_to_the_right():
    c = cam(POS, AT, UP, fov=50)
    W, H = 9, 7
    _, d, _ = rays(c, W, H)
    fwd, right, up = basis_np(POS, AT, UP)
    x = ((d @ right) / (d @ fwd)).reshape(H, W)
    y = ((d @ up) / (d @ fwd)).reshape(H, W)
    assert np.all(np.diff(x, axis=1) > 0) and np.all(np.diff(y, axis=0) < 0)
    assert y[0, 0] > 0 and x[0, 0] < 0  # pixel (0, 0): top left
    np.testing.assert_allclose(np.diff(x, axis=0), 0.0, atol=1e-12)  # rows are horizontal lines


def test_seed_field_of_view_is_a_20x20_image_plane_at_distance_40():
    assert 2 * math.degrees(math.atan(10 / 40)) == pytest.approx(28.0725, abs=1e-4)
    b = rt.SceneBuilder()
    b.material("m")
    default_fov = float(b.build(F64).camera.fov)
    assert default_fov == pytest.approx(2 * math.degrees(math.atan(10 / 40)), rel=1e-12)
    c = cam((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov=default_fov)
    W = H = 20
    _, d, _ = rays(c, W, H)
    p = d * (-40.0 / d[:, 2:3])  # hits of the plane z = -40
    row, col = np.divmod(np.arange(W * H), W)
    np.testing.assert_allclose(p[:, 0], -10 + (col + 0.5), atol=1e-9)
    np.testing.assert_allclose(p[:, 1], 10 - (row + 0.5), atol=1e-9)


def test_vertical_fov_and_aspect_ratio():
    c = cam((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov=60.0)
    W, H = 8, 4
    _, d, spread = rays(c, W, H)
    t = math.tan(math.radians(30))
    x, y = d[:, 0] / -d[:, 2], d[:, 1] / -d[:, 2]
    # pixel centres span (H - 1)/H of the vertical extent and the same pixel pitch horizontally
    assert y.max() == pytest.approx(t * (1 - 1 / H), rel=1e-12)
    assert x.max() == pytest.approx(t * W / H * (1 - 1 / W), rel=1e-12)
    assert spread == pytest.approx(2 * t / H, rel=1e-12)  # one pixel's angular pitch


def test_stratified_samples_sit_at_subpixel_cell_centres():
    c = cam(POS, AT, UP, fov=40)
    W, H, n = 6, 5, 3
    _, d, _ = rays(c, W, H, spp=n * n)
    px, py = image_coords(d, c, W, H)
    px, py = px.reshape(n * n, H * W), py.reshape(n * n, H * W)  # sample-major
    row, col = np.divmod(np.arange(W * H), W)
    for s in range(n * n):
        iy, ix = divmod(s, n)
        np.testing.assert_allclose(px[s] - col, (ix + 0.5) / n, atol=1e-9)
        np.testing.assert_allclose(py[s] - row, (iy + 0.5) / n, atol=1e-9)


def test_jitter_changes_samples_but_stays_in_its_stratum():
    c = cam(POS, AT, UP, fov=40)
    W, H, n = 6, 5, 2
    _, d0, _ = rays(c, W, H, spp=n * n)
    _, d1, _ = rays(c, W, H, spp=n * n, key=jax.random.key(1))
    _, d1b, _ = rays(c, W, H, spp=n * n, key=jax.random.key(1))
    _, d2, _ = rays(c, W, H, spp=n * n, key=jax.random.key(2))
    np.testing.assert_array_equal(d1, d1b)  # deterministic given the key
    assert np.abs(d1 - d0).max() > 1e-4 and np.abs(d1 - d2).max() > 1e-4
    row, col = np.divmod(np.arange(W * H), W)
    for dd in (d1, d2):
        px, py = image_coords(dd, c, W, H)
        fx = px.reshape(n * n, -1) - col
        fy = py.reshape(n * n, -1) - row
        assert np.all((fx >= 0) & (fx < 1) & (fy >= 0) & (fy < 1))  # inside its pixel
        for s in range(n * n):
            iy, ix = divmod(s, n)
            assert np.all(np.floor(fx[s] * n) == ix) and np.all(np.floor(fy[s] * n) == iy)
        # and actually spread over the stratum (not all at one spot)
        assert np.ptp(fx[0]) > 0.2 / n and np.ptp(fy[0]) > 0.2 / n


# ----------------------------------------------------------------------------
# anti-aliasing: a white quad on black, compared with its exact pixel coverage
# ----------------------------------------------------------------------------

AA_W, AA_H, AA_FOV, AA_DIST = 15, 9, 40.0, 10.0
# quad corners in continuous pixel coordinates (col, row): a vertical left edge
# through the centres of column 7, a slanted right edge
AA_POLY = np.array([[7.5, -3.0], [13.3, -3.0], [10.1, 12.0], [7.5, 12.0]])


def _pix_to_world(p):
    half_h = math.tan(math.radians(AA_FOV) / 2)
    half_w = half_h * AA_W / AA_H
    X = (p[:, 0] / AA_W * 2 - 1) * half_w * AA_DIST
    Y = (1 - p[:, 1] / AA_H * 2) * half_h * AA_DIST
    return np.stack([X, Y, np.zeros_like(X)], 1)


def _clip(poly, axis, val, keep_greater):
    out = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        ina = (a[axis] >= val) if keep_greater else (a[axis] <= val)
        inb = (b[axis] >= val) if keep_greater else (b[axis] <= val)
        if ina:
            out.append(a)
        if ina != inb:
            t = (val - a[axis]) / (b[axis] - a[axis])
            out.append(a + t * (b - a))
    return np.asarray(out)


def _area(poly):
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def exact_coverage():
    cov = np.zeros((AA_H, AA_W))
    for r in range(AA_H):
        for c in range(AA_W):
            p = AA_POLY
            for axis, val, g in ((0, c, True), (0, c + 1, False), (1, r, True), (1, r + 1, False)):
                p = _clip(p, axis, val, g)
                if len(p) == 0:
                    break
            cov[r, c] = _area(p) if len(p) else 0.0
    return cov


@pytest.fixture(scope="module")
def aa_scene():
    b = rt.SceneBuilder(
        "classic", width=AA_W, height=AA_H, spp=1, max_depth=0, background=(0.0, 0.0, 0.0), ambient=(1.0, 1.0, 1.0)
    )
    b.camera(position=(0.0, 0.0, AA_DIST), look_at=(0.0, 0.0, 0.0), fov=AA_FOV)
    b.material("white", color=(1.0, 1.0, 1.0), ambient=1.0)
    b.quad(_pix_to_world(AA_POLY), "white")
    return b.build()


@pytest.fixture(scope="module")
def aa_images(aa_scene):
    return {spp: np.asarray(rt.render(aa_scene, spp=spp))[..., 0] for spp in (1, 4, 16)}


def test_aa_scene_is_white_on_black(aa_images):
    img = aa_images[16]
    cov = exact_coverage()
    np.testing.assert_array_equal(img[cov == 0], 0.0)
    np.testing.assert_allclose(img[cov == 1], 1.0, rtol=1e-6)
    assert (cov == 0).sum() > 40 and (cov == 1).sum() > 20


@pytest.mark.parametrize("spp", [4, 16])
def test_pixel_half_covered_by_an_edge_is_half_way(aa_images, spp):
    col = aa_images[spp][:, 7]  # the vertical edge passes through these pixel centres
    np.testing.assert_allclose(col, 0.5, atol=1e-6)
    np.testing.assert_allclose(exact_coverage()[:, 7], 0.5, atol=1e-12)


def test_supersampling_converges_to_exact_coverage(aa_images):
    cov = exact_coverage()
    edge = (cov > 0) & (cov < 1)
    assert edge.sum() >= 15
    err = {s: np.abs(aa_images[s] - cov)[edge].mean() for s in (1, 4, 16)}
    assert err[4] < 0.6 * err[1], err
    assert err[16] < 0.6 * err[4], err
    assert np.abs(aa_images[16] - cov).max() <= 0.25 + 1e-6
    assert np.abs(aa_images[4] - cov).max() <= 0.5 + 1e-6
    # one sample per pixel is all-or-nothing; 2 x 2 gives quarters
    np.testing.assert_array_equal(np.isin(aa_images[1], [0.0, 1.0]), True)
    np.testing.assert_allclose(aa_images[4] * 4, np.round(aa_images[4] * 4), atol=1e-5)


def test_2x2_is_smoother_than_1_sample_along_the_slanted_edge(aa_images):
    """Total variation down the columns the slanted edge crosses: a staircase of
    0/1 jumps with one sample, graded steps with 2 x 2."""
    cols = slice(9, 14)
    tv = {s: np.abs(np.diff(aa_images[s][:, cols], axis=0)).sum() for s in (1, 4)}
    tv_exact = np.abs(np.diff(exact_coverage()[:, cols], axis=0)).sum()
    assert tv[4] < tv[1]
    assert abs(tv[4] - tv_exact) < abs(tv[1] - tv_exact)
    # the largest step between vertical neighbours: a full 0 -> 1 jump with one sample
    jump = {s: np.abs(np.diff(aa_images[s][:, cols], axis=0)).max() for s in (1, 4)}
    assert jump[1] == 1.0 and jump[4] <= 0.5
