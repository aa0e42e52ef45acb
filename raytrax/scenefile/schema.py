"""A JSON Schema of scene files, generated from the kind and light registries and
:mod:`raytrax.limits`, for TOML editors (completion and checking as you type; e.g.
the Even Better TOML / taplo extension with ``#:schema ./raytrax-scene.schema.json``
on the first line of a scene file).

The schema checks structure, types, required keys and value ranges. The loader
(:func:`raytrax.load_scene`) checks more (geometry such as convex quads, files that
exist, limits that depend on the shading model for textures) and its messages name
the key path; the schema is an editing aid, not a replacement.
"""

from __future__ import annotations

from typing import Any

from .. import limits as L
from ..lights import LIGHTS
from ..shapes import KINDS
from .description import MESH_EXTENSIONS
from .parse import MATERIAL_KEYS

_NUM: dict = {"type": "number"}


def _range(r: L.Range) -> dict:
    s: dict[str, Any] = {"type": "number"}
    if r.lo is not None:
        s["exclusiveMinimum" if r.lo_open else "minimum"] = r.lo
    if r.hi is not None:
        s["exclusiveMaximum" if r.hi_open else "maximum"] = r.hi
    return s


def _vec(n: int = 3, item: dict = _NUM) -> dict:
    return {"type": "array", "items": item, "minItems": n, "maxItems": n}


def _rgb(r: L.Range = L.RGB_NON_NEGATIVE) -> dict:
    one = _range(r)
    return {"anyOf": [one, _vec(3, one)], "description": "[r, g, b], or one number for grey"}


def _key(k) -> dict:
    f = k.ftype
    if f == "positive":
        return _range(L.POSITIVE)
    if f == "rgb":
        return _rgb()
    if f == "matrix":
        return _vec(k.shape[0], _vec(3))
    return _vec(3)


def json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of raytrax scene files, as a dict."""
    d = L.RENDER_DEFAULTS
    render = {
        "type": "object",
        "properties": {
            "width": {"type": "integer", "minimum": 1, "maximum": L.LIMITS["side"], "default": d.width},
            "height": {"type": "integer", "minimum": 1, "maximum": L.LIMITS["side"], "default": d.height},
            "spp": {"type": "integer", "minimum": 1, "maximum": L.LIMITS["spp"], "default": d.spp},
            "max_depth": {"type": "integer", "minimum": 0, "maximum": L.LIMITS["max_depth"], "default": d.max_depth},
            "background": _rgb(L.ENVIRONMENT_RGB),
            "ambient": _rgb(L.ENVIRONMENT_RGB),
            "filter_textures": {"type": "boolean", "default": d.filter_textures},
        },
        "additionalProperties": False,
    }
    camera = {
        "type": "object",
        "properties": {"position": _vec(), "look_at": _vec(), "up": _vec(), "fov": _range(L.FOV)},
        "additionalProperties": False,
    }
    lights = []
    for s in LIGHTS:
        required = [k.name for k in s.keys if k.default is None]
        props: dict[str, Any] = {"type": {"const": s.name}}
        props.update({k.name: _key(k) for k in s.keys})
        entry: dict[str, Any] = {"type": "object", "properties": props, "additionalProperties": False}
        if s.name == "point":  # ``type`` may be left out for a point light
            entry["required"] = required
        else:
            entry["required"] = ["type", *required]
        lights.append(entry)
    ranges = L.MATERIAL_RANGES["classic"]  # the widest; physical colours are checked by the loader
    texture = {
        "type": "object",
        "properties": {
            "kind": {"enum": ["checker", "stripes", "image", "builtin"]},
            "color2": _rgb(),
            "scale": _range(L.TEXTURE_SCALE),
            "direction": _vec(2),
            "file": {"type": "string"},
            "name": {"type": "string"},
        },
        "required": ["kind"],
        "additionalProperties": False,
    }
    material_props: dict[str, Any] = {}
    for k in MATERIAL_KEYS:
        if k == "texture":
            material_props[k] = texture
        elif k in ("color", "reflectivity"):
            material_props[k] = _rgb(ranges[k])
        else:
            material_props[k] = _range(ranges[k])
    objects = []
    for spec in KINDS:
        props = {"type": {"const": spec.name}, "material": {"type": "string"}}
        required = ["type", "material"]
        if spec.name == "mesh":
            props.update(
                file={"type": "string", "description": "a mesh file: " + ", ".join(MESH_EXTENSIONS)},
                scale={"anyOf": [_NUM, _vec()]},
                translate=_vec(),
                vertices={"type": "array", "items": _vec(), "minItems": 3},
                faces={"type": "array", "items": _vec(3, {"type": "integer", "minimum": 0}), "minItems": 1},
            )
        else:
            props.update({k.name: _key(k) for k in spec.keys})
            required += [k.name for k in spec.keys if k.default is None]
        objects.append({"type": "object", "properties": props, "required": required, "additionalProperties": False})
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "raytrax scene file",
        "type": "object",
        "properties": {
            "name": {"type": "string"},
            "shading": {"enum": list(L.SHADING_MODELS)},
            "camera": camera,
            "render": render,
            "light": {"type": "array", "items": {"oneOf": lights}, "maxItems": L.LIMITS["lights"]},
            "material": {
                "type": "object",
                "additionalProperties": {"type": "object", "properties": material_props, "additionalProperties": False},
            },
            "object": {"type": "array", "items": {"oneOf": objects}, "maxItems": L.LIMITS["objects"]},
        },
        "additionalProperties": False,
    }
