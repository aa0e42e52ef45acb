"""TOML scene files: every key, every error message, and load/save round trips."""

from __future__ import annotations

import math
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt
from raytrax import scenefile as sf
from raytrax.imageio import load_image, save_image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# A minimal valid scene: one material, one sphere (object[0]); error cases edit it.
BASE = """\
shading = "classic"

[camera]
position = [0.0, 0.0, 0.0]
look_at = [0.0, 0.0, -1.0]
fov = 30.0

[render]
width = 8
height = 6
spp = 1
max_depth = 1

[[light]]
position = [0.0, 10.0, 0.0]

[material.m]
color = [0.5, 0.5, 0.5]

[[object]]
type = "sphere"
material = "m"
center = [0.0, 0.0, -5.0]
radius = 1.0
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def error_of(tmp_path, text, name="s.toml"):
    p = write(tmp_path, text, name)
    with pytest.raises(rt.SceneError) as e:
        rt.load_scene(p)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith(f"{p}: "), msg
    return msg[len(f"{p}: ") :]


def edit(old, new):
    assert old in BASE, old
    return BASE.replace(old, new)


def add_object(body):
    return BASE + "\n[[object]]\n" + body + "\n"


def leaves_equal(a, b):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    return True


# -----------------------------------------------------------------------------
# Every key, with its value landing in the runtime scene
# -----------------------------------------------------------------------------

OBJ = """\
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
f 1 2 3
f 1 2 4
"""


@pytest.fixture(scope="module")
def full_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("full")
    (d / "tex").mkdir()
    rng = np.random.default_rng(3)
    save_image(d / "tex" / "wood.exr", rng.random((4, 5, 3)).astype(np.float32))
    (d / "tri.obj").write_text(OBJ)
    (d / "full.toml").write_text("""\
name = "everything"
shading = "classic"

[camera]
position = [1.0, 2.0, 3.0]
look_at = [0.0, 0.5, -10.0]
up = [0.0, 1.0, 0.1]
fov = 35.5

[render]
width = 20
height = 10
spp = 9
max_depth = 3
background = [0.1, 0.2, 0.3]
ambient = 0.25
filter_textures = false

[[light]]
position = [10.0, 40.0, -5.0]
intensity = [0.5, 0.6, 0.7]

[[light]]
position = [-10.0, 40.0, -5.0]
intensity = 0.4

[material.floor]
color = [0.9, 0.8, 0.7]
ambient = 0.5
diffuse = 0.75
specular = 0.3
shininess = 12.0
reflectivity = [0.1, 0.2, 0.3]
texture = { kind = "checker", color2 = [0.1, 0.1, 0.1], scale = 0.2 }

[material.glass]
color = 1.0
reflectivity = 0.1
transparency = 0.9
ior = 1.5
texture = { kind = "stripes", color2 = [0.0, 1.0, 0.0], scale = 10.0, direction = [1.0, 2.0] }

[material.wood]
texture = { kind = "image", file = "tex/wood.exr" }

[material."moon rock"]
color = [1.0, 0.5, 0.25]
texture = { kind = "builtin", name = "moon" }

[[object]]
type = "plane"
material = "floor"
point = [0.0, -15.0, 0.0]
normal = [0.0, 2.0, 0.0]

[[object]]
type = "sphere"
material = "glass"
center = [0.0, 0.0, -90.0]
radius = 15.0

[[object]]
type = "quad"
material = "wood"
corners = [[0.0, 0.0, -50.0], [2.0, 0.0, -50.0], [2.0, 2.0, -50.0], [0.0, 2.0, -50.0]]

[[object]]
type = "triangle"
material = "moon rock"
vertices = [[0.0, 0.0, -40.0], [1.0, 0.0, -40.0], [0.0, 1.0, -40.0]]

[[object]]
type = "box"
material = "floor"
min = [-1.0, -2.0, -60.0]
max = [1.0, 2.0, -58.0]
rotation = [10.0, 20.0, 30.0]

[[object]]
type = "box"
material = "wood"
min = [3.0, -2.0, -60.0]
max = [4.0, 2.0, -58.0]

[[object]]
type = "tetrahedron"
material = "glass"
center = [5.0, -10.0, -70.0]
size = 7.0

[[object]]
type = "mesh"
material = "wood"
file = "tri.obj"
scale = 2.0
translate = [1.0, 2.0, 3.0]

[[object]]
type = "mesh"
material = "floor"
vertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
faces = [[0, 1, 2]]
scale = [1.0, 2.0, 3.0]

[[object]]
type = "sphere"
material = "wood"
center = [-3.0, 1.0, -20.0]
radius = 0.5
""")
    return d


@pytest.fixture(scope="module")
def full(full_dir):
    return rt.load_scene(full_dir / "full.toml")


def test_every_key_lands_in_the_scene(full, full_dir):
    s = full
    assert s.name == "everything" and s.dtype == jnp.float32
    st = s.settings
    assert (st.shading, st.width, st.height, st.spp, st.max_depth, st.filter_textures, st.branches) == (
        "classic",
        20,
        10,
        9,
        3,
        False,
        2,
    )
    c = s.camera
    np.testing.assert_array_equal(c.position, np.float32([1, 2, 3]))
    np.testing.assert_array_equal(c.look_at, np.float32([0, 0.5, -10]))
    np.testing.assert_array_equal(c.up, np.float32([0, 1, 0.1]))
    assert float(c.fov) == np.float32(35.5)
    np.testing.assert_array_equal(s.environment.background, np.float32([0.1, 0.2, 0.3]))
    np.testing.assert_array_equal(s.environment.ambient, np.float32([0.25] * 3))
    np.testing.assert_array_equal(s.lights.position, np.float32([[10, 40, -5], [-10, 40, -5]]))
    np.testing.assert_array_equal(s.lights.intensity, np.float32([[0.5, 0.6, 0.7], [0.4, 0.4, 0.4]]))

    m = s.materials
    assert s.material_names == ("floor", "glass", "wood", "moon rock")
    np.testing.assert_array_equal(m.color, np.float32([[0.9, 0.8, 0.7], [1, 1, 1], [1, 1, 1], [1, 0.5, 0.25]]))
    np.testing.assert_array_equal(m.ambient, np.float32([0.5, 1, 1, 1]))
    np.testing.assert_array_equal(m.diffuse, np.float32([0.75, 1, 1, 1]))
    np.testing.assert_array_equal(m.specular, np.float32([0.3, 0, 0, 0]))
    np.testing.assert_array_equal(m.shininess, np.float32([12, 10, 10, 10]))
    np.testing.assert_array_equal(m.reflectivity[:2], np.float32([[0.1, 0.2, 0.3], [0.1, 0.1, 0.1]]))
    np.testing.assert_array_equal(m.transparency, np.float32([0, 0.9, 0, 0]))
    np.testing.assert_array_equal(m.ior, np.float32([1, 1.5, 1, 1]))
    np.testing.assert_array_equal(m.tex_kind, [1, 2, 3, 3])
    np.testing.assert_array_equal(m.tex_color2[:2], np.float32([[0.1] * 3, [0, 1, 0]]))
    np.testing.assert_array_equal(m.tex_scale[:2], np.float32([0.2, 10]))
    np.testing.assert_array_equal(m.tex_direction[1], np.float32([1, 2]))
    np.testing.assert_array_equal(m.images[int(m.tex_image[2])], load_image(full_dir / "tex" / "wood.exr"))
    np.testing.assert_array_equal(m.images[int(m.tex_image[3])], rt.builtin_image("moon"))

    assert s.object_index == (
        ("plane", 0),
        ("sphere", 0),
        ("quad", 0),
        ("triangle", 0),
        ("box", 0),
        ("box", 1),
        ("tetrahedron", 0),
        ("mesh", 0),
        ("mesh", 1),
        ("sphere", 1),
    )
    np.testing.assert_array_equal(s.planes.point, np.float32([[0, -15, 0]]))
    np.testing.assert_array_equal(s.planes.normal, np.float32([[0, 2, 0]]))
    np.testing.assert_array_equal(s.spheres.center, np.float32([[0, 0, -90], [-3, 1, -20]]))
    np.testing.assert_array_equal(s.spheres.radius, np.float32([15, 0.5]))
    np.testing.assert_array_equal(s.spheres.material, [1, 2])
    np.testing.assert_array_equal(s.quads.corners[0, 2], np.float32([2, 2, -50]))
    np.testing.assert_array_equal(s.triangles.vertices[0, 1], np.float32([1, 0, -40]))
    np.testing.assert_array_equal(s.triangles.material, [3])
    np.testing.assert_array_equal(s.boxes.lo, np.float32([[-1, -2, -60], [3, -2, -60]]))
    np.testing.assert_array_equal(s.boxes.hi, np.float32([[1, 2, -58], [4, 2, -58]]))
    np.testing.assert_array_equal(s.boxes.rotation, np.float32([[10, 20, 30], [0, 0, 0]]))
    np.testing.assert_array_equal(s.tetrahedra.center, np.float32([[5, -10, -70]]))
    np.testing.assert_array_equal(s.tetrahedra.size, np.float32([7]))
    mesh, inline = s.meshes
    np.testing.assert_array_equal(
        mesh.vertices, np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * 2 + np.float32([1, 2, 3])
    )
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 1, 3]])
    assert int(mesh.material) == 2 and int(inline.material) == 0
    np.testing.assert_array_equal(inline.vertices, np.float32([[0, 0, 0], [1, 0, 0], [0, 2, 0]]))


def test_defaults(tmp_path):
    s = rt.load_scene(
        write(
            tmp_path,
            '[material.m]\n[[object]]\ntype = "sphere"\nmaterial = "m"\ncenter = [0.0, 0.0, -5.0]\nradius = 1\n',
            "defaults.toml",
        )
    )
    assert s.name == "defaults"  # the file's stem
    st = s.settings
    assert (st.shading, st.width, st.height, st.spp, st.max_depth, st.filter_textures) == (
        "classic",
        640,
        480,
        1,
        5,
        True,
    )
    assert float(s.camera.fov) == np.float32(2 * math.degrees(math.atan(10 / 40)))  # the seed camera
    np.testing.assert_array_equal(s.camera.look_at, np.float32([0, 0, -1]))
    np.testing.assert_array_equal(s.environment.ambient, np.float32([0.2] * 3))
    np.testing.assert_array_equal(s.environment.background, np.float32([0] * 3))
    assert s.lights.position.shape == (0, 3)
    m = s.materials
    assert (
        float(m.ambient[0]),
        float(m.diffuse[0]),
        float(m.specular[0]),
        float(m.shininess[0]),
        float(m.transparency[0]),
        float(m.ior[0]),
    ) == (1, 1, 0, 10, 0, 1)
    np.testing.assert_array_equal(m.color[0], np.float32([1, 1, 1]))
    np.testing.assert_array_equal(m.reflectivity[0], np.float32([0, 0, 0]))


def test_dtype_and_description(full_dir):
    d = sf.load_description(full_dir / "full.toml")
    assert isinstance(d, sf.SceneDescription) and d.materials["glass"].ior == 1.5
    assert d.objects[7].params["file"] == "tri.obj"
    s64 = d.build(jnp.float64)
    assert s64.dtype == jnp.float64 and float(s64.camera.fov) == 35.5


def test_physical_values_in_range(tmp_path):
    text = edit('shading = "classic"', 'shading = "physical"').replace(
        "color = [0.5, 0.5, 0.5]", "color = [0.0, 0.0, 0.0]\nreflectivity = [1.0, 0.9, 0.8]"
    )
    s = rt.load_scene(write(tmp_path, text))
    assert s.settings.shading == "physical"


def test_scene_file_cannot_run_code(tmp_path):
    evil = "__import__('os').system('touch pwned')"
    s = rt.load_scene(write(tmp_path, f'name = "{evil}"\n' + BASE))
    assert s.name == evil and not (tmp_path / "pwned").exists()
    assert error_of(tmp_path, BASE.replace("radius = 1.0", f'radius = "{evil}"')).startswith(
        "object[0].radius: expected a positive number, got the string"
    )


# -----------------------------------------------------------------------------
# Errors: one message naming file, key path, what was expected and what was found
# -----------------------------------------------------------------------------

SHAPES = {
    "plane": 'type = "plane"\nmaterial = "m"\npoint = [0.0, 0.0, 0.0]\nnormal = {n}',
    "quad": 'type = "quad"\nmaterial = "m"\ncorners = {c}',
    "triangle": 'type = "triangle"\nmaterial = "m"\nvertices = {v}',
    "box": 'type = "box"\nmaterial = "m"\nmin = [0.0, 0.0, 0.0]\nmax = {mx}{extra}',
    "tetra": 'type = "tetrahedron"\nmaterial = "m"\ncenter = [0.0, 0.0, 0.0]\nsize = {s}',
}

ERRORS = [
    # top level
    (edit("radius = 1.0", "radius = "), r"invalid TOML: .*\(at line 24, column 10\)"),
    (BASE + "lights = 3\n", None),  # placed inside the last table: object[0].lights
    (
        "lights = []\n" + BASE,
        r"lights: unknown key \(did you mean 'light'\?\); expected one of: name, shading, "
        r"camera, render, light, material, object",
    ),
    ("objects = []\n" + BASE, r"objects: unknown key \(did you mean 'object'\?\); expected one of: .*"),
    ("name = 1\n" + BASE, r"name: expected a string, got the integer 1"),
    (
        edit('shading = "classic"', 'shading = "clasic"'),
        r"shading: expected one of 'classic', 'physical', got 'clasic' \(did you mean 'classic'\?\)",
    ),
    (edit('shading = "classic"', "shading = 3"), r"shading: expected one of 'classic', 'physical', got the integer 3"),
    # camera
    (
        "camera = 3\n"
        + BASE.replace("[camera]\nposition = [0.0, 0.0, 0.0]\nlook_at = [0.0, 0.0, -1.0]\nfov = 30.0\n", ""),
        r"camera: expected a table \(\[camera\] section\), got the integer 3",
    ),
    (
        edit("fov = 30.0", "fovy = 30.0"),
        r"camera.fovy: unknown key \(did you mean 'fov'\?\); \[camera\] takes: position, look_at, up, fov",
    ),
    (
        edit("position = [0.0, 0.0, 0.0]", "position = [0.0, 0.0]"),
        r"camera.position: expected an array of 3 numbers, got an array of 2 items",
    ),
    (
        edit("position = [0.0, 0.0, 0.0]", 'position = [0.0, "a", 0.0]'),
        r"camera.position\[1\]: expected a number, got the string 'a'",
    ),
    (
        edit("fov = 30.0", "fov = 180"),
        r"camera.fov: expected a vertical field of view in degrees, in \(0, 180\), got 180",
    ),
    (edit("fov = 30.0", "fov = true"), r"camera.fov: expected a vertical field of view .*, got the boolean true"),
    (
        edit("look_at = [0.0, 0.0, -1.0]", "look_at = [0.0, 0.0, 0.0]"),
        r"camera.look_at: must differ from camera.position",
    ),
    (
        edit("fov = 30.0", "fov = 30.0\nup = [0.0, 0.0, -2.0]"),
        r"camera.up: must not be parallel to the viewing direction",
    ),
    (edit("fov = 30.0", "fov = nan"), r"camera.fov: expected a finite number, got nan"),
    # render
    (edit("width = 8", "width = 0"), r"render.width: expected an integer number of pixels in \[1, 65536\], got 0"),
    (edit("width = 8", "width = 8.0"), r"render.width: expected an integer number of pixels in \[1, 65536\], got 8.0"),
    (edit("height = 6", "height = 100000"), r"render.height: expected .* in \[1, 65536\], got 100000"),
    (
        edit("width = 8\nheight = 6", "width = 20000\nheight = 20000"),
        r"render: expected at most 100,000,000 pixels, got width x height = 20000 x 20000 = 400,000,000",
    ),
    (
        edit("spp = 1", "spp = 3"),
        r"render.spp: expected a square number of samples per pixel \(1, 4, 9, 16, \.\.\.; an n x n grid\), got 3 "
        r"\(nearest: 1 or 4\)",
    ),
    (
        edit("spp = 1", "spp = 2048"),
        r"render.spp: expected a square number of samples per pixel in \[1, 1024\], got 2048",
    ),
    (edit("spp = 1", 'spp = "4"'), r"render.spp: expected .*, got the string '4'"),
    (edit("max_depth = 1", "max_depth = 65"), r"render.max_depth: expected an integer in \[0, 64\], got 65"),
    (edit("max_depth = 1", "max_depth = -1"), r"render.max_depth: expected an integer in \[0, 64\], got -1"),
    (
        edit("max_depth = 1", "max_detph = 1"),
        r"render.max_detph: unknown key \(did you mean 'max_depth'\?\); "
        r"\[render\] takes: width, height, spp, max_depth, background, "
        r"ambient, filter_textures",
    ),
    (
        edit("max_depth = 1", "max_depth = 1\nbackground = [1.0, 2.0]"),
        r"render.background: expected an \[r, g, b\] array of non-negative numbers \(or one number for grey\), "
        r"got an array of 2 items",
    ),
    (
        edit("max_depth = 1", "max_depth = 1\nambient = -1"),
        r"render.ambient: expected an \[r, g, b\] array of non-negative numbers \(or one number for grey\), got -1",
    ),
    (
        edit("max_depth = 1", "max_depth = 1\nfilter_textures = 1"),
        r"render.filter_textures: expected true or false, got 1",
    ),
    # lights
    (
        edit("[[light]]", "[light]"),
        r"light: expected an array of tables \(\[\[light\]\] sections\), got a table "
        r"\(\[light\]\)",
    ),
    (
        edit("position = [0.0, 10.0, 0.0]", "intensity = 1.0"),
        r"light\[0\]: missing key 'position' \(a point light needs position\)",
    ),
    (
        edit("position = [0.0, 10.0, 0.0]", "position = [0.0, 10.0, 0.0]\nintensity = [-1.0, 0.0, 0.0]"),
        r"light\[0\].intensity: expected an \[r, g, b\] array of non-negative numbers .*, got \[-1.0, 0.0, 0.0\]",
    ),
    (
        edit("position = [0.0, 10.0, 0.0]", "position = [0.0, 10.0, 0.0]\ncolour = 1.0"),
        r"light\[0\].colour: unknown key; a point light takes: type, position, intensity",
    ),
    # materials
    (
        edit("[material.m]\ncolor = [0.5, 0.5, 0.5]", "[[material]]\ncolor = [0.5, 0.5, 0.5]"),
        r"material: expected a table of named materials \(\[material.NAME\] sections\), got an array of tables \(\[\[material\]\]\)",
    ),
    (
        BASE.split("[material.m]")[0],
        r"material: expected at least one material \(\[material.NAME\] section\), found none",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "colour = [0.5, 0.5, 0.5]"),
        r"material.m.colour: unknown key \(did you mean 'color'\?\); a material takes: color, ambient, diffuse, "
        r"specular, shininess, reflectivity, transparency, ior, texture",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "color = [0.5, 0.5, 0.5, 1.0]"),
        r"material.m.color: expected an \[r, g, b\] array .*, got an array of 4 items",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "transparency = 1.5"),
        r"material.m.transparency: expected a number in \[0, 1\], got 1.5",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "ior = 0.5"),
        r"material.m.ior: expected a refractive index in \[1, 10\], got 0.5",
    ),
    (edit("color = [0.5, 0.5, 0.5]", "specular = -1"), r"material.m.specular: expected a non-negative number, got -1"),
    (
        edit("color = [0.5, 0.5, 0.5]", 'shininess = "high"'),
        r"material.m.shininess: expected a non-negative number, got the string 'high'",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "reflectivity = [0.5, -0.5, 0.5]"),
        r"material.m.reflectivity: expected .* non-negative .*, got \[0.5, -0.5, 0.5\]",
    ),
    (
        edit('shading = "classic"', 'shading = "physical"').replace(
            "color = [0.5, 0.5, 0.5]", "color = [1.2, 0.5, 0.5]"
        ),
        r"material.m.color: expected an \[r, g, b\] array of numbers in \[0, 1\] in physical shading "
        r"\(or one number for grey\), got \[1.2, 0.5, 0.5\]",
    ),
    (
        edit('shading = "classic"', 'shading = "physical"').replace("color = [0.5, 0.5, 0.5]", "reflectivity = 2"),
        r"material.m.reflectivity: expected .* in \[0, 1\] .*, got 2",
    ),
    (edit("[material.m]", "[material.m]\nother = 1\n[material.n]"), None),
    (
        edit('shading = "classic"', 'shading = "physical"').replace(
            "color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = "hdr.exr" }'
        ),
        r"material.m.texture.file: expected an image with values in \[0, 1\] in physical shading \(an albedo\), "
        r"found values up to 2",
    ),
    # textures
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = "checker"'),
        r"material.m.texture: expected an inline table such as .*, got the string 'checker'",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", "texture = { scale = 2.0 }"),
        r"material.m.texture: missing key 'kind' \(one of checker, stripes, image, builtin\)",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "checkers" }'),
        r"material.m.texture.kind: expected one of checker, stripes, image, builtin, got 'checkers' "
        r"\(did you mean 'checker'\?\)",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "checker", direction = [1.0, 0.0] }'),
        r"material.m.texture.direction: unknown key; a checker texture takes: kind, color2, scale",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "checker", scale = 0 }'),
        r"material.m.texture.scale: expected a positive number, got 0",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "checker", color2 = "black" }'),
        r"material.m.texture.color2: expected an \[r, g, b\] array .*, got the string 'black'",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "stripes", direction = [0, 0] }'),
        r"material.m.texture.direction: expected a non-zero \[du, dv\] direction, got \[0, 0\]",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "stripes", direction = [1] }'),
        r"material.m.texture.direction: expected a \[du, dv\] array of 2 numbers, got an array of 1 item",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image" }'),
        r"material.m.texture: missing key 'file' \(an image texture needs kind, file\)",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = 3 }'),
        r"material.m.texture.file: expected a file name \(a string\), got the integer 3",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = "nope.png" }'),
        r"material.m.texture.file: expected an existing image file, found no file {dir}/nope.png "
        r"\('nope.png' is read relative to {dir}\)",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = "bad.png" }'),
        r"material.m.texture.file: expected a readable image, got an error: {dir}/bad.png: cannot read image: .*",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = "sub" }'),
        r"material.m.texture.file: expected an image file, found a folder {dir}/sub",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "builtin", name = "mooon" }'),
        r"material.m.texture.name: expected one of moon, astronaut, .*, got 'mooon' \(did you mean 'moon'\?\)",
    ),
    (
        edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "builtin", file = "moon" }'),
        r"material.m.texture.file: unknown key; a builtin texture takes: kind, name",
    ),
    # objects
    (
        edit("[[object]]", "[object]"),
        r"object: expected an array of tables \(\[\[object\]\] sections\), got a table \(\[object\]\)",
    ),
    (
        edit('type = "sphere"\n', ""),
        r"object\[0\]: missing key 'type' \(one of sphere, plane, quad, disk, triangle, "
        r"tetrahedron, mesh, box\)",
    ),
    (
        edit('type = "sphere"', 'type = "sphre"'),
        r"object\[0\].type: expected one of sphere, .*, got 'sphre' "
        r"\(did you mean 'sphere'\?\)",
    ),
    (edit('type = "sphere"', "type = 5"), r"object\[0\].type: expected one of .*, got the integer 5"),
    (
        edit("radius = 1.0", "raduis = 1.0"),
        r"object\[0\].raduis: unknown key \(did you mean 'radius'\?\); a sphere takes: type, material, center, radius",
    ),
    (edit("radius = 1.0", ""), r"object\[0\]: missing key 'radius' \(a sphere needs type, material, center, radius\)"),
    (
        edit('material = "m"\ncenter', "center"),
        r"object\[0\]: missing key 'material' \(a sphere needs type, material, center, radius\)",
    ),
    (
        edit('material = "m"\ncenter', 'material = "mm"\ncenter'),
        r"object\[0\].material: expected a defined material, got undefined material 'mm' \(did you mean 'm'\?\); "
        r"defined: m",
    ),
    (
        edit('material = "m"\ncenter', "material = 1\ncenter"),
        r"object\[0\].material: expected a material name \(a string\), got the integer 1",
    ),
    (edit("radius = 1.0", "radius = -1"), r"object\[0\].radius: expected a positive number, got -1"),
    (edit("radius = 1.0", "radius = 0.0"), r"object\[0\].radius: expected a positive number, got 0.0"),
    (edit("radius = 1.0", "radius = inf"), r"object\[0\].radius: expected a finite number, got inf"),
    (
        edit("center = [0.0, 0.0, -5.0]", 'center = "abc"'),
        r"object\[0\].center: expected an array of 3 numbers, got the string 'abc'",
    ),
    (
        edit("center = [0.0, 0.0, -5.0]", "center = [[0.0], 0.0, -5.0]"),
        r"object\[0\].center\[0\]: expected a number, got an array of 1 item",
    ),
    (
        add_object(SHAPES["plane"].format(n="[0.0, 0.0, 0.0]")),
        r"object\[1\].normal: expected a non-zero vector, got \[0, 0, 0\]",
    ),
    (
        add_object(SHAPES["quad"].format(c="[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]")),
        r"object\[1\].corners: expected an array of 4 corners \(\[x, y, z\] each, in order around the edge\), "
        r"got an array of 3 items",
    ),
    (
        add_object(SHAPES["quad"].format(c="[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]]")),
        r"object\[1\].corners: expected a convex quad with non-zero area and corners in order around its edge, got a degenerate or self-intersecting quad",
    ),
    (
        add_object(SHAPES["quad"].format(c="[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.5], [0.0, 1.0, 0.0]]")),
        r"object\[1\].corners: the four corners are not coplanar \(off by .*\)",
    ),
    (
        add_object(SHAPES["quad"].format(c="[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.5, 0.0], [0.0, 2.0, 0.0]]")),
        r"object\[1\].corners: expected a convex quad with corners in order around its edge",
    ),
    (
        add_object(SHAPES["quad"].format(c="[[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]")),
        r"object\[1\].corners: expected a convex quad with non-zero area and corners in order around its edge, got a degenerate or self-intersecting quad",
    ),  # a bow-tie: its diagonals are parallel
    (
        add_object(SHAPES["triangle"].format(v="[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]")),
        r"object\[1\].vertices: degenerate triangle \(zero area\)",
    ),
    (
        add_object(SHAPES["triangle"].format(v="[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0]]")),
        r"object\[1\].vertices\[2\]: expected an array of 3 numbers, got an array of 2 items",
    ),
    (
        add_object(SHAPES["box"].format(mx="[1.0, 0.0, 1.0]", extra="")),
        r"object\[1\].max: expected every component greater than min, got min=\[0.0, 0.0, 0.0\] max=\[1.0, 0.0, 1.0\]",
    ),
    (
        add_object(SHAPES["box"].format(mx="[1.0, 1.0, 1.0]", extra="\nrotation = 30.0")),
        r"object\[1\].rotation: expected an array of 3 angles in degrees \(\[rx, ry, rz\]\), got the number 30.0",
    ),
    (
        add_object(SHAPES["box"].format(mx="[1.0, 1.0, 1.0]", extra="\ncenter = [0.0, 0.0, 0.0]")),
        r"object\[1\].center: unknown key; a box takes: type, material, min, max, rotation",
    ),
    (add_object(SHAPES["tetra"].format(s="0")), r"object\[1\].size: expected a positive edge length, got 0"),
    # meshes
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "nope.obj"'),
        r"object\[1\].file: expected an existing mesh file, found no file {dir}/nope.obj \('nope.obj' is read relative to {dir}\)",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "notes.txt"'),
        r"object\[1\].file: expected a mesh file \(.obj, .ply, .stl, .off\), got 'notes.txt'",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "empty.obj"'),
        r"object\[1\].file: expected a mesh with triangles, found none in 'empty.obj'",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "tri.obj"\nfaces = [[0, 1, 2]]'),
        r"object\[1\]: expected either 'file' or 'vertices' and 'faces', got both",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"'),
        r"object\[1\]: missing key 'file' \(a mesh needs a file, or inline vertices and faces\)",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nvertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]'),
        r"object\[1\]: missing key 'faces' \(an inline mesh needs vertices and faces\)",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nvertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\nfaces = [[0, 1, 1]]'),
        r"object\[1\].vertices: expected an array of at least 3 \[x, y, z\] vertices, got an array of 2 items",
    ),
    (
        add_object(
            'type = "mesh"\nmaterial = "m"\nvertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n'
            "faces = [[0, 1, 3]]"
        ),
        r"object\[1\].faces\[0\]\[2\]: expected a vertex index in \[0, 2\], got 3",
    ),
    (
        add_object(
            'type = "mesh"\nmaterial = "m"\nvertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n'
            "faces = [[0, 1]]"
        ),
        r"object\[1\].faces\[0\]: expected an array of 3 vertex indices, got an array of 2 items",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "tri.obj"\nscale = 0'),
        r"object\[1\].scale: expected non-zero scale factors, got 0",
    ),
    (
        add_object('type = "mesh"\nmaterial = "m"\nfile = "tri.obj"\ntranslate = [1.0]'),
        r"object\[1\].translate: expected an array of 3 numbers, got an array of 1 item",
    ),
]


@pytest.fixture(scope="module")
def err_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("errors")
    (d / "bad.png").write_bytes(b"not an image at all")
    (d / "sub").mkdir()
    (d / "notes.txt").write_text("hello")
    (d / "empty.obj").write_text("# nothing\n")
    (d / "tri.obj").write_text(OBJ)
    save_image(d / "hdr.exr", np.full((2, 2, 3), 2.0, np.float32))
    return d


@pytest.mark.parametrize(
    "text,pattern",
    [e for e in ERRORS if e[1] is not None],
    ids=[f"e{i}" for i, e in enumerate(ERRORS) if e[1] is not None],
)
def test_error_messages(err_dir, text, pattern):
    msg = error_of(err_dir, text)
    pattern = pattern.replace("{dir}", re.escape(str(err_dir)))
    assert re.fullmatch(pattern, msg), f"\n got: {msg}\nwant: {pattern}"


def test_unknown_keys_inside_tables(err_dir):
    # a key after the last [[object]] header belongs to that object
    assert error_of(err_dir, BASE + "lights = 3\n").startswith("object[0].lights: unknown key")
    # a material with an unknown key among several materials
    msg = error_of(err_dir, edit("[material.m]", "[material.n]\nshine = 1\n[material.m]"))
    assert msg.startswith("material.n.shine: unknown key (did you mean 'shininess'?)")
    # material names that need quoting appear quoted in key paths
    msg = error_of(err_dir, edit("[material.m]", '[material."my glass"]\nior = 0\n[material.m]'))
    assert msg.startswith('material."my glass".ior: expected a refractive index in [1, 10], got 0')


def test_limits(err_dir, monkeypatch):
    monkeypatch.setitem(sf.LIMITS, "lights", 1)
    assert (
        error_of(err_dir, edit("[[light]]", "[[light]]\nposition = [1.0, 1.0, 1.0]\n[[light]]"))
        == "light: expected at most 1 lights, got 2"
    )
    monkeypatch.setitem(sf.LIMITS, "objects", 1)
    assert error_of(err_dir, add_object(SHAPES["tetra"].format(s="1"))) == "object: expected at most 1 objects, got 2"
    monkeypatch.setitem(sf.LIMITS, "objects", 100)
    monkeypatch.setitem(sf.LIMITS, "mesh_faces", 1)
    assert (
        error_of(err_dir, add_object('type = "mesh"\nmaterial = "m"\nfile = "tri.obj"'))
        == "object[1]: expected at most 1 mesh triangles in all, got 2 so far"
    )
    monkeypatch.setitem(sf.LIMITS, "texture_pixels", 10)
    save_image(err_dir / "big.png", np.zeros((4, 4, 3), np.float32))
    assert (
        error_of(err_dir, edit("color = [0.5, 0.5, 0.5]", 'texture = { kind = "image", file = "big.png" }'))
        == "material.m.texture.file: expected at most 10 pixels, got 4 x 4"
    )
    monkeypatch.setitem(sf.LIMITS, "materials", 1)
    assert (
        error_of(err_dir, edit("[material.m]", "[material.n]\n[material.m]"))
        == "material: expected at most 1 materials, got 2"
    )


def test_file_errors(tmp_path):
    with pytest.raises(rt.SceneError, match=r"^.*missing\.toml: scene file not found$"):
        rt.load_scene(tmp_path / "missing.toml")
    with pytest.raises(rt.SceneError, match=r"expected a scene file, found a folder$"):
        rt.load_scene(tmp_path)
    p = tmp_path / "latin1.toml"
    p.write_bytes(b'name = "caf\xe9"\n')
    with pytest.raises(
        rt.SceneError,
        match=r"latin1\.toml: invalid TOML: expected UTF-8 text, found byte 0xe9 at "
        r"offset 11$",
    ):
        rt.load_scene(p)
    assert issubclass(rt.SceneError, ValueError)


def test_relative_paths_are_relative_to_the_scene_file(full_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the scene's folder
    s = rt.load_scene(os.path.relpath(full_dir / "full.toml"))
    assert s.meshes[0].vertices.shape == (4, 3)


def test_with_render_overrides(full_dir):
    d = sf.load_description(full_dir / "full.toml")
    assert d.with_render(width=4, spp=16).build().settings.spp == 16
    with pytest.raises(rt.SceneError, match=r"full\.toml: render\.spp: expected a square number"):
        d.with_render(spp=2)


# -----------------------------------------------------------------------------
# Round trips
# -----------------------------------------------------------------------------


def test_roundtrip_scene_equal_leaves(full, full_dir, tmp_path):
    out = tmp_path / "other" / "copy.toml"
    out.parent.mkdir()
    rt.save_scene(full, out)
    text = out.read_text()
    # Sources are referred to again, relative to the new file; nothing else is written.
    assert 'kind = "builtin", name = "moon"' in text
    assert re.search(r'file = "[^"]*tex/wood\.exr"', text)
    assert re.search(r'file = "[^"]*tri\.obj"', text) and "scale = 2.0" in text
    assert sorted(os.listdir(out.parent)) == ["copy.toml"]
    back = rt.load_scene(out)
    assert leaves_equal(full, back)
    assert (back.settings, back.object_index, back.material_names, back.name) == (
        full.settings,
        full.object_index,
        full.material_names,
        full.name,
    )
    # Saving the loaded copy again gives the same text (a fixed point).
    again = tmp_path / "other" / "again.toml"
    rt.save_scene(back, again)
    assert again.read_text() == text


def test_roundtrip_description(full_dir, tmp_path):
    d = sf.load_description(full_dir / "full.toml")
    out = tmp_path / "desc.toml"
    rt.save_scene(d, out)
    assert leaves_equal(d.build(), rt.load_scene(out))


def test_roundtrip_python_scene_with_sidecar_and_inline_mesh(tmp_path):
    rng = np.random.default_rng(0)
    tex = rng.random((3, 4, 3)).astype(np.float32)
    b = rt.SceneBuilder("physical", width=5, height=4, spp=4, max_depth=2, name="py scene")
    b.camera(position=(0.1, 0.2, 0.3), look_at=(0, 0, -1), fov=41.3)
    b.light((1, 2, 3), intensity=(1000.0, 2000.0, 3000.0))
    b.material("img", color=(0.3, 0.2, 0.1), texture=rt.ImageTexture(tex, "noise"))
    b.material("glass", color=(0, 0, 0), transparency=1.0, ior=1.33)
    b.mesh(rng.random((5, 3)), np.array([[0, 1, 2], [2, 3, 4]]), "img")
    b.sphere((0.1, 0.2, -3.3), 0.7, "glass")
    scene = b.build()
    out = tmp_path / "py.toml"
    rt.save_scene(scene, out)
    assert sorted(os.listdir(tmp_path)) == ["py.img.exr", "py.toml"]
    text = out.read_text()
    assert 'file = "py.img.exr"' in text and "vertices = [" in text and "faces = [" in text
    back = rt.load_scene(out)
    assert leaves_equal(scene, back) and back.name == "py scene" and back.settings == scene.settings


def test_roundtrip_float64(tmp_path):
    b = rt.SceneBuilder(width=3, height=2)
    b.material("m", color=(0.1, 1 / 3, 2 / 3), shininess=math.pi)
    b.sphere((1e-7, 12345.678901234, -5.0), 1 / 7, "m")
    s64 = b.build(jnp.float64)
    rt.save_scene(s64, tmp_path / "f64.toml")
    assert leaves_equal(s64, rt.load_scene(tmp_path / "f64.toml", dtype=jnp.float64))


def test_save_errors(full, tmp_path):
    with pytest.raises(rt.SceneError, match=r"cannot write: folder .*nowhere does not exist"):
        rt.save_scene(full, tmp_path / "nowhere" / "x.toml")
    with pytest.raises(TypeError, match="expected a Scene or SceneDescription"):
        rt.save_scene({"a": 1}, tmp_path / "x.toml")
    assert os.listdir(tmp_path) == []


def test_shipped_scenes_load_and_roundtrip(tmp_path):
    for name in ("cosc363", "physical_showcase", "tiny"):
        s = rt.load_scene(os.path.join(ROOT, "scenes", f"{name}.toml"))
        assert s.name == name
        rt.save_scene(s, tmp_path / f"{name}.toml")
        assert leaves_equal(s, rt.load_scene(tmp_path / f"{name}.toml"))


def test_docs_example_is_valid(tmp_path):
    text = open(os.path.join(ROOT, "docs", "scene-format.md")).read()
    example = text.split("## A complete example")[1].split("```toml\n")[1].split("```")[0]
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "bunny.obj").write_text(OBJ)
    s = rt.load_scene(write(tmp_path, example, "example.toml"))
    assert s.name == "example" and s.settings.shading == "physical" and len(s.meshes) == 1
