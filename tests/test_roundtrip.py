"""Builder and scene file agree: every scene :class:`raytrax.SceneBuilder` accepts
saves (:func:`raytrax.save_scene`) and loads back (:func:`raytrax.load_scene`) equal,
values at the limits of :mod:`raytrax.limits` included, and both refuse the same
out-of-range values with the same message at the same key path.

No rendering: building, saving and loading only.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

import raytrax as rt
from raytrax import limits as L
from raytrax import scenefile as sf
from raytrax.shapes import KINDS

F32_MAX = float(np.finfo(np.float32).max)


def _below(x):
    """The largest float32 below ``x`` (a float32 value), as a float."""
    return float(np.nextafter(np.float32(x), np.float32(-np.inf)))


def _above(x):
    return float(np.nextafter(np.float32(x), np.float32(np.inf)))


# -----------------------------------------------------------------------------
# Comparing scenes
# -----------------------------------------------------------------------------


def assert_same_scene(a, b):
    """Equal named parameters (as stored), equal static structure and equal leaves."""
    pa, pb = rt.parameters(a), rt.parameters(b)
    assert list(pa) == list(pb)
    for k in pa:
        x, y = np.asarray(pa[k]), np.asarray(pb[k])
        assert x.dtype == y.dtype and x.shape == y.shape, k
        np.testing.assert_array_equal(x, y, err_msg=k)
    assert (a.settings, a.object_index, a.light_index, a.material_names, a.name) == (
        b.settings,
        b.object_index,
        b.light_index,
        b.material_names,
        b.name,
    )
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def roundtrip(scene, folder, stem="scene"):
    """Save ``scene`` in ``folder``, load it back and check it is the same scene, and
    that the loaded copy saves and loads as the same scene again; returns it."""
    path = os.path.join(folder, f"{stem}.toml")
    rt.save_scene(scene, path)
    back = rt.load_scene(path)
    assert_same_scene(scene, back)
    again = os.path.join(folder, f"{stem}.again.toml")
    rt.save_scene(back, again)
    assert_same_scene(scene, rt.load_scene(again))
    return back


# -----------------------------------------------------------------------------
# Strategies: values at, near and beyond the limits
# -----------------------------------------------------------------------------


def sometimes(good, bad):
    """Mostly ``good``, one time in ten ``bad`` (a value the builder refuses, so that
    refusals are exercised without discarding most scenes)."""
    return st.integers(0, 9).flatmap(lambda i: bad if i == 5 else good)


def in_range(rng: L.Range, typical=(0.0, 10.0)):
    """Numbers of ``rng``: its closed ends and the float32 numbers just inside, ordinary
    values; sometimes an open end or the float32 number just outside (for an unbounded
    range: the largest float32, and outside it 1e39, finite only in float64)."""
    inside, outside = [], []
    for end, is_open, inward, outward in ((rng.lo, rng.lo_open, _above, _below), (rng.hi, rng.hi_open, _below, _above)):
        if end is not None:
            inside.append(inward(end))
            (outside if is_open else inside).append(float(end))
            outside.append(outward(end))
    if rng.hi is None:
        inside += [1e6, F32_MAX]
        outside.append(1e39)  # refused by build(): infinite once stored in float32
    lo = rng.lo if rng.lo is not None else -1e6
    hi = rng.hi if rng.hi is not None else max(typical[1], lo + 1.0)
    good = st.one_of(
        st.sampled_from(inside),
        st.floats(max(lo, typical[0]), min(hi, typical[1]), exclude_min=rng.lo_open, exclude_max=rng.hi_open),
        st.floats(lo, hi, exclude_min=rng.lo_open, exclude_max=rng.hi_open),
    )
    return sometimes(good, st.sampled_from(outside))


def rgb(rng: L.Range):
    """An RGB triple or a grey number, components at and near the ends of ``rng``."""
    comp = st.one_of(st.sampled_from([0.0, 1.0, _below(1.0), 0.5, -0.0, 2.0]), in_range(rng, (0.0, 1.0)))
    return st.one_of(comp, st.tuples(comp, comp, comp))


coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(coord, coord, coord)
# Directions and normals: non-zero and not so small that float32 rounds them to zero
# (that is the object/light registry's business; see test_known_registry_gaps).
direction = st.tuples(*[st.floats(-10, 10)] * 3).map(lambda v: v if max(map(abs, v)) >= 1e-3 else (0.0, 0.0, 1.0))
size = st.one_of(st.sampled_from([1e-3, 1.0, 1e3]), st.floats(1e-3, 1e3))
color_any = st.one_of(st.sampled_from([0.0, 1.0, 2.0, F32_MAX]), st.floats(0, 1e6))


@st.composite
def image(draw, physical):
    h, w = draw(st.integers(1, 3)), draw(st.integers(1, 3))
    hi = 1.0 if physical else 4.0
    vals = draw(st.lists(st.floats(0.0, hi, width=32), min_size=h * w * 3, max_size=h * w * 3))
    return np.asarray(vals, np.float32).reshape(h, w, 3)


@st.composite
def texture(draw, shading):
    kind = draw(st.sampled_from(["none", "checker", "stripes", "image"]))
    cr = L.material_ranges(shading)["color"]
    if kind == "none":
        return None
    if kind == "image":
        return rt.ImageTexture(draw(image(shading == "physical")), "generated")
    c2 = draw(rgb(cr))
    scale = draw(st.one_of(st.sampled_from([1e-3, 1.0, 1e3]), in_range(L.TEXTURE_SCALE, (1e-3, 100.0))))
    if kind == "checker":
        return rt.Checker(color2=c2, scale=scale)
    d = draw(
        sometimes(
            st.one_of(st.sampled_from([(0.0, 1.0), (1.0, 0.0), (1.0, 1.0), (-1e-30, 0.0)]), st.tuples(coord, coord)),
            st.just((0.0, 0.0)),
        )
    )
    return rt.Stripes(color2=c2, scale=scale, direction=d)


name_text = st.text(alphabet="abcXYZ09_- .\"'\\é\t\nΩ", max_size=6)


@st.composite
def material_kwargs(draw, shading):
    ranges = L.material_ranges(shading)
    kw = {}
    for k in ("color", "reflectivity"):
        if draw(st.booleans()):
            kw[k] = draw(rgb(ranges[k]))
    for k in ("ambient", "diffuse", "specular", "shininess", "transparency", "ior"):
        if draw(st.booleans()):
            kw[k] = draw(in_range(ranges[k], (0.0, 10.0)))
    kw["texture"] = draw(texture(shading))
    return kw


@st.composite
def quad_corners(draw):
    """A planar convex quad: a rectangle or parallelogram in an axis-aligned plane
    (the same coordinate for all four corners, so float32 rounding keeps it planar)."""
    axis = draw(st.integers(0, 2))
    at = draw(coord)
    u0, v0 = draw(coord), draw(coord)
    du, dv, shear = draw(size), draw(size), draw(st.floats(-0.5, 0.5))
    pts2 = [(u0, v0), (u0 + du, v0), (u0 + du + shear * du, v0 + dv), (u0 + shear * du, v0 + dv)]
    if draw(st.booleans()):
        pts2 = pts2[::-1]

    def lift(u, v):
        p = [u, v]
        p.insert(axis, at)
        return tuple(p)

    return [lift(u, v) for u, v in pts2]


@st.composite
def triangle_vertices(draw):
    """Three vertices of a well-shaped triangle (no float32 rounding makes it degenerate)."""
    c = np.asarray(draw(vec3))
    e1 = np.asarray(draw(direction))
    e2 = np.asarray(draw(direction))
    s = draw(size)
    n = np.cross(e1, e2)
    assume(np.linalg.norm(n) > 0.1 * np.linalg.norm(e1) * np.linalg.norm(e2))
    return [tuple(c), tuple(c + s * e1), tuple(c + s * e2)]


def object_params(kind, draw):
    """Parameters of an object of ``kind`` (one of raytrax.shapes.KINDS)."""
    if kind == "sphere":
        return dict(center=draw(vec3), radius=draw(size))
    if kind == "plane":
        return dict(point=draw(vec3), normal=draw(direction))
    if kind == "quad":
        return dict(corners=draw(quad_corners()))
    if kind == "disk":
        return dict(center=draw(vec3), normal=draw(direction), radius=draw(size))
    if kind == "triangle":
        return dict(vertices=draw(triangle_vertices()))
    if kind == "tetrahedron":
        return dict(center=draw(vec3), size=draw(size))
    if kind == "mesh":
        nv = draw(st.integers(3, 6))
        v = np.asarray(draw(st.lists(vec3, min_size=nv, max_size=nv)))
        f = np.asarray(draw(st.lists(st.tuples(*[st.integers(0, nv - 1)] * 3), min_size=1, max_size=4)))
        return dict(vertices=v, faces=f)
    if kind == "box":
        lo = np.asarray(draw(vec3))
        ext = np.asarray(draw(st.tuples(size, size, size)))
        p = dict(min=tuple(lo), max=tuple(lo + ext))
        if draw(st.booleans()):
            p["rotation"] = draw(st.tuples(*[st.floats(-360, 360)] * 3))
        return p
    raise AssertionError(f"no strategy for kind {kind!r}: add one")


KINDS_WITH_A_STRATEGY = {"sphere", "plane", "quad", "disk", "triangle", "tetrahedron", "mesh", "box"}


def test_every_kind_has_a_strategy():
    assert {k.name for k in KINDS} <= KINDS_WITH_A_STRATEGY, "add the new kind to object_params"


def _try(what, op, *a, **kw):
    """Apply one builder call; a ValueError (a refused value) leaves the builder as it
    was. ``what`` names the call in the statistics (``--hypothesis-show-statistics``)."""
    try:
        op(*a, **kw)
    except ValueError:
        event(f"refused: {what}")
        return False
    event(f"accepted: {what}")
    return True


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large],
)
@given(st.data())
def test_every_scene_the_builder_accepts_round_trips(data):
    draw = data.draw
    shading = draw(st.sampled_from(L.SHADING_MODELS))
    render = {}
    side, spp, depth = L.LIMITS["side"], L.LIMITS["spp"], L.LIMITS["max_depth"]
    if draw(st.booleans()):
        render["width"] = draw(sometimes(st.sampled_from([1, 7, 640, side]), st.sampled_from([side + 1, 0])))
        # 65536 x 1525 is under the limit of pixels, 65536 x 1526 over it
        render["height"] = draw(sometimes(st.sampled_from([1, 5, 480, 1525]), st.just(1526)))
    if draw(st.booleans()):
        render["spp"] = draw(sometimes(st.sampled_from([1, 4, 9, spp]), st.sampled_from([spp - 1, 33**2, 0])))
    if draw(st.booleans()):
        render["max_depth"] = draw(sometimes(st.sampled_from([0, 1, 5, depth]), st.sampled_from([depth + 1, -1])))
    if draw(st.booleans()):
        render["filter_textures"] = draw(st.booleans())
    for k in ("background", "ambient"):
        if draw(st.booleans()):
            render[k] = draw(st.one_of(rgb(L.ENVIRONMENT_RGB), color_any))
    name = draw(st.one_of(st.just("scene"), name_text))
    try:
        b = rt.SceneBuilder(shading, name=name, **render)
    except ValueError:
        event("refused: render settings")
        assume(False)
        return

    if draw(st.booleans()):
        fov = draw(
            sometimes(
                st.one_of(
                    st.sampled_from([L.SEED_FOV, 1e-3, _below(180.0), 90.0]),
                    st.floats(0.0, 180.0, exclude_min=True, exclude_max=True),
                ),
                st.sampled_from([179.9999999, 180.0, 0.0, 1e-46]),  # 179.9999999 and 1e-46: refused by build()
            )
        )
        _try("camera", b.camera, draw(vec3), draw(vec3), draw(st.one_of(st.just((0.0, 1.0, 0.0)), direction)), fov)

    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            _try("point light", b.light, draw(vec3), intensity=draw(color_any))
        else:
            _try(
                "directional light",
                b.directional_light,
                draw(direction),
                irradiance=draw(st.tuples(color_any, color_any, color_any)),
            )

    names = []
    for _ in range(draw(st.integers(1, 4))):
        mname = draw(st.one_of(st.sampled_from(["m", "glass", "my glass", ""]), name_text))
        kw = draw(material_kwargs(shading))
        tex = type(kw["texture"]).__name__ if kw["texture"] is not None else "no texture"
        if _try(f"{shading} material ({tex})", b.material, mname, **kw):
            names.append(mname)
    assume(names)

    for _ in range(draw(st.integers(0, 8))):
        kind = draw(st.sampled_from([k.name for k in KINDS]))
        params = object_params(kind, draw)
        mat = draw(st.sampled_from(names))
        if kind == "mesh" or draw(st.booleans()):
            _try(kind, b.add, kind, mat, **params)
        else:
            _try(kind, getattr(b, kind), material=mat, **params)

    try:
        scene = b.build()
    except ValueError as e:
        event(f"refused by build(): {str(e).split(':')[0]}")
        assume(False)
        return
    with tempfile.TemporaryDirectory() as folder:
        roundtrip(scene, folder)


# -----------------------------------------------------------------------------
# Values exactly at the limits
# -----------------------------------------------------------------------------


@pytest.mark.parametrize("max_depth", [0, L.LIMITS["max_depth"]])
def test_physical_values_at_the_limits_round_trip(tmp_path, max_depth):
    b = rt.SceneBuilder(
        "physical",
        width=L.LIMITS["side"],
        height=L.LIMITS["pixels"] // L.LIMITS["side"],
        spp=L.LIMITS["spp"],
        max_depth=max_depth,
        background=0.0,
        ambient=(0.0, 0.0, 0.0),
        filter_textures=False,
        name="limits",
    )
    b.camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), _below(180.0))
    b.light((0.0, 5.0, 0.0), intensity=0.0)
    b.directional_light((0.0, -1.0, 0.0), irradiance=(F32_MAX, 0.0, 1.0))
    b.material("white", color=1.0, reflectivity=(0.0, 0.0, 0.0), transparency=0.0)
    b.material("black", color=(0.0, 0.0, 0.0), reflectivity=1.0, ambient=0.0, diffuse=0.0, specular=0.0)
    b.material("glass", color=(1.0, 0.0, 1.0), transparency=1.0, ior=1.0, shininess=0.0)
    b.material("dense", color=(0.0, 1.0, 0.0), transparency=1.0, ior=10.0, reflectivity=(1.0, 0.0, 1.0))
    b.material("tiles", color=1.0, texture=rt.Checker(color2=(1.0, 1.0, 1.0), scale=float(np.float32(1e-30))))
    b.material("stripes", color=0.0, texture=rt.Stripes(color2=0.0, scale=F32_MAX, direction=(0.0, 1e-30)))
    b.material("poster", texture=rt.ImageTexture(np.array([[[0.0, 1.0, 0.5]]], np.float32)))
    for k, m in enumerate(["white", "black", "glass", "dense", "tiles", "stripes", "poster"]):
        b.sphere((float(k), 0.0, -5.0), 0.5, m)
    scene = b.build()
    assert scene.settings.spp == L.LIMITS["spp"] and scene.settings.max_depth == max_depth
    back = roundtrip(scene, str(tmp_path))
    assert float(back.materials.transparency[2]) == 1.0 and float(back.materials.ior[2]) == 1.0
    np.testing.assert_array_equal(back.materials.color[0], [1.0, 1.0, 1.0])


def test_classic_values_at_the_limits_round_trip(tmp_path):
    b = rt.SceneBuilder("classic", width=1, height=1, spp=1, max_depth=0, background=F32_MAX, ambient=0.0)
    b.camera(fov=float(np.float32(1e-30)))  # the smallest field of view is any positive float32
    b.material(
        "bright",
        color=(F32_MAX, 2.0, 0.0),
        ambient=F32_MAX,
        diffuse=0.0,
        specular=F32_MAX,
        shininess=F32_MAX,
        reflectivity=(0.0, F32_MAX, 1.5),
        transparency=_below(1.0),
        ior=_below(10.0),
    )
    b.material("hdr", texture=rt.ImageTexture(np.full((2, 1, 3), 4.0, np.float32)))
    b.sphere((0.0, 0.0, -5.0), 1.0, "bright")
    b.quad([(0, 0, -1), (1, 0, -1), (1, 1, -1), (0, 1, -1)], "hdr")
    roundtrip(b.build(), str(tmp_path))


def test_names_that_need_quoting_round_trip(tmp_path):
    """Material and scene names are TOML keys and strings: quoted unless bare (a
    trailing newline once passed for bare and wrote an invalid file)."""
    names = ["0\n", "my glass", "", 'a"b', "x\\y", "tab\there", "é", "a.b", "plain-name_1"]
    b = rt.SceneBuilder(name="line\nbreak")
    for k, n in enumerate(names):
        b.material(n, color=0.1 * k)
        b.sphere((float(k), 0.0, -5.0), 0.5, n)
    back = roundtrip(b.build(), str(tmp_path))
    assert back.material_names == tuple(names) and back.name == "line\nbreak"


def test_one_default_size_and_camera_for_builder_and_file(tmp_path):
    b = rt.SceneBuilder()
    b.material("m")
    built = b.build()
    path = tmp_path / "defaults.toml"
    path.write_text("[material.m]\n")
    loaded = rt.load_scene(path)
    assert (
        (built.settings.width, built.settings.height)
        == (L.RENDER_DEFAULTS.width, L.RENDER_DEFAULTS.height)
        == (640, 480)
    )
    assert built.settings == loaded.settings == rt.Settings(branches=1)
    for k in ("position", "look_at", "up", "fov"):
        np.testing.assert_array_equal(getattr(built.camera, k), getattr(loaded.camera, k))
    assert float(built.camera.fov) == np.float32(L.SEED_FOV)
    b.camera()  # the camera() defaults are the same camera
    np.testing.assert_array_equal(b.build().camera.fov, built.camera.fov)
    assert sf.MaterialDesc() == sf.MaterialDesc(**dataclasses.asdict(L.MATERIAL_DEFAULTS))


def test_builder_refuses_values_that_round_out_of_range_when_stored():
    """A value fine in float64 but not once rounded to float32 (what the file holds)."""
    b = rt.SceneBuilder()
    b.material("m")
    b.camera(fov=179.9999999)
    with pytest.raises(ValueError, match=r"^camera\.fov: .*got 180\.0 \(the value as stored in float32\)$"):
        b.build()
    b.camera(fov=30.0)
    b.material("big", color=1e39)
    with pytest.raises(ValueError, match=r"^material\.big\.color: expected finite numbers, got \[inf, inf, inf\]"):
        b.build()
    b = rt.SceneBuilder()
    b.material("m", texture=rt.Checker(scale=1e-50))
    with pytest.raises(ValueError, match=r"^material\.m\.texture\.scale: expected a positive number, got 0\.0 \("):
        b.build()


# -----------------------------------------------------------------------------
# The same refusal from the builder and from a file
# -----------------------------------------------------------------------------

SCENE = """\
shading = "{shading}"

[render]
width = {width}
height = {height}
spp = {spp}
max_depth = {max_depth}
background = {background}

[camera]
fov = {fov}

[[light]]
position = [0.0, 5.0, 0.0]

[material.{mname}]
{material}

[[object]]
type = "sphere"
material = {mref}
center = [0.0, 0.0, -5.0]
radius = 1.0
"""

BASE = dict(
    shading="classic",
    width=8,
    height=6,
    spp=1,
    max_depth=1,
    background=0.0,
    fov=30.0,
    mname="red",
    material={},
    texture=None,
)


def _toml(v):
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    if isinstance(v, str):
        return L.toml_string(v)
    return repr(v)


def file_message(tmp_path, case):
    c = BASE | case
    mat = dict(c["material"])
    lines = [f"{k} = {_toml(v)}" for k, v in mat.items()]
    if c["texture"] is not None:
        lines.append(f"texture = {_toml(c['texture'])}")
    text = SCENE.format(
        **{k: c[k] for k in ("shading", "width", "height", "spp", "max_depth", "fov")},
        background=_toml(c["background"]),
        mname=L.toml_key(c["mname"]),
        mref=L.toml_string(c["mname"]),
        material="\n".join(lines),
    )
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(rt.SceneError) as e:
        rt.load_scene(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ")
    return msg[len(f"{path}: ") :]


def builder_message(case):
    c = BASE | case
    tex = c["texture"]
    if tex is not None:
        kind = tex["kind"]
        kw = {k: v for k, v in tex.items() if k != "kind"}
        tex = rt.Checker(**kw) if kind == "checker" else rt.Stripes(**kw)
    with pytest.raises(ValueError) as e:
        b = rt.SceneBuilder(
            c["shading"],
            width=c["width"],
            height=c["height"],
            spp=c["spp"],
            max_depth=c["max_depth"],
            background=c["background"],
        )
        b.camera(fov=c["fov"])
        b.light((0.0, 5.0, 0.0))
        b.material(c["mname"], texture=tex, **c["material"])
        b.sphere((0.0, 0.0, -5.0), 1.0, c["mname"])
        b.build()
    return str(e.value)


PHYS = dict(shading="physical")
SAME_REFUSAL = {
    "physical color": (PHYS | dict(material=dict(color=(2.0, 1.0, 1.0))), "material.red.color"),
    "physical color, grey": (PHYS | dict(material=dict(color=1.5)), "material.red.color"),
    "physical color, one ulp over": (PHYS | dict(material=dict(color=(0.0, _above(1.0), 0.0))), "material.red.color"),
    "physical reflectivity": (PHYS | dict(material=dict(reflectivity=(0.5, 1.25, 0.0))), "material.red.reflectivity"),
    "negative color": (dict(material=dict(color=(0.5, -0.5, 0.5))), "material.red.color"),
    "transparency": (dict(material=dict(transparency=1.5)), "material.red.transparency"),
    "negative transparency": (dict(material=dict(transparency=-0.25)), "material.red.transparency"),
    "ior below 1": (dict(material=dict(ior=0.5)), "material.red.ior"),
    "ior above 10": (dict(material=dict(ior=10.5)), "material.red.ior"),
    "shininess": (dict(material=dict(shininess=-1.0)), "material.red.shininess"),
    "ambient": (dict(material=dict(ambient=-0.5)), "material.red.ambient"),
    "quoted material name": (dict(mname="my glass", material=dict(ior=0.0)), 'material."my glass".ior'),
    "texture scale": (dict(texture=dict(kind="checker", scale=0.0)), "material.red.texture.scale"),
    "physical texture color2": (
        PHYS | dict(texture=dict(kind="stripes", color2=(1.5, 0.0, 0.0))),
        "material.red.texture.color2",
    ),
    "stripes direction": (dict(texture=dict(kind="stripes", direction=(0.0, 0.0))), "material.red.texture.direction"),
    "shading": (dict(shading="clasic"), "shading"),
    "fov 180": (dict(fov=180.0), "camera.fov"),
    "fov 0": (dict(fov=0.0), "camera.fov"),
    "background": (dict(background=(0.0, -1.0, 0.0)), "render.background"),
    "width 0": (dict(width=0), "render.width"),
    "width over the limit": (dict(width=L.LIMITS["side"] + 1), "render.width"),
    "too many pixels": (dict(width=20000, height=20000), "render"),
    "spp not square": (dict(spp=3), "render.spp"),
    "spp over the limit": (dict(spp=2048), "render.spp"),
    "max_depth over the limit": (dict(max_depth=L.LIMITS["max_depth"] + 1), "render.max_depth"),
    "max_depth negative": (dict(max_depth=-1), "render.max_depth"),
}


@pytest.mark.parametrize("case,path", SAME_REFUSAL.values(), ids=list(SAME_REFUSAL))
def test_builder_and_file_refuse_the_same_value_with_the_same_message(tmp_path, case, path):
    from_file = file_message(tmp_path, case)
    from_builder = builder_message(case)
    assert from_file.startswith(f"{path}: expected "), from_file
    assert from_builder == from_file


def test_builder_and_file_share_the_count_limits(tmp_path, monkeypatch):
    monkeypatch.setitem(L.LIMITS, "lights", 1)
    assert sf.LIMITS is L.LIMITS
    text = SCENE.format(
        **{k: BASE[k] for k in ("shading", "width", "height", "spp", "max_depth", "fov")},
        background="0.0",
        mname="red",
        mref='"red"',
        material="",
    )
    path = tmp_path / "s.toml"
    path.write_text(text + "\n[[light]]\nposition = [1.0, 1.0, 1.0]\n")
    with pytest.raises(rt.SceneError) as e:
        rt.load_scene(path)
    b = rt.SceneBuilder()
    b.light((0, 5, 0)).light((1, 1, 1)).material("red")
    with pytest.raises(ValueError) as e2:
        b.build()
    assert str(e.value) == f"{path}: {e2.value}" == f"{path}: light: expected at most 1 lights, got 2"


# -----------------------------------------------------------------------------
# Values the file refuses are refused by the object and light registries' builder
# checks too (raytrax/shapes, raytrax/lights), also where float32 storage rounds them.
# -----------------------------------------------------------------------------

REFUSED = {
    "negative light intensity": (lambda b: b.light((0.0, 5.0, 0.0), intensity=-1.0), "light[0].intensity"),
    "directional light direction that rounds to zero": (
        lambda b: b.directional_light((1e-50, 0.0, 0.0)),
        "light[0].direction",
    ),
    "sphere radius that rounds to zero": (lambda b: b.sphere((0.0, 0.0, -5.0), 1e-50, "m"), "object[0].radius"),
    "sphere centre beyond float32": (lambda b: b.sphere((1e39, 0.0, -5.0), 1.0, "m"), "object[0].center"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_registry_builder_refuses_what_the_file_refuses(case):
    add, key = REFUSED[case]
    b = rt.SceneBuilder()
    b.material("m")
    with pytest.raises(ValueError) as e:
        add(b)
    assert str(e.value).startswith(key + ":"), str(e.value)


def test_the_issue_example_is_refused_by_the_builder():
    """``color=(2, 1, 1)`` in physical shading was built and rendered, then saved to a
    file that would not load."""
    b = rt.SceneBuilder("physical")
    with pytest.raises(ValueError) as e:
        b.material("red", color=(2, 1, 1))
    assert str(e.value) == (
        "material.red.color: expected an [r, g, b] array of numbers in [0, 1] in physical shading "
        "(or one number for grey), got [2.0, 1.0, 1.0]"
    )


def test_image_textures_of_names_that_sanitise_alike_keep_their_own_files(tmp_path):
    # "'" and '"' both become "_" in a sidecar file name; each keeps its own image.
    b = rt.SceneBuilder("classic", width=4, height=4, spp=1)
    b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=30)
    img = np.zeros((2, 2, 3), np.float32)
    img[0, 1, 1] = 0.5
    b.material("'", color=(1, 1, 1), texture=rt.ImageTexture(img))
    b.material('"', color=(1, 1, 1), texture=rt.ImageTexture(np.zeros((1, 1, 3), np.float32)))
    b.sphere((0, 0, 0), 1.0, "'")
    b.sphere((0, 2, 0), 1.0, '"')
    roundtrip(b.build(), str(tmp_path))
