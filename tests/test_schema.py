"""The scene files' JSON Schema (``raytrax schema``) agrees with the loader: every
shipped scene validates, it lists every registered kind and light type, and typical
mistakes that the loader refuses are flagged."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys
import tomllib

import jsonschema
import pytest

from raytrax.lights import LIGHTS
from raytrax.scenefile import json_schema
from raytrax.shapes import KINDS

SCENES = sorted((pathlib.Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
VALIDATOR = jsonschema.Draft202012Validator(json_schema())


def test_schema_is_valid_and_covers_the_registries():
    jsonschema.Draft202012Validator.check_schema(json_schema())
    props = json_schema()["properties"]
    kinds = {o["properties"]["type"]["const"] for o in props["object"]["items"]["oneOf"]}
    lights = {o["properties"]["type"]["const"] for o in props["light"]["items"]["oneOf"]}
    assert kinds == {k.name for k in KINDS}
    assert lights == {s.name for s in LIGHTS}


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_shipped_scenes_validate(path):
    errors = list(VALIDATOR.iter_errors(tomllib.loads(path.read_text())))
    assert not errors, [e.message for e in errors]


BASE = """
[camera]
position = [0, 0, 5]
[[light]]
position = [0, 5, 5]
[[light]]
type = "directional"
direction = [0, -1, 0]
[material.m]
color = 0.5
[[object]]
type = "disk"
material = "m"
center = [0, 0, 0]
normal = [0, 0, 1]
radius = 1.0
"""

MISTAKES = {
    "unknown object type": ('type = "disk"', 'type = "disc"'),
    "missing radius": ("radius = 1.0", ""),
    "negative radius": ("radius = 1.0", "radius = -1.0"),
    "unknown key": ("radius = 1.0", "radius = 1.0\ncolour = 1"),
    "two-component centre": ("center = [0, 0, 0]", "center = [0, 0]"),
    "directional light without a direction": ("direction = [0, -1, 0]", ""),
    "negative spp": ("[camera]", "[render]\nspp = 0\n[camera]"),
}


def test_base_scene_validates():
    assert not list(VALIDATOR.iter_errors(tomllib.loads(BASE)))


@pytest.mark.parametrize("case", list(MISTAKES))
def test_mistakes_are_flagged_by_schema_and_loader(case, tmp_path):
    import raytrax as rt

    old, new = MISTAKES[case]
    text = BASE.replace(old, new, 1)
    assert list(VALIDATOR.iter_errors(tomllib.loads(text))), f"schema accepts: {case}"
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(rt.SceneError):
        rt.load_scene(path)


def test_cli_prints_the_schema():
    out = subprocess.run([sys.executable, "-m", "raytrax", "schema"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == json_schema()
