"""The seed scene (scenes/cosc363.toml) renders with each of its features where it should be.

One compile: the scene is rendered at 80 x 80, 1 spp, depth 5; variants that
only change leaf values (a material, a sphere's position) reuse the compiled
program. Expected pixel positions come from the scene's own geometry through a
pinhole model of the camera (pixel centres, as rendered with spp = 1).
"""

from __future__ import annotations

import math
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = os.path.join(ROOT, "scenes", "cosc363.toml")
N = 80


def test_seed_scene_file_is_shipped_with_the_package():
    from raytrax.cli import seed_scene_path

    with open(SEED, "rb") as a, open(os.path.join(ROOT, "raytrax", "data", "scenes", "cosc363.toml"), "rb") as b:
        assert a.read() == b.read()
    assert os.path.samefile(seed_scene_path(), os.path.join(ROOT, "raytrax", "data", "scenes", "cosc363.toml"))


def test_seed_scene_settings(seed):
    st = seed.settings
    assert (st.shading, st.width, st.height, st.spp, st.max_depth) == ("classic", 600, 600, 4, 5)
    np.testing.assert_array_equal(seed.camera.position, np.zeros(3, np.float32))
    np.testing.assert_array_equal(seed.camera.look_at, np.float32([0, 0, -1]))
    assert float(seed.camera.fov) == pytest.approx(2 * math.degrees(math.atan(10 / 40)), abs=1e-4)
    np.testing.assert_array_equal(seed.lights.position, np.float32([[10, 40, -5], [-10, 40, -5]]))
    kinds = [k for k, _ in seed.object_index]
    assert sorted(kinds) == ["box", "plane", "sphere", "sphere", "sphere", "sphere", "tetrahedron"]


@pytest.fixture(scope="module")
def seed():
    return rt.load_scene(SEED)


def render(scene):
    return np.asarray(rt.render(scene, width=N, height=N, spp=1), dtype=np.float64)


@pytest.fixture(scope="module")
def img(seed):
    return render(seed)


def sphere(seed, material):
    k = seed.material_names.index(material)
    j = int(np.nonzero(np.asarray(seed.spheres.material) == k)[0][0])
    return j, np.asarray(seed.spheres.center[j], np.float64), float(seed.spheres.radius[j])


def pixel_rays():
    """Unit directions (N, N, 3) of the pixel-centre rays of the seed camera."""
    half = math.tan(math.radians(2 * math.degrees(math.atan(10 / 40))) / 2)
    c = (np.arange(N) + 0.5) / N * 2 - 1
    x, y = np.meshgrid(c * half, -c * half)
    d = np.stack([x, y, -np.ones_like(x)], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def ray_sphere(o, d, c, r):
    """Distance along rays ``d (..., 3)`` from ``o`` to the sphere, inf on a miss."""
    oc = o - c
    b = (d * oc).sum(-1)
    disc = b * b - ((oc * oc).sum(-1) - r * r)
    t = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def disc_mask(seed, material, shrink=0.6):
    """Pixels well inside the image of a sphere (its centre's projection, radius shrunk)."""
    _, c, r = sphere(seed, material)
    d = pixel_rays()
    t = ray_sphere(np.zeros(3), d, c, r * shrink)
    return np.isfinite(t)


def lum(a):
    return a @ np.array([0.2126, 0.7152, 0.0722])


def test_floor_is_a_checker(seed, img):
    d = pixel_rays()
    t = -15.0 / np.minimum(d[..., 1], -1e-9)
    p = d * t[..., None]
    hits_floor = d[..., 1] < 0
    # Away from the objects (front rows) and from cell edges (the texture is box-filtered).
    blocked = np.zeros((N, N), bool)
    for j in range(seed.spheres.center.shape[0]):
        c, r = np.asarray(seed.spheres.center[j], np.float64), float(seed.spheres.radius[j])
        blocked |= np.isfinite(ray_sphere(np.zeros(3), d, c, r + 1.0))
    tc = np.asarray(seed.tetrahedra.center[0], np.float64)
    blocked |= np.isfinite(ray_sphere(np.zeros(3), d, tc, float(seed.tetrahedra.size[0])))  # bounding spheres
    bc = 0.5 * np.asarray(seed.boxes.lo[0] + seed.boxes.hi[0], np.float64)
    blocked |= np.isfinite(ray_sphere(np.zeros(3), d, bc, float(np.linalg.norm(seed.boxes.hi[0] - seed.boxes.lo[0]))))
    # Cells are 5 units. The texture is box-filtered over the footprint: the sample's cone
    # width (distance x 0.5 / N) over max(cos(incidence), 1/4); keep pixels whose filter
    # box lies inside one cell.
    u, v = p[..., 0] / 5.0, -p[..., 2] / 5.0
    dist = np.linalg.norm(p, axis=-1)
    foot = dist * 0.5 / N / np.maximum(15.0 / dist, 0.25) / 5.0
    margin = 0.5 * foot + 0.02
    ok = (np.abs(u - np.round(u)) > margin) & (np.abs(v - np.round(v)) > margin)
    sel = hits_floor & ~blocked & (p[..., 2] > -85) & ok
    assert sel.sum() > 100, sel.sum()
    dark = ((np.floor(u) + np.floor(v)) % 2 == 1)[sel]
    L = lum(img[sel])
    assert dark.sum() > 40 and (~dark).sum() > 40
    assert np.median(L[~dark]) > 3 * np.median(L[dark])
    split = 0.5 * (np.median(L[~dark]) + np.median(L[dark]))
    assert np.mean((L < split) == dark) > 0.97


def test_big_sphere_is_light_purple_and_reflects(seed, img):
    j, c, r = sphere(seed, "purple_mirror")
    assert r == max(float(x) for x in seed.spheres.radius)  # the large one
    d = pixel_rays()
    inside = disc_mask(seed, "purple_mirror", 0.85)
    upper = (
        inside
        & (d[..., 1] > d[..., 1][inside].mean())
        & ~disc_mask(seed, "glass", 1.2)
        & ~disc_mask(seed, "planet", 1.2)
    )
    assert upper.sum() > 100
    rgb = np.median(img[upper], 0)
    assert rgb[2] > rgb[0] > rgb[1] and rgb[2] > 0.3  # blue > red > green: purple, and light
    assert rgb[1] > 0.1 and rgb[0] / rgb[2] > 0.5  # a pale (light) purple, not a deep violet
    # Reflection: without it the lower half (which mirrors the bright floor) changes a lot.
    k = seed.material_names.index("purple_mirror")
    matte = eqx.tree_at(lambda s: s.materials.reflectivity, seed, seed.materials.reflectivity.at[k].set(0.0))
    lower = (
        inside
        & (d[..., 1] < d[..., 1][inside].mean())
        & ~disc_mask(seed, "glass", 1.2)
        & ~disc_mask(seed, "planet", 1.2)
    )
    diff = np.abs(render(matte) - img).max(-1)
    assert np.median(diff[lower]) > 0.1
    assert img[lower].std(0).max() > 0.05  # the reflected checker and objects


def test_planet_is_textured(seed, img):
    m = disc_mask(seed, "planet", 0.7)
    assert m.sum() > 30
    L = lum(img[m])
    assert L.std() / L.mean() > 0.1  # not uniform
    rgb = np.median(img[m], 0)
    assert rgb[0] > rgb[1] > rgb[2]  # the warm (Mercury-like) tint of the moon image


def test_striped_sphere_is_green_and_black(seed, img):
    m = disc_mask(seed, "stripes", 0.8)
    px = img[m]
    green = (px[:, 1] > 0.15) & (px[:, 1] > 2 * px[:, 0]) & (px[:, 1] > 2 * px[:, 2])
    black = px.max(-1) < 0.06
    assert green.mean() > 0.2 and black.mean() > 0.15, (green.mean(), black.mean())


def test_glass_sphere_is_transparent_and_refracts(seed, img):
    m = disc_mask(seed, "glass", 0.8)
    k = seed.material_names.index("glass")
    flat = eqx.tree_at(lambda s: s.materials.ior, seed, seed.materials.ior.at[k].set(1.0))
    opaque = eqx.tree_at(lambda s: s.materials.transparency, seed, seed.materials.transparency.at[k].set(0.0))
    straight, solid = render(flat), render(opaque)
    # Refraction bends what is seen through it (n = 1.5 vs 1.0) ...
    assert np.median(np.abs(img - straight).max(-1)[m]) > 0.05
    # ... and it is see-through: the view through it is not the shading of an opaque white ball.
    assert np.median(np.abs(img - solid).max(-1)[m]) > 0.1
    # The purple sphere behind it is seen (upside down) through it.
    px = img[m]
    assert np.mean((px[:, 2] > px[:, 1] + 0.1) & (px[:, 0] > px[:, 1])) > 0.1


def test_cube_and_tetrahedron_are_there(seed, img):
    lo, hi = np.asarray(seed.boxes.lo[0], np.float64), np.asarray(seed.boxes.hi[0], np.float64)
    c = 0.5 * (lo + hi)
    col, row = (c[0] / -c[2] * 40 / 20 + 0.5) * N, (0.5 - c[1] / -c[2] * 40 / 20) * N
    cube = img[int(row), int(col)]
    assert cube[0] > 0.3 and cube[0] > 1.5 * cube[1] > 1.5 * cube[2]  # orange
    tc = np.asarray(seed.tetrahedra.center[0], np.float64)
    col, row = (tc[0] / -tc[2] * 2 + 0.5) * N, (0.5 - tc[1] / -tc[2] * 2) * N
    tet = img[int(row), int(col)]
    assert tet[0] > 0.3 and tet[1] > 0.3 and tet[2] < 0.5 * tet[1]  # yellow


def test_shadows_of_two_lights_overlap_darker(seed, img):
    """Floor below the floating planet: the ratio to a render without the planet is the
    fraction of light that still arrives, 1 (both lights), about 0.6 (one) or 0.27 (none,
    ambient only), matching the analytic occlusion of each light by the planet."""
    j, c, r = sphere(seed, "planet")
    away = eqx.tree_at(lambda s: s.spheres.center, seed, seed.spheres.center.at[j].set(jnp.float32([0, 0, 1e4])))
    ratio = lum(img) / np.maximum(lum(render(away)), 1e-6)

    d = pixel_rays()
    t = -15.0 / np.minimum(d[..., 1], -1e-9)
    p = d * t[..., None]
    sel = (d[..., 1] < 0) & ~np.isfinite(ray_sphere(np.zeros(3), d, c, r)) & (p[..., 2] > -115) & (p[..., 0] < 10)
    for k in range(seed.spheres.center.shape[0]):
        if k != j:  # nothing else in front of these floor points
            sel &= ~np.isfinite(
                ray_sphere(
                    np.zeros(3), d, np.asarray(seed.spheres.center[k], np.float64), float(seed.spheres.radius[k])
                )
            )
    lights = np.asarray(seed.lights.position, np.float64)
    I = np.asarray(seed.lights.intensity, np.float64)[:, 0]
    amb = float(seed.environment.ambient[0])
    blocked, cos = [], []
    for lp in lights:
        v = lp - p
        dist = np.linalg.norm(v, axis=-1)
        u = v / dist[..., None]
        tb = ray_sphere(p, u, c, r)
        blocked.append(tb < dist)
        cos.append(u[..., 1])
    blocked, cos = np.stack(blocked), np.stack(cos)
    lit = np.where(blocked, 0.0, I[:, None, None] * cos).sum(0)
    expected = (amb + lit) / (amb + (I[:, None, None] * cos).sum(0))
    n_blocked = blocked.sum(0)
    groups = {k: sel & (n_blocked == k) for k in (0, 1, 2)}
    assert groups[2].sum() >= 5 and groups[1].sum() >= 10 and groups[0].sum() >= 50, [
        int(g.sum()) for g in groups.values()
    ]
    med = {k: float(np.median(ratio[g])) for k, g in groups.items()}
    assert med[0] > 0.98 and 0.45 < med[1] < 0.75 and med[2] < 0.35, med
    # Pixel by pixel the rendered shadow matches the analytic one (a few edge pixels may differ).
    assert np.mean(np.abs(ratio[sel] - expected[sel]) < 0.03) > 0.95


def test_saved_and_loaded_seed_renders_identically(seed, img, tmp_path):
    """Round trip through save_scene/load_scene: equal leaves, the same compiled
    program (same static structure), the same pixels."""
    rt.save_scene(seed, tmp_path / "copy.toml")
    back = rt.load_scene(tmp_path / "copy.toml")
    assert back.settings == seed.settings and back.object_index == seed.object_index
    np.testing.assert_array_equal(render(back), img)
