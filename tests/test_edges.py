"""Edge (boundary) gradients: ``render(..., edge_gradients=True)``.

Plain automatic differentiation of the sampled image misses the terms that come
from edges moving over the image (silhouettes, hard-shadow boundaries). These
tests check the boundary term of :mod:`raytrax.edges`:

* against an analytic derivative (a flat-shaded quad sliding sideways, where
  plain AD gives exactly 0);
* against central finite differences of high-sample renders (light positions
  with two lights and several occluders, and the occluders' parameters: a sphere's
  centre and radius over a checkered floor, a box's position; a ball seen only in
  a mirror and the refractive index of a glass sphere), where plain AD is shown
  to be off;
* against central differences of jittered renders averaged over keys (a sphere's
  centre and radius in front of a checkered wall, lit from the side);
* for the unchanged image, the budget error, and finite gradients in
  degenerate configurations.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from golden import cases
from helpers import compiled_programs, jit_grad

import raytrax as rt
from raytrax import edges
from raytrax.testing import jittered_central_differences, smooth_weights

# In one worker with the golden test's gradients, which the finite-difference checks
# below reuse (tests/golden/cases.py).
pytestmark = pytest.mark.xdist_group(cases.GROUP)

# ---------------------------------------------------------------------------
# Analytic: a fronto-parallel quad with constant radiance over a black background.
# ---------------------------------------------------------------------------

QW, QH = 16, 12
ALBEDO = np.array([0.5, 0.25, 1.0])
AMBIENT = 0.8


@functools.cache
def quad_scene():
    """Camera at distance 10 with ``10 tan(fov / 2) = QH / 2``: one world unit at the
    quad is exactly one pixel. The quad spans x in [-2.3, 3.4] (pixel columns 5.7 to
    11.4) and y in [-3, 3] (pixel rows 3 to 9: its horizontal edges lie on sample-row
    boundaries for every grid size, so the row quadrature is exact). Classic shading
    with no light: the quad's radiance is the constant ``ambient * color``."""
    b = rt.SceneBuilder("classic", width=QW, height=QH, spp=4, max_depth=0, background=(0, 0, 0), ambient=(1, 1, 1))
    b.camera(position=(0.0, 0.0, 10.0), look_at=(0, 0, 0), fov=math.degrees(2 * math.atan(QH / 2 / 10)))
    b.material("q", color=tuple(ALBEDO), ambient=AMBIENT)
    b.quad([(-2.3, -3, 0), (3.4, -3, 0), (3.4, 3, 0), (-2.3, 3, 0)], "q")
    return b.build(jnp.float64)


@functools.cache
def box_scene():
    """:func:`quad_scene` with the quad the front face of a box one unit deep (its
    silhouette is that face: the camera, at x = y = 0, sees no side). A scene with a
    convex solid and no sphere, disk or light: the edge functions carry only the
    polygon and solid code (``raytrax.edges.Prims``)."""
    b = rt.SceneBuilder("classic", width=QW, height=QH, spp=4, max_depth=0, background=(0, 0, 0), ambient=(1, 1, 1))
    b.camera(position=(0.0, 0.0, 10.0), look_at=(0, 0, 0), fov=math.degrees(2 * math.atan(QH / 2 / 10)))
    b.material("q", color=tuple(ALBEDO), ambient=AMBIENT)
    b.box((-2.3, -3, -1), (3.4, 3, 0), "q")
    return b.build(jnp.float64)


# One edge budget for the spp-9 programs, so that the budget test and the unchanged-image
# test run the edge finder that test_sliding_quad_matches_analytic_derivative[9] compiled
# (the budget is static: another value is another compilation). At spp 9 (a 48 x 36
# sample grid) the quad has 70 sample pairs with an edge between them, DIAMOND 156.
QUAD_BUDGET = 100
DIAMOND = ((0.0, -5.7, 0.0), (7.7, 0.0, 0.0), (0.0, 5.7, 0.0), (-7.7, 0.0, 0.0))  # corners in the image


def _moment(shift, corners=None, **kw):
    """``sum_pixels column * image`` with the quad (or a quad with these ``corners``: the
    same compiled program) shifted by ``shift`` along x."""
    s = quad_scene()
    base = rt.parameters(s)["object[0].corners"] if corners is None else jnp.asarray(corners, jnp.float64)
    c = base + jnp.stack([shift, 0.0 * shift, 0.0 * shift])[None]
    img = rt.render(rt.with_parameters(s, {"object[0].corners": c}), **kw)
    col = jnp.arange(QW, dtype=img.dtype)[None, :, None]
    return jnp.sum(col * img)


@pytest.mark.parametrize("spp", [1, 9])
def test_sliding_quad_matches_analytic_derivative(spp):
    # Shifting the quad by dx moves its left edge (column 5) and right edge (column 11)
    # by dx pixels over 6 pixel rows: d/dx sum(col * I) = f * 6 * (11 - 5) per channel.
    exact = float(np.sum(AMBIENT * ALBEDO * 6 * (11 - 5)))
    zero = jnp.asarray(0.0, jnp.float64)
    budget = {"edge_budget": QUAD_BUDGET} if spp == 9 else {}  # spp 1: the default budget
    g_edge = float(jax.grad(lambda d: _moment(d, spp=spp, edge_gradients=True, **budget))(zero))
    g_plain = float(jax.grad(lambda d: _moment(d, spp=spp))(zero))
    assert g_plain == 0.0  # constant radiance: the interior term is zero, all of it is the edge
    # The rows quadrature is exact; what is left is where each of the four corners is
    # located along its edge, by bisection to 2^-(END_STEPS + 1) of the sample spacing h:
    # |error| <= f h 2^-(END_STEPS + 1) (11 + 11 + 5 + 5), against exact = 36 f.
    h = 1.0 / math.isqrt(spp)
    rtol = 2.0 ** -(edges.END_STEPS + 1) * h * (11 + 11 + 5 + 5) / 36
    np.testing.assert_allclose(g_edge, exact, rtol=rtol)


def test_gradient_of_a_vmapped_edge_render_matches_a_loop():
    # jax.grad of a jax.vmap of edge-mode renders (spp 1: the finder of
    # test_sliding_quad_matches_analytic_derivative[1] for the loop) is the sum of the
    # single gradients.
    offsets = jnp.asarray([0.0, 0.3], jnp.float64)
    zero = jnp.asarray(0.0, jnp.float64)
    batched = jax.grad(lambda d: jnp.sum(jax.vmap(lambda o: _moment(d + o, spp=1, edge_gradients=True))(offsets)))(zero)
    one = jax.grad(lambda d: _moment(d, spp=1, edge_gradients=True))
    loop = sum(one(o) for o in offsets)
    np.testing.assert_allclose(float(batched), float(loop), rtol=1e-9)
    assert abs(float(loop)) > 1.0


def test_sliding_box_matches_analytic_derivative():
    # As the quad above (spp 9): the box's silhouette is the quad's outline, found with the
    # solid's miss function (t_near - t_far) in place of the polygon's.
    def moment(shift, **kw):
        s = box_scene()
        p = rt.parameters(s)
        d = jnp.stack([shift, 0.0 * shift, 0.0 * shift])
        img = rt.render(
            rt.with_parameters(s, {"object[0].min": p["object[0].min"] + d, "object[0].max": p["object[0].max"] + d}),
            **kw,
        )
        return jnp.sum(jnp.arange(QW, dtype=img.dtype)[None, :, None] * img)

    exact = float(np.sum(AMBIENT * ALBEDO * 6 * (11 - 5)))
    zero = jnp.asarray(0.0, jnp.float64)
    g_edge = float(jax.grad(lambda d: moment(d, spp=9, edge_gradients=True, edge_budget=QUAD_BUDGET))(zero))
    rtol = 2.0 ** -(edges.END_STEPS + 1) * (1.0 / 3.0) * (11 + 11 + 5 + 5) / 36  # as the quad's at spp 9
    np.testing.assert_allclose(g_edge, exact, rtol=rtol)


def test_edge_mode_leaves_the_image_unchanged():
    s = quad_scene()
    a = np.asarray(rt.render(s, spp=9))
    # The same 3 x 3 grid per pixel; the spp-9 budget: the programs of
    # test_sliding_quad_matches_analytic_derivative[9], compiled once. An eager render
    # and an eager jax.grad run one compiled edge finder.
    jax.grad(lambda d: _moment(d, spp=9, edge_gradients=True, edge_budget=QUAD_BUDGET))(jnp.asarray(0.0, jnp.float64))
    with compiled_programs() as compiled:
        b = np.asarray(rt.render(s, spp=9, edge_gradients=True, edge_budget=QUAD_BUDGET))
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    assert "jit(_find)" not in compiled, compiled


def test_edge_budget_overflow_is_a_clear_error():
    # The program of test_sliding_quad_matches_analytic_derivative[9] (the same budget),
    # with a quad whose edges more sample pairs straddle than the budget allows.
    zero = jnp.asarray(0.0, jnp.float64)
    # Under an eager jax.grad the scene's values are concrete: a ValueError with the need.
    with pytest.raises(ValueError, match=r"edge_budget=100; this render needs at least 156"):
        jax.grad(lambda d: _moment(d, DIAMOND, spp=9, edge_gradients=True, edge_budget=QUAD_BUDGET))(zero)


def test_edge_pairs_counts_what_the_budget_must_hold():
    # The finder of test_sliding_quad_matches_analytic_derivative[9] (the same budget): at
    # spp 9 (a 48 x 36 sample grid) the quad's vertical edges (x = 5.7 and 11.4 pixels)
    # separate 18 pairs of samples each (the sample rows with y in (3, 9)) and its
    # horizontal edges (y = 3 and 9) 17 each (the sample columns with x in (5.7, 11.4)).
    assert rt.edge_pairs(quad_scene(), spp=9, edge_budget=QUAD_BUDGET) == 2 * 18 + 2 * 17
    diamond = rt.with_parameters(quad_scene(), {"object[0].corners": jnp.asarray(DIAMOND, jnp.float64)})
    with pytest.raises(ValueError, match="edge_budget"):
        rt.edge_pairs(diamond, spp=9, edge_budget=QUAD_BUDGET)
    # Inside an eager jax.grad of something else the scene's values are concrete: it runs.
    assert float(jax.grad(lambda x: x * rt.edge_pairs(quad_scene(), spp=9, edge_budget=QUAD_BUDGET))(1.0)) == 70.0
    with pytest.raises(TypeError, match="outside jax.jit"):
        jax.jit(lambda s: rt.edge_pairs(s, spp=9, edge_budget=QUAD_BUDGET))(quad_scene())


def test_bad_edge_options():
    s = quad_scene()
    with pytest.raises(ValueError, match="key=None"):
        rt.render(s, edge_gradients=True, key=jax.random.key(0))
    with pytest.raises(ValueError, match="edge_budget"):
        rt.render(s, edge_gradients=True, edge_budget=-3)


# ---------------------------------------------------------------------------
# Against finite differences of high-sample renders.
# ---------------------------------------------------------------------------

FW, FH = 16, 12
EDGE_SPP = 256  # the edge gradient's samples: a 16 x 16 grid per pixel
REF_SPP = 9216  # the reference: a 96 x 96 grid per pixel
STEP = 0.015  # world units: edges move 0.05-0.1 pixel, 5-10 of the reference's sample rows
# The reference has converged: against spp 16384 (128 x 128) at the same step and spp 9216 at
# half the step, every component asserted below agrees within 4 % (benchmarks/bench_edges.py
# prints both). The loss weights are smooth over the image (a per-pixel random weight makes the
# loss kink whenever an edge crosses a pixel boundary, so that no finite step converges).
RTOL = 0.05


def occluder_scene():
    """``scenes/edge_occluders.toml``: a checkered floor (filtered texture) under two lights,
    with a sphere, a box (lifted, rotated) and a tetrahedron casting shadows and silhouettes,
    16 x 12, spp 256, float64 (the benchmark loads the same file)."""
    s = cases.edge_scene("edge_occluders")
    assert (s.settings.width, s.settings.height, s.settings.spp) == (FW, FH, EDGE_SPP)
    return s


# The checked parameters: short name -> scene parameter, and "box", an offset that moves
# both of the box's corners (its derivative is the sum of theirs).
OCC_NAMES = {
    "light0": "light[0].position",
    "light1": "light[1].position",
    "center": "object[1].center",
    "radius": "object[1].radius",
}
BOX_CORNERS = ("object[2].min", "object[2].max")


def _occ_params():
    p = rt.parameters(occluder_scene())
    return {k: p[v] for k, v in OCC_NAMES.items()} | {"box": jnp.zeros(3, jnp.float64)}


def _occ_loss(q, **kw):
    s = occluder_scene()
    p = rt.parameters(s)
    moved = {v: q[k] for k, v in OCC_NAMES.items()} | {c: p[c] + q["box"] for c in BOX_CORNERS}
    return cases.weighted_mean(rt.with_parameters(s, moved), **kw)


def _occ_grad(edge):
    """The gradient of :func:`_occ_loss` at :func:`_occ_params`, from the golden case's
    gradient with respect to every parameter."""
    g = cases.gradient_case("edge_occluders", edge)
    return {k: g[v] for k, v in OCC_NAMES.items()} | {"box": sum(g[c] for c in BOX_CORNERS)}


@functools.cache
def _occ_table():
    """(name, component) -> (FD, edge, plain) for every parameter component."""
    q0 = _occ_params()
    g_edge, g_plain = _occ_grad(True), _occ_grad(False)
    ref = jax.jit(lambda q: _occ_loss(q, spp=REF_SPP))
    out = {}
    for name, v in q0.items():
        v = jnp.atleast_1d(v)
        for c in range(v.shape[0]):
            e = jnp.zeros_like(v).at[c].set(STEP).reshape(jnp.shape(q0[name]))
            fd = float((ref(q0 | {name: q0[name] + e}) - ref(q0 | {name: q0[name] - e})) / (2 * STEP))
            out[name, c] = (fd, float(np.atleast_1d(g_edge[name])[c]), float(np.atleast_1d(g_plain[name])[c]))
    return out


def _table_text(t):
    return "\n".join(
        f"{n}[{c}]: FD {fd:+.5f}  edge {ge:+.5f} ({(ge - fd) / fd:+.1%})  plain {gp:+.5f} ({(gp - fd) / fd:+.1%})"
        for (n, c), (fd, ge, gp) in t.items()
    )


# Known miss at spp 256 (see docs/gradients.md): the sphere centre's x component is 3 % of the
# largest centre component; jittered central differences put it at 0.000285 +- 0.000009 (the grid
# reference here says 0.00033). The edge estimate comes down with the samples, slowly but
# steadily: -86, -63, -41, -25 % at spp 256, 1024, 2304, 4096 (benchmarks/bench_edge_convergence.py).
KNOWN = {("center", 0)}


def test_edge_gradients_match_finite_differences_where_plain_ad_does_not():
    t = _occ_table()
    bad = [k for k, (fd, ge, _) in t.items() if k not in KNOWN and abs(ge - fd) > RTOL * abs(fd)]
    assert not bad, f"edge gradients off by more than 5 % in {bad}:\n{_table_text(t)}"
    # Plain AD misses the boundary terms: off by more than 20 % in some component of every parameter.
    for name in ("light0", "light1", "center", "radius", "box"):
        worst = max(abs(gp - fd) / abs(fd) for (n, _), (fd, _, gp) in t.items() if n == name)
        assert worst > 0.2, f"plain AD unexpectedly close for {name}:\n{_table_text(t)}"


@pytest.mark.xfail(
    reason="known miss at spp 256: the sphere centre's x (3 % of its largest component; "
    "-25 % at spp 4096); see docs/gradients.md",
    strict=False,
)
def test_known_misses_within_5_percent():
    t = _occ_table()
    bad = [k for k in KNOWN if abs(t[k][1] - t[k][0]) > RTOL * abs(t[k][0])]
    assert not bad, f"off by more than 5 % in {bad}:\n{_table_text(t)}"


def test_probe_radiance_per_light_matches_renders_with_one_light_on():
    """The probes' radiance (one trace per ray, each ray carrying one light's
    contribution or everything) against renders of the same scene with only that
    light on and no ambient or background (classic and physical shading, a mirror
    so that the light also arrives along reflected paths)."""
    from raytrax.renderer import RenderOptions
    from raytrax.renderer.edge_mode import radiance_at

    for shading in ("classic", "physical"):
        b = rt.SceneBuilder(
            shading, width=4, height=3, spp=1, max_depth=1, background=(0.3, 0.2, 0.1), ambient=(0.2, 0.25, 0.3)
        )
        b.camera(position=(0, 1, 5), look_at=(0, 0.3, 0), fov=40)
        b.light((2, 4, 3), intensity=(9.0, 8.0, 7.0) if shading == "physical" else (0.7, 0.6, 0.5))
        b.light((-3, 3, 1), intensity=(4.0, 5.0, 6.0) if shading == "physical" else (0.3, 0.4, 0.5))
        b.material("floor", color=(0.8, 0.8, 0.7))
        b.material("mirror", color=(0.1, 0.1, 0.1), reflectivity=0.6)
        b.plane((0, 0, 0), (0, 1, 0), "floor")
        b.sphere((0.3, 0.6, 0), 0.6, "mirror")
        s = b.build(jnp.float64)
        jj, ii = np.meshgrid(np.arange(4) + 0.5, np.arange(3) + 0.5)
        xy = jnp.asarray(np.stack([jj.ravel(), ii.ravel()]))  # pixel centres, row-major
        opts = RenderOptions(settings=s.settings)
        sel = jnp.asarray([0, 1, 2, 2, 1, 0, 0, 1, 2, 1, 2, 0], jnp.int32)  # 2: everything
        got = np.asarray(radiance_at(s, opts, xy, 1, sel))
        for k in range(3):
            q = {"render.background": jnp.zeros(3), "render.ambient": jnp.zeros(3)} if k < 2 else {}
            if k < 2:
                q[f"light[{1 - k}].intensity"] = jnp.zeros(3)
            want = np.asarray(rt.render(rt.with_parameters(s, q))).reshape(-1, 3)
            m = np.asarray(sel) == k
            assert np.allclose(got[m], want[m], rtol=1e-12, atol=1e-14), (shading, k, got[m], want[m])
        # Not trivially equal: light 0 alone lights most of its pixels, and less than everything.
        m0 = np.asarray(sel) == 0
        full = np.asarray(rt.render(s)).reshape(-1, 3)
        assert np.count_nonzero(got[m0].sum(1)) >= 3 and np.all(got[m0] < full[m0]), (got[m0], full[m0])


# ---------------------------------------------------------------------------
# A sphere over a textured wall: centre and radius against jittered differences.
# ---------------------------------------------------------------------------

SPHERE_KEYS = 64  # jitter keys averaged by the reference
SPHERE_STEP = 0.02  # world units: the silhouette moves 0.045 pixel


def test_sphere_centre_and_radius_over_a_textured_wall():
    """``scenes/edge_sphere.toml``: a Phong sphere in front of a hard-edged checkered
    wall, lit from the side, so that the terminator runs inside the silhouette and
    the sphere's shadow on the wall meets it (the silhouette's radiance beside it is
    ``f_s + a sqrt(distance)``, edges.py step 6). 8 x 6, edge gradients at spp 256.

    Reference: central differences of jittered renders (spp 4096, the same key on
    both sides) averaged over 64 keys, each an unbiased estimate of the difference
    quotient of the pixel-integrated image; its standard errors are 1.0, 0.2, 0.3
    and 0.1 % of the components, and at twice the step (0.04) none of them moves by
    more than 0.8 %. A grid reference is not used: on a regular grid a silhouette is
    sampled at phases that change slowly along it and the error does not average out.
    The silhouette's extreme points and the checker's lines are kept 0.25 pixel or
    more from pixel boundaries and from each other (3 steps): where one is tangent
    to the other, the pixel-integrated derivative goes as ``sqrt(distance)`` and no
    finite step converges. Measured edge errors: +0.8 %, +0.6 %, -0.6 %, +0.3 %
    (x, 6 % of the gradient's norm, was -3.2 % with the asymptotic silhouette
    correction, which a terminator just inside the silhouette breaks); plain AD is
    off by 79 % or more in every component (-174, +79, +121, +134 %)."""
    s0 = cases.edge_scene("edge_sphere")
    h, w_ = s0.settings.height, s0.settings.width
    assert (w_, h, s0.settings.spp) == (8, 6, EDGE_SPP)
    p0 = rt.parameters(s0)
    q0 = jnp.concatenate([p0["object[1].center"], p0["object[1].radius"][None]])

    def loss(q, **kw):
        return cases.weighted_mean(rt.with_parameters(s0, {"object[1].center": q[:3], "object[1].radius": q[3]}), **kw)

    def grad(edge):  # from the golden case's gradient with respect to every parameter
        g = cases.gradient_case("edge_sphere", edge)
        return np.concatenate([g["object[1].center"], g["object[1].radius"][None]])

    ref, se = jittered_central_differences(loss, q0, SPHERE_STEP, 4096, SPHERE_KEYS)
    g_edge, g_plain = grad(True), grad(False)
    text = (
        f"(centre x, y, z, radius)\nreference {ref} +- {se}\nedge {g_edge} ({(g_edge - ref) / np.abs(ref)})\n"
        f"plain {g_plain} ({(g_plain - ref) / np.abs(ref)})"
    )
    print(text)  # shown with pytest -s
    assert np.all(se < 0.015 * np.abs(ref)), text  # the reference is known to 1.5 %
    assert np.all(np.abs(g_edge - ref) <= RTOL * np.abs(ref)), text
    assert np.all(np.abs(g_plain - ref) > 0.5 * np.abs(ref)), text


# ---------------------------------------------------------------------------
# Edges seen in a mirror and through glass.
# ---------------------------------------------------------------------------

SW, SH = 24, 18
SPEC_RTOL = 0.15


@functools.cache
def specular_scene():
    """Physical shading, one light. A tilted mirror shows a ball that the camera does not
    see directly (outside the view); a glass sphere (ior 1.5) refracts the edges of a red
    stripe on the wall behind it; a degenerate (zero-area) triangle. 24 x 18, depth 2 (the
    glass needs two refractions)."""
    b = rt.SceneBuilder("physical", width=SW, height=SH, spp=EDGE_SPP, max_depth=2, background=(0.15, 0.15, 0.2))
    b.camera(position=(0.0, 1.2, 6.0), look_at=(0.0, 1.0, 0.0), fov=40)
    b.light((1.0, 4.0, 4.0), intensity=(25.0, 25.0, 25.0))
    b.material("wall", color=(0.7, 0.7, 0.7))
    b.material("red", color=(0.9, 0.15, 0.1))
    b.material("mirror", color=(0.0, 0.0, 0.0), reflectivity=0.95)
    b.material("ball", color=(0.2, 0.4, 0.9))
    b.material("glass", transparency=1.0, ior=1.5)
    b.quad([(-4, -1, -2), (4, -1, -2), (4, 4, -2), (-4, 4, -2)], "wall")
    b.quad([(-2.2, -0.5, -1.9), (-1.4, -0.5, -1.9), (-1.4, 3.0, -1.9), (-2.2, 3.0, -1.9)], "red")
    b.quad([(0.3, 0.0, -1.0), (2.6, 0.0, -1.5), (2.6, 2.4, -1.5), (0.3, 2.4, -1.0)], "mirror")
    b.sphere((4.2, 1.0, 3.0), 0.6, "ball")
    b.sphere((-1.4, 0.9, 0.5), 0.6, "glass")
    b.triangle([(1.0, 0.2, 1.0), (1.5, 0.2, 1.0), (1.5, 0.5, 1.0)], "ball")
    s = b.build(jnp.float64)
    # The builder refuses a zero-area triangle; a fit can still make one: collapse it.
    return rt.with_parameters(
        s, {"object[5].vertices": jnp.asarray([(1.0, 0.2, 1.0), (1.5, 0.2, 1.0), (2.0, 0.2, 1.0)], jnp.float64)}
    )


def test_edges_seen_in_a_mirror_and_through_glass():
    s = specular_scene()
    names = {"ball": "object[3].center", "ior": "material.glass.ior"}
    steps = {"ball": 0.015, "ior": 0.005}  # edges move 0.05-0.2 pixel
    p0 = rt.parameters(s)
    q0 = {k: p0[v] for k, v in names.items()}
    w = jnp.asarray(smooth_weights(SH, SW))

    def loss(p, **kw):
        return jnp.mean(w * rt.render(rt.with_parameters(s, p), **kw))

    # Every parameter at once: the gradients must be finite everywhere (grazing rays at
    # the spheres' silhouettes, total internal reflection inside the glass, the
    # zero-area triangle).
    g_edge = jax.grad(lambda p: loss(p, edge_gradients=True))(p0)
    g_plain = jit_grad(loss)(p0)
    for g in (g_edge, g_plain):
        bad = [k for k, v in g.items() if not np.all(np.isfinite(np.asarray(v)))]
        assert not bad, f"non-finite gradients: {bad}"
    ref = jax.jit(lambda q: loss(p0 | {names[k]: v for k, v in q.items()}, spp=REF_SPP))
    rows = []
    for k, name in names.items():
        v = jnp.atleast_1d(q0[k])
        for c in range(v.shape[0]):
            e = jnp.zeros_like(v).at[c].set(steps[k]).reshape(jnp.shape(q0[k]))
            fd = float((ref(q0 | {k: q0[k] + e}) - ref(q0 | {k: q0[k] - e})) / (2 * steps[k]))
            rows.append(
                (f"{k}[{c}]", fd, float(jnp.atleast_1d(g_edge[name])[c]), float(jnp.atleast_1d(g_plain[name])[c]))
            )
    text = "\n".join(
        f"{n}: FD {fd:+.3e}  edge {ge:+.3e} ({(ge - fd) / fd:+.1%})  plain {gp:+.3e}" for n, fd, ge, gp in rows
    )
    print(text)  # shown with pytest -s
    # The reference moves by up to 13 % (the ball's x, 5e-5) between this step and half of it,
    # hence 15 %; plain AD is off by 70 % or more in every component, with the wrong sign for the ball.
    assert all(abs(ge - fd) <= SPEC_RTOL * abs(fd) for _, fd, ge, _ in rows), text
    assert all(abs(gp - fd) > 0.5 * abs(fd) for _, fd, _, gp in rows), text
