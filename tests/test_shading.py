"""Shading against hand-computed values.

Every scene here is rendered once (module fixtures; float64 scenes so the
comparison is limited by the integrator's ray offsets, not by float32) and
compared pixel by pixel with an independent numpy computation of the documented
model (see the :mod:`raytrax.materials` docstring):

- classic: one sphere, one light: ``ambient + diffuse max(n.l, 0) + specular
  max(r.v, 0)^shininess`` (+ reflectivity x background for the escaping
  reflected ray);
- classic shadows: a floor under two lights with an opaque and transparent
  occluders (overlapping shadows darker; transparent ones lighter);
- physical: a floor, a diffuse sphere and a glass slab under one point light
  (``albedo / pi * I cos / r^2``; through the slab ``(1 - F)^2`` of it).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import camera_rays_np, ray_sphere_np

import raytrax as rt

F64 = jnp.float64


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _fresnel(cos_i, n1, n2):
    """Unpolarised Fresnel reflectance (textbook form, independent of raytrax)."""
    st = n1 / n2 * np.sqrt(np.maximum(1 - cos_i**2, 0))
    ct = np.sqrt(np.maximum(1 - st**2, 0))
    rs = (n1 * cos_i - n2 * ct) / (n1 * cos_i + n2 * ct)
    rp = (n2 * cos_i - n1 * ct) / (n2 * cos_i + n1 * ct)
    return np.where(st >= 1, 1.0, 0.5 * (rs**2 + rp**2))


# ============================================================================
# classic: one sphere, one light
# ============================================================================

CL = dict(position=(0.0, 0.0, 5.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=30.0)
CL_W = CL_H = 15  # odd: the centre pixel looks straight at the sphere centre
CL_AMB = np.array([0.1, 0.2, 0.3])
CL_BG = np.array([0.05, 0.1, 0.15])
CL_LIGHT = np.array([3.0, 4.0, 6.0])
CL_I = np.array([1.0, 0.9, 0.8])
CL_MAT = dict(color=(0.8, 0.5, 0.2), ambient=0.7, diffuse=0.9, specular=0.6, shininess=12.0)


def classic_sphere_scene(reflectivity):
    # max_depth=1: the reflected ray is traced once more and escapes to the background
    b = rt.SceneBuilder("classic", width=CL_W, height=CL_H, spp=1, max_depth=1, background=CL_BG, ambient=CL_AMB)
    b.camera(**CL)
    b.light(CL_LIGHT, intensity=CL_I)
    b.material("m", reflectivity=reflectivity, **CL_MAT)
    b.sphere((0.0, 0.0, 0.0), 1.0, "m")
    return b.build(F64)


@pytest.fixture(scope="module")
def classic_images():
    # same structure, different reflectivity: one compilation
    return {r: np.asarray(rt.render(classic_sphere_scene(r))) for r in (0.0, 0.5)}


def classic_sphere_reference(reflectivity):
    d = camera_rays_np(CL["position"], CL["look_at"], CL["up"], CL["fov"], CL_W, CL_H)
    o = np.asarray(CL["position"])
    t = ray_sphere_np(o, d, np.zeros(3), 1.0)
    hit = np.isfinite(t)
    p = o + np.where(hit, t, 0)[:, None] * d
    n = _unit(p)
    l = _unit(CL_LIGHT - p)
    ndl = (n * l).sum(1)
    r = -l + 2 * ndl[:, None] * n
    rv = (r * -d).sum(1)
    C = np.asarray(CL_MAT["color"])
    spec = np.where(ndl > 0, CL_MAT["specular"] * np.maximum(rv, 0) ** CL_MAT["shininess"], 0.0)
    local = CL_AMB * CL_MAT["ambient"] * C + CL_I * (
        CL_MAT["diffuse"] * C * np.maximum(ndl, 0)[:, None] + spec[:, None]
    )
    # the reflected ray of a convex sphere escapes to the background
    img = np.where(hit[:, None], local + reflectivity * CL_BG, CL_BG)
    return img.reshape(CL_H, CL_W, 3), hit.reshape(CL_H, CL_W)


def test_classic_sphere_centre_pixel_by_hand(classic_images):
    # hit (0, 0, 1), n = v = +z, l = (3, 4, 5)/sqrt(50): n.l = r.v = 1/sqrt(2)
    c = 1 / math.sqrt(2)
    C = np.array([0.8, 0.5, 0.2])
    want = CL_AMB * 0.7 * C + CL_I * (0.9 * C * c + 0.6 * c**12)
    px = classic_images[0.0][CL_H // 2, CL_W // 2]
    np.testing.assert_allclose(px, want, rtol=1e-4)
    np.testing.assert_allclose(classic_images[0.5][CL_H // 2, CL_W // 2], want + 0.5 * CL_BG, rtol=1e-4)


@pytest.mark.parametrize("refl", [0.0, 0.5])
def test_classic_sphere_whole_image(classic_images, refl):
    ref, hit = classic_sphere_reference(refl)
    img = classic_images[refl]
    assert img.dtype == np.float64 and img.shape == (CL_H, CL_W, 3)
    assert 40 < hit.sum() < CL_W * CL_H - 40
    np.testing.assert_array_equal(img[~hit], np.broadcast_to(CL_BG, img[~hit].shape))
    # atol: shadow rays start 1e-4 off the surface, which tilts l by ~1e-5
    np.testing.assert_allclose(img[hit], ref[hit], rtol=1e-4, atol=2e-4)
    # the specular highlight is really there (a pure diffuse model would miss it)
    assert img.max() > 0.9


def test_classic_light_behind_surface_gives_ambient_only(classic_images):
    ref, hit = classic_sphere_reference(0.0)
    d = camera_rays_np(CL["position"], CL["look_at"], CL["up"], CL["fov"], CL_W, CL_H)
    o = np.asarray(CL["position"])
    t = ray_sphere_np(o, d, np.zeros(3), 1.0)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    dark = (hit.ravel() & ((p * _unit(CL_LIGHT - p)).sum(1) < -0.05)).reshape(CL_H, CL_W)
    assert dark.sum() >= 3
    amb = CL_AMB * 0.7 * np.array([0.8, 0.5, 0.2])
    np.testing.assert_allclose(classic_images[0.0][dark], np.broadcast_to(amb, (dark.sum(), 3)), rtol=1e-9)


# ============================================================================
# classic: shadows from two lights (opaque and transparent occluders)
# ============================================================================

SH_CAM = dict(position=(3.0, 30.0, 0.0), look_at=(3.0, 0.0, 0.0), up=(0.0, 0.0, -1.0))
SH_W, SH_H = 39, 36  # 1/3 world unit per pixel on the floor
SH_FOV = 2 * math.degrees(math.atan(6.0 / 30.0))  # floor z in [-6, 6], x in [-3.5, 9.5]
SH_AMB = np.array([0.2, 0.2, 0.2])
SH_LIGHTS = [
    (np.array([2.0, 20.0, 0.0]), np.array([0.5, 0.5, 0.5])),
    (np.array([-2.0, 20.0, 0.0]), np.array([0.3, 0.3, 0.3])),
]
SH_FLOOR = np.array([0.9, 0.8, 0.7])
SH_T = 0.6  # transparency of the glass occluders
SPH_A = (np.array([0.0, 5.0, -3.0]), 1.0)  # opaque
SPH_B = (np.array([0.0, 5.0, 3.0]), 1.0)  # transparent
BOX_C = (np.array([5.0, 4.0, -4.0]), np.array([7.0, 6.0, -2.0]))  # transparent box
BOX_D = (np.array([5.0, 4.0, 2.0]), np.array([7.0, 6.0, 4.0]))  # the same cube as a 12-triangle mesh


def _cube_mesh(lo, hi):
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = [
        (0, 1, 3),
        (0, 3, 2),
        (4, 6, 7),
        (4, 7, 5),
        (0, 4, 5),
        (0, 5, 1),
        (2, 3, 7),
        (2, 7, 6),
        (0, 2, 6),
        (0, 6, 4),
        (1, 5, 7),
        (1, 7, 3),
    ]
    return v, np.asarray(f, np.int32)


@pytest.fixture(scope="module")
def shadow_image():
    # max_depth=0: only floor pixels are compared, and the floor has no specular children
    b = rt.SceneBuilder(
        "classic", width=SH_W, height=SH_H, spp=1, max_depth=0, background=(0.0, 0.0, 0.0), ambient=SH_AMB
    )
    b.camera(fov=SH_FOV, **SH_CAM)
    for p, i in SH_LIGHTS:
        b.light(p, intensity=i)
    b.material("floor", color=SH_FLOOR, ambient=1.0, diffuse=1.0, specular=0.0)
    b.material("opaque", color=(0.2, 0.3, 0.9), specular=0.0)
    b.material("glass", color=(1.0, 1.0, 1.0), transparency=SH_T, ior=1.5, specular=0.0)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere(SPH_A[0], SPH_A[1], "opaque")
    b.sphere(SPH_B[0], SPH_B[1], "glass")
    b.box(BOX_C[0], BOX_C[1], "glass")
    v, f = _cube_mesh(*BOX_D)
    b.mesh(v, f, "glass")
    scene = b.build(F64)
    assert scene.settings.branches == 2
    return np.asarray(rt.render(scene))


def _segment_sphere(p, q, c, r):
    """Surface crossings of segments p -> q (n, 3) with a sphere, and whether the
    segment comes within 1e-3 of the surface (ambiguous: excluded)."""
    d = q - p
    L = np.linalg.norm(d, axis=1)
    d = d / L[:, None]
    oc = p - c
    b = (d * oc).sum(1)
    roots = []
    for rr in (r, r - 1e-3, r + 1e-3):
        disc = b * b - ((oc * oc).sum(1) - rr * rr)
        sq = np.sqrt(np.maximum(disc, 0))
        n = ((disc > 0) & (-b - sq > 0) & (-b - sq < L)).astype(int) + ((disc > 0) & (-b + sq > 0) & (-b + sq < L))
        roots.append(n)
    amb = (roots[1] != roots[0]) | (roots[2] != roots[0])
    return roots[0], amb


def _segment_box(p, q, lo, hi):
    d = q - p
    out = []
    for s in (0.0, -1e-3, 1e-3):
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo - s - p) / d
            t2 = (hi + s - p) / d
        tn = np.minimum(t1, t2).max(1)
        tf = np.maximum(t1, t2).min(1)
        hit = tn <= tf
        out.append(hit * ((tn > 0) & (tn < 1)).astype(int) + hit * ((tf > 0) & (tf < 1)))
    return out[0], (out[1] != out[0]) | (out[2] != out[0])


def shadow_reference():
    """Floor radiance under the documented classic model: ambient + per light
    S diffuse C max(n.l, 0), S = product over crossed surfaces of their
    transparency (0 for the opaque sphere). Returns the image, a mask of floor
    pixels to compare, and per-light occluder classes."""
    o = np.asarray(SH_CAM["position"])
    d = camera_rays_np(o, SH_CAM["look_at"], SH_CAM["up"], SH_FOV, SH_W, SH_H)
    t_floor = -o[1] / d[:, 1]
    p = o + t_floor[:, None] * d
    # pixels whose camera ray meets an occluder first (or nearly) are not compared
    blocked = np.zeros(len(d), bool)
    for c, r in (SPH_A, SPH_B):
        n, amb = _segment_sphere(np.tile(o, (len(d), 1)), p, c, r)
        blocked |= (n > 0) | amb
    for lo, hi in (BOX_C, BOX_D):
        n, amb = _segment_box(np.tile(o, (len(d), 1)), p, lo, hi)
        blocked |= (n > 0) | amb
    img = np.tile(SH_AMB * SH_FLOOR, (len(d), 1))
    ok = ~blocked
    cls = []
    for lp, I in SH_LIGHTS:
        q = np.tile(lp, (len(d), 1))
        nA, aA = _segment_sphere(p, q, *SPH_A)
        nB, aB = _segment_sphere(p, q, *SPH_B)
        nC, aC = _segment_box(p, q, *BOX_C)
        nD, aD = _segment_box(p, q, *BOX_D)
        ok &= ~(aA | aB | aC | aD)
        S = np.where(nA > 0, 0.0, SH_T ** (nB + nC + nD))
        cos = _unit(lp - p)[:, 1]
        img = img + I * (S * cos)[:, None] * SH_FLOOR
        cls.append(dict(A=nA > 0, B=nB > 0, C=nC > 0, D=nD > 0))
    return (
        img.reshape(SH_H, SH_W, 3),
        ok.reshape(SH_H, SH_W),
        [{k: v.reshape(SH_H, SH_W) for k, v in c.items()} for c in cls],
    )


def test_classic_unshadowed_and_opaque_shadowed_floor_matches_reference(shadow_image):
    ref, ok, cls = shadow_reference()
    no_glass = ~(cls[0]["B"] | cls[0]["C"] | cls[0]["D"] | cls[1]["B"] | cls[1]["C"] | cls[1]["D"])
    m = ok & no_glass
    assert m.sum() > 500
    np.testing.assert_allclose(shadow_image[m], ref[m], rtol=1e-4, atol=1e-4)


def test_overlapping_shadows_are_darker_than_single_ones(shadow_image):
    _, ok, cls = shadow_reference()
    a1, a2 = cls[0]["A"] & ok, cls[1]["A"] & ok
    both, only1, only2 = a1 & a2, a1 & ~a2, a2 & ~a1
    lit = ok & ~(
        cls[0]["A"] | cls[1]["A"] | cls[0]["B"] | cls[1]["B"] | cls[0]["C"] | cls[1]["C"] | cls[0]["D"] | cls[1]["D"]
    )
    assert both.sum() >= 3 and only1.sum() >= 3 and only2.sum() >= 3
    lum = shadow_image.mean(-1)
    # only ambient where both lights are blocked
    np.testing.assert_allclose(shadow_image[both], np.broadcast_to(SH_AMB * SH_FLOOR, (both.sum(), 3)), rtol=1e-9)
    assert lum[both].max() < min(lum[only1].min(), lum[only2].min())
    assert max(lum[only1].max(), lum[only2].max()) < lum[lit].min()


def test_transparent_objects_cast_lighter_shadows(shadow_image):
    _, ok, cls = shadow_reference()
    lum = shadow_image.mean(-1)
    for k in ("B", "C", "D"):
        glass_both = cls[0][k] & cls[1][k] & ok
        opaque_both = cls[0]["A"] & cls[1]["A"] & ok
        assert glass_both.sum() >= 3
        assert lum[glass_both].min() > lum[opaque_both].max() + 0.05
        # and still darker than the unshadowed floor right next to it
        lit = ok & ~np.any([c[x] for c in cls for x in "ABCD"], axis=0)
        assert lum[glass_both].max() < lum[lit].min()


# Documented: "each crossing of an occluder's surface multiplies by its
# transparency", so a shadow ray through a closed transparent object (two
# crossings) carries T^2, whatever the primitive kind.


@pytest.mark.parametrize("occluder", ["B", "C"])
def test_transparent_sphere_and_box_shadow_transmission_is_T_squared(shadow_image, occluder):
    ref, ok, cls = shadow_reference()
    m = ok & (cls[0][occluder] | cls[1][occluder])
    assert m.sum() >= 5
    np.testing.assert_allclose(shadow_image[m], ref[m], rtol=1e-4, atol=1e-4)


def test_transparent_mesh_shadow_transmission_is_T_squared(shadow_image):
    ref, ok, cls = shadow_reference()
    m = ok & (cls[0]["D"] | cls[1]["D"])
    assert m.sum() >= 5
    np.testing.assert_allclose(shadow_image[m], ref[m], rtol=1e-4, atol=1e-4)


def test_transparent_box_and_identical_cube_mesh_cast_equal_shadows(shadow_image):
    """Box C and mesh D are the same cube 6 units apart in z under lights at z = 0:
    their shadows are mirror images in z (pixel rows are z), so they must match."""
    _, ok, cls = shadow_reference()
    c_rows = cls[0]["C"] | cls[1]["C"]
    d_rows = cls[0]["D"] | cls[1]["D"]
    both_ok = ok & ok[::-1]
    np.testing.assert_array_equal(c_rows[both_ok], d_rows[::-1][both_ok])  # the geometry is symmetric
    ab = cls[0]["A"] | cls[1]["A"] | cls[0]["B"] | cls[1]["B"]
    m = c_rows & both_ok & ~ab & ~ab[::-1]
    assert m.sum() >= 5
    np.testing.assert_allclose(shadow_image[m], shadow_image[::-1][m], rtol=1e-6)


# ============================================================================
# physical: floor, diffuse sphere and a glass slab under one point light
# ============================================================================

PH_CAM = dict(position=(0.0, 0.0, 10.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=40.0)
PH_W = PH_H = 21  # odd: the centre pixel looks straight down -z through the slab
PH_LIGHT = np.array([0.5, 0.3, 2.5])
PH_I = np.array([20.0, 16.0, 12.0])
PH_FLOOR = np.array([0.8, 0.6, 0.4])
PH_BALL = (np.array([2.0, -1.8, 1.0]), 0.8)
PH_BALL_ALBEDO = np.array([0.3, 0.7, 0.5])
PH_SLAB = (np.array([-0.9, -0.9, 4.0]), np.array([0.9, 0.9, 5.0]))
PH_IOR = 1.5


@pytest.fixture(scope="module")
def physical_scene():
    b = rt.SceneBuilder("physical", width=PH_W, height=PH_H, spp=1, max_depth=2)
    b.camera(**PH_CAM)
    b.light(PH_LIGHT, intensity=PH_I)
    b.material("floor", color=PH_FLOOR)
    b.material("ball", color=PH_BALL_ALBEDO)
    b.material("glass", color=(0.0, 0.0, 0.0), transparency=1.0, ior=PH_IOR)
    b.plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "floor")
    b.sphere(PH_BALL[0], PH_BALL[1], "ball")
    b.box(PH_SLAB[0], PH_SLAB[1], "glass")
    return b.build(F64)


@pytest.fixture(scope="module")
def physical_image(physical_scene):
    return np.asarray(rt.render(physical_scene))


def _direct(p, n, albedo):
    """albedo / pi * I * max(n.l, 0) / r^2 at points p (n, 3), with the ball's shadow;
    also a mask of points whose shadow ray grazes the ball (ambiguous)."""
    Lv = PH_LIGHT - p
    r2 = (Lv * Lv).sum(1)
    cos = (n * _unit(Lv)).sum(1)
    nb, amb = _segment_sphere(p + 2e-3 * n, np.tile(PH_LIGHT, (len(p), 1)), *PH_BALL)
    vis = (nb == 0) & (cos > 0)
    return albedo / math.pi * PH_I * np.where(vis, cos / r2, 0.0)[:, None], amb


def _first_hit_diffuse(o, d):
    """Radiance along rays that hit the floor or the ball (no glass in the way)."""
    n_rays = len(d)
    tb = ray_sphere_np(o, d, *PH_BALL)
    tf = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
    ball = tb < tf
    t = np.where(ball, tb, tf)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    n = np.where(ball[:, None], _unit(p - PH_BALL[0]), np.tile([0.0, 0.0, 1.0], (n_rays, 1)))
    alb = np.where(ball[:, None], PH_BALL_ALBEDO, PH_FLOOR)
    L, amb = _direct(p, n, alb)
    # silhouette of the ball: ambiguous
    near = np.isfinite(ray_sphere_np(o, d, PH_BALL[0], PH_BALL[1] + 1e-3)) != np.isfinite(
        ray_sphere_np(o, d, PH_BALL[0], PH_BALL[1] - 1e-3)
    )
    return np.where(np.isfinite(t)[:, None], L, 0.0), amb | near


def physical_reference():
    o = np.asarray(PH_CAM["position"])
    d = camera_rays_np(o, PH_CAM["look_at"], PH_CAM["up"], PH_CAM["fov"], PH_W, PH_H)
    O = np.tile(o, (len(d), 1))
    lo, hi = PH_SLAB
    # camera rays through the slab: enter the top face (z = 5), leave the bottom (z = 4)
    t_top = (hi[2] - o[2]) / d[:, 2]
    p_top = O + t_top[:, None] * d
    in_top = np.all((p_top[:, :2] > lo[:2] + 1e-3) & (p_top[:, :2] < hi[:2] - 1e-3), axis=1)
    cos_i = -d[:, 2]
    sin_t = np.sqrt(1 - cos_i**2) / PH_IOR
    cos_t = np.sqrt(1 - sin_t**2)
    tang = d.copy()
    tang[:, 2] = 0
    g = tang / PH_IOR
    g[:, 2] = -cos_t  # refracted direction (Snell, independent of raytrax's vector form)
    g = _unit(g)
    p_bot = p_top + ((hi[2] - lo[2]) / cos_t)[:, None] * g
    in_bot = np.all((p_bot[:, :2] > lo[:2] + 1e-3) & (p_bot[:, :2] < hi[:2] - 1e-3), axis=1)
    through = in_top & in_bot
    F1 = _fresnel(cos_i, 1.0, PH_IOR)
    F2 = _fresnel(cos_t, PH_IOR, 1.0)
    L_after, amb_after = _first_hit_diffuse(p_bot, d)  # a parallel slab leaves the direction unchanged
    L_direct, amb_direct = _first_hit_diffuse(O, d)
    img = np.where(through[:, None], ((1 - F1) * (1 - F2))[:, None] * L_after, L_direct)
    # rays that come anywhere near the slab but do not pass cleanly through its
    # top and bottom faces (side faces, edges) are not modelled here
    far = O + 100.0 * d
    n_slab, amb_slab = _segment_box(O, far, lo, hi)
    misses_slab = (n_slab == 0) & ~amb_slab
    ok = np.where(through, ~amb_after, misses_slab & ~amb_direct)
    return img.reshape(PH_H, PH_W, 3), ok.reshape(PH_H, PH_W), through.reshape(PH_H, PH_W)


def test_physical_glass_scene_keeps_two_branches(physical_scene):
    assert physical_scene.settings.branches == 2
    assert physical_scene.settings.shading == "physical"


def test_physical_floor_pixel_exact(physical_image):
    """A floor pixel seen directly: albedo / pi * I cos / r^2, by hand."""
    row, col = 2, 17  # upper right: floor, away from slab, ball and ball shadow
    d = camera_rays_np(PH_CAM["position"], PH_CAM["look_at"], PH_CAM["up"], PH_CAM["fov"], PH_W, PH_H)[row * PH_W + col]
    p = np.asarray(PH_CAM["position"]) + (10.0 / -d[2]) * d
    assert abs(p[2]) < 1e-12 and p[0] > 1.5 and p[1] > 1.5
    Lv = PH_LIGHT - p
    r2 = Lv @ Lv
    cos = Lv[2] / math.sqrt(r2)
    want = PH_FLOOR / math.pi * PH_I * cos / r2
    # rtol: shadow rays start ~1e-4 above the floor (the integrator's offset)
    np.testing.assert_allclose(physical_image[row, col], want, rtol=1e-3)


def test_physical_normal_incidence_through_glass_slab(physical_image):
    """Centre pixel: straight through the slab at normal incidence to the floor
    point (0, 0, 0): (1 - F0)^2 of the floor radiance, F0 = ((1 - n)/(1 + n))^2.
    (The eta^2 radiance factors of entering and leaving cancel.)"""
    F0 = ((1 - PH_IOR) / (1 + PH_IOR)) ** 2
    assert F0 == pytest.approx(0.04)
    r2 = PH_LIGHT @ PH_LIGHT
    L_floor = PH_FLOOR / math.pi * PH_I * (PH_LIGHT[2] / math.sqrt(r2)) / r2
    np.testing.assert_allclose(physical_image[PH_H // 2, PH_W // 2], (1 - F0) ** 2 * L_floor, rtol=1e-3)


def test_physical_image_matches_reference(physical_image):
    ref, ok, through = physical_reference()
    assert through.sum() >= 9 and ok.sum() > 300
    assert np.all(np.isfinite(physical_image))
    np.testing.assert_allclose(physical_image[ok], ref[ok], rtol=2e-3, atol=1e-6)


def test_physical_sphere_pixels_and_its_shadow(physical_image):
    """The diffuse ball seen directly, and its shadow on the floor (black: no ambient)."""
    ref, ok, _ = physical_reference()
    o = np.asarray(PH_CAM["position"])
    d = camera_rays_np(o, PH_CAM["look_at"], PH_CAM["up"], PH_CAM["fov"], PH_W, PH_H)
    ball = np.isfinite(ray_sphere_np(o, d, *PH_BALL)).reshape(PH_H, PH_W) & ok
    assert ball.sum() >= 6
    np.testing.assert_allclose(physical_image[ball], ref[ball], rtol=2e-3, atol=1e-6)
    shadow = ok & ~ball & (ref.sum(-1) == 0)
    assert shadow.sum() >= 2
    np.testing.assert_array_equal(physical_image[shadow], 0.0)
