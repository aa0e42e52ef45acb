"""TOML scene files: parse and validate into a description, build the runtime scene,
and write scenes back.

Three layers:

1. the file (TOML, read with the standard library's :mod:`tomllib`: data only,
   a scene file cannot run code; the format is documented in
   ``docs/scene-format.md``);
2. a :class:`SceneDescription` of plain dataclasses (numbers, tuples, names,
   and the texture images and mesh arrays already read from disk), produced by
   :func:`load_description` after validating every key;
3. the runtime :class:`~raytrax.scene.Scene` pytree, built from the description
   through :class:`~raytrax.scene.SceneBuilder` (:meth:`SceneDescription.build`).

:func:`load_scene` goes from 1 to 3. :func:`save_scene` accepts a description
or a :class:`Scene`. A scene carries its arrays plus its static names
(``material_names``, ``object_index``, ``settings``, ``name``), which is all a
file needs, so :func:`describe_scene` rebuilds the description from them: a
saved-then-loaded scene has equal leaves and renders identically. Where a
scene's image texture or mesh still equals (bit for bit) one read from a file
by this process (or a builtin image), the saved file refers to that source
again (``file = ...`` relative to the new scene file, ``kind = "builtin"``);
otherwise images are written next to the scene file as float32 EXR sidecars
(``<stem>.<material>.exr``) and meshes are written inline (``vertices`` and
``faces`` arrays).

Every problem is reported as one :class:`SceneError` whose message names the
file, the key path (``object[3].radius``), what was expected and what was
found.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from . import limits as L
from . import textures as tx
from ._atomic import atomic_path
from .lights import BY_NAME as LIGHT_BY_NAME
from .lights import LIGHT_TYPES as _LIGHT_TYPES
from .lights import LIGHTS
from .limits import LIMITS, SEED_FOV, SHADING_MODELS, check_render_value  # noqa: F401 - names of this module too
from .scene import Scene, SceneBuilder
from .shapes import BY_NAME as KIND_BY_NAME
from .shapes import KINDS
from .shapes import OBJECT_TYPES as _KINDS_OBJECT_TYPES

__all__ = [
    "SceneError",
    "SceneDescription",
    "CameraDesc",
    "RenderDesc",
    "LightDesc",
    "MaterialDesc",
    "TextureDesc",
    "ObjectDesc",
    "load_scene",
    "load_description",
    "loads_description",
    "save_scene",
    "dumps_scene",
    "describe_scene",
    "LIMITS",
    "SEED_FOV",
    "check_render_value",
]


class SceneError(ValueError):
    """A scene file (or a scene description) is invalid; the message says where and why."""


# LIMITS (upper bounds beyond which a value is rejected as absurd), the defaults and
# the value ranges live in raytrax.limits, shared with SceneBuilder; LIMITS is the
# same dict object, so changing an entry here changes it for the builder too.

OBJECT_TYPES = _KINDS_OBJECT_TYPES  # every registered kind (raytrax.shapes.registry)
LIGHT_TYPES = _LIGHT_TYPES  # every registered light type (raytrax.lights.registry)
TEXTURE_KINDS = ("checker", "stripes", "image", "builtin")
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off")
_R, _C, _M, _T = L.RENDER_DEFAULTS, L.CAMERA_DEFAULTS, L.MATERIAL_DEFAULTS, L.TEXTURE_DEFAULTS


# -----------------------------------------------------------------------------
# Description dataclasses
# -----------------------------------------------------------------------------


@dataclasses.dataclass
class CameraDesc:
    """``[camera]``; defaults from :data:`raytrax.limits.CAMERA_DEFAULTS`."""

    position: tuple = _C.position
    look_at: tuple = _C.look_at
    up: tuple = _C.up
    fov: float = _C.fov  # vertical, degrees (SEED_FOV)


@dataclasses.dataclass
class RenderDesc:
    """``[render]``; defaults from :data:`raytrax.limits.RENDER_DEFAULTS` (640 x 480)."""

    width: int = _R.width
    height: int = _R.height
    spp: int = _R.spp
    max_depth: int = _R.max_depth
    background: tuple = _R.background
    ambient: tuple = _R.ambient
    filter_textures: bool = _R.filter_textures


@dataclasses.dataclass
class LightDesc:
    """A light: ``type`` (a registered light type) and its parameters in ``params``
    (tuples of floats)."""

    type: str
    params: dict

    def __getattr__(self, name):  # light.position, light.direction, ...
        params = self.__dict__.get("params", {})
        if name in params:
            return params[name]
        raise AttributeError(name)


@dataclasses.dataclass
class TextureDesc:
    """``kind``: checker, stripes, image or builtin. ``file`` is as written (relative
    to the scene file's folder ``base_dir``); ``image`` holds the loaded linear
    pixels for image and builtin textures."""

    kind: str
    color2: tuple = _T.color2
    scale: float = _T.scale
    direction: tuple = _T.direction
    file: str | None = None
    name: str | None = None
    image: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    source: str | None = None  # absolute path of the image file

    def runtime(self):
        if self.kind == "checker":
            return tx.Checker(color2=tuple(self.color2), scale=float(self.scale))
        if self.kind == "stripes":
            return tx.Stripes(color2=tuple(self.color2), scale=float(self.scale), direction=tuple(self.direction))
        # image is None only in a hand-made description: the builder names the material
        return tx.ImageTexture(image=self.image, name=self.name or self.file or "")  # pyright: ignore[reportArgumentType]


@dataclasses.dataclass
class MaterialDesc:
    """``[material.NAME]``; defaults from :data:`raytrax.limits.MATERIAL_DEFAULTS`."""

    color: tuple = _M.color
    ambient: float = _M.ambient
    diffuse: float = _M.diffuse
    specular: float = _M.specular
    shininess: float = _M.shininess
    reflectivity: tuple = _M.reflectivity
    transparency: float = _M.transparency
    ior: float = _M.ior
    texture: TextureDesc | None = None


@dataclasses.dataclass
class ObjectDesc:
    """``type`` and ``material`` plus the type's parameters in ``params``
    (tuples of floats; meshes: ``vertices``/``faces`` arrays, and ``file``,
    ``scale``, ``translate``, ``source`` when read from a file)."""

    type: str
    material: str
    params: dict


@dataclasses.dataclass
class SceneDescription:
    """A validated scene in plain Python; :meth:`build` makes the runtime :class:`Scene`."""

    name: str = "scene"
    shading: str = "classic"
    camera: CameraDesc = dataclasses.field(default_factory=CameraDesc)
    render: RenderDesc = dataclasses.field(default_factory=RenderDesc)
    lights: list = dataclasses.field(default_factory=list)
    materials: dict = dataclasses.field(default_factory=dict)
    objects: list = dataclasses.field(default_factory=list)
    source: str = "<scene>"  # the file it came from, for messages
    base_dir: str | None = None  # folder that relative files are read from
    float32: bool = False  # values are float32 numbers (came from a float32 Scene)

    def builder(self) -> SceneBuilder:
        """A :class:`SceneBuilder` holding this description (validated by the builder too)."""
        try:
            r = self.render
            b = SceneBuilder(
                self.shading,
                width=r.width,
                height=r.height,
                spp=r.spp,
                max_depth=r.max_depth,
                background=r.background,
                ambient=r.ambient,
                filter_textures=r.filter_textures,
                name=self.name,
            )
            c = self.camera
            b.camera(position=c.position, look_at=c.look_at, up=c.up, fov=c.fov)
            for light in self.lights:
                b.add_light(light.type, **light.params)
            for name, m in self.materials.items():
                b.material(
                    name,
                    color=m.color,
                    ambient=m.ambient,
                    diffuse=m.diffuse,
                    specular=m.specular,
                    shininess=m.shininess,
                    reflectivity=m.reflectivity,
                    transparency=m.transparency,
                    ior=m.ior,
                    texture=None if m.texture is None else m.texture.runtime(),
                )
            for o in self.objects:
                params = {k: v for k, v in o.params.items() if k not in _MESH_FILE_KEYS}
                b.add(o.type, o.material, **params)
        except SceneError:
            raise
        except (ValueError, TypeError, KeyError) as e:
            raise SceneError(f"{self.source}: {e}") from None
        return b

    def build(self, dtype=None) -> Scene:
        """The runtime :class:`Scene` (float32 leaves unless ``dtype`` says otherwise)."""
        b = self.builder()
        try:
            scene = b.build(dtype)
        except ValueError as e:
            raise SceneError(f"{self.source}: {e}") from None
        _remember_sources(self)
        return scene

    def with_render(self, **kw) -> SceneDescription:
        """A copy with some ``[render]`` values changed (validated)."""
        for k, v in kw.items():
            msg = check_render_value(k, v)
            if msg:
                raise SceneError(f"{self.source}: render.{k}: {msg}")
        r = dataclasses.replace(self.render, **kw)
        msg = L.check_pixels(r.width, r.height)
        if msg:
            raise SceneError(f"{self.source}: render: {msg}")
        return dataclasses.replace(self, render=r)

    def primitive_counts(self) -> dict:
        """Objects per type and the number of triangles the renderer will intersect."""
        counts = {t: 0 for t in OBJECT_TYPES}
        tris = 0
        for o in self.objects:
            counts[o.type] += 1
            tris += KIND_BY_NAME[o.type].n_triangles(o.params)
        counts["triangles_total"] = tris
        return counts


# -----------------------------------------------------------------------------
# Validation helpers
# -----------------------------------------------------------------------------


class _KeyError(Exception):
    """Internal: a problem at a key path; turned into a SceneError with the file name."""

    def __init__(self, path: str, msg: str):
        super().__init__(path, msg)
        self.path = path
        self.msg = msg


_key = L.toml_key  # a table key as a key path writes it (quoted unless bare)


def _join(path: str, key: str) -> str:
    return f"{path}.{_key(key)}" if path else _key(key)


_show = L.show_value  # how a found value is described in messages


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _num(v, path, *, lo=None, hi=None, lo_open=False, hi_open=False, what="a number") -> float:
    """A finite number (in ``[lo, hi]``, ends open as told), else a _KeyError
    "expected ``what``, got ...". See :func:`_in` for the shared ranges."""
    if not _is_num(v):
        raise _KeyError(path, f"expected {what}, got {_show(v)}")
    x = float(v)
    if not math.isfinite(x):
        raise _KeyError(path, f"expected a finite number, got {v!r}")
    if lo is not None and (x < lo or (lo_open and x == lo)) or hi is not None and (x > hi or (hi_open and x == hi)):
        raise _KeyError(path, f"expected {what}, got {v!r}")
    return x


def _in(v, path, rng: L.Range) -> float:
    """A number in the shared range ``rng`` (:mod:`raytrax.limits`)."""
    return _num(v, path, lo=rng.lo, hi=rng.hi, lo_open=rng.lo_open, hi_open=rng.hi_open, what=rng.what)


def _int(v, path, *, lo=None, hi=None, what="an integer") -> int:
    if not isinstance(v, int) or isinstance(v, bool):
        raise _KeyError(path, f"expected {what}, got {_show(v)}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise _KeyError(path, f"expected {what}, got {v}")
    return v


def _vec(v, path, n=3, what=None) -> tuple:
    what = what or f"an array of {n} numbers"
    if not isinstance(v, list):
        raise _KeyError(path, f"expected {what}, got {_show(v)}")
    if len(v) != n:
        raise _KeyError(path, f"expected {what}, got {_show(v)}")
    return tuple(_num(x, f"{path}[{i}]") for i, x in enumerate(v))


def _rgb(v, path, rng: L.Range = L.RGB_NON_NEGATIVE) -> tuple:
    """An RGB triple: ``[r, g, b]`` or one number for grey, each in ``rng``
    (non-negative unless told; see :mod:`raytrax.limits`)."""
    if _is_num(v):
        x = _num(v, path)
        c = (x, x, x)
    elif isinstance(v, list) and len(v) == 3:
        c = tuple(_num(x, f"{path}[{i}]") for i, x in enumerate(v))
    else:
        raise _KeyError(path, f"expected {L.rgb_what(rng)}, got {_show(v)}")
    msg = L.rgb_problem(c, rng, v if _is_num(v) else None)
    if msg:
        raise _KeyError(path, msg)
    return c


def _matrix(v, path, rows, what):
    if not isinstance(v, list) or len(v) != rows:
        raise _KeyError(path, f"expected {what}, got {_show(v)}")
    return tuple(_vec(r, f"{path}[{i}]") for i, r in enumerate(v))


def _table(v, path, what=None) -> dict:
    if not isinstance(v, dict):
        raise _KeyError(path, f"expected {what or 'a table'}, got {_show(v)}")
    return v


def _check_keys(table: dict, path: str, allowed, required=(), context: str = ""):
    allowed = list(allowed)
    for k in table:
        if k not in allowed:
            near = difflib.get_close_matches(k, allowed, n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            ctx = f"{context} takes" if context else "expected one of"
            raise _KeyError(_join(path, k) if path else _key(k), f"unknown key{hint}; {ctx}: {', '.join(allowed)}")
    for k in required:
        if k not in table:
            ctx = f" ({context} needs {', '.join(required)})" if context else ""
            raise _KeyError(path or "(top level)", f"missing key {k!r}{ctx}")


def _a(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def _did_you_mean(value: str, options) -> str:
    near = difflib.get_close_matches(value, list(options), n=1, cutoff=0.6)
    return f" (did you mean {near[0]!r}?)" if near else ""


def _got(v) -> str:
    return repr(v) if isinstance(v, str) else _show(v)


# -----------------------------------------------------------------------------
# Parsing
# -----------------------------------------------------------------------------

TOP_KEYS = ("name", "shading", "camera", "render", "light", "material", "object")
CAMERA_KEYS = ("position", "look_at", "up", "fov")
RENDER_KEYS = ("width", "height", "spp", "max_depth", "background", "ambient", "filter_textures")
LIGHT_KEYS = {spec.name: ("type",) + tuple(k.name for k in spec.keys) for spec in LIGHTS}
MATERIAL_KEYS = (
    "color",
    "ambient",
    "diffuse",
    "specular",
    "shininess",
    "reflectivity",
    "transparency",
    "ior",
    "texture",
)
TEXTURE_KEYS = {
    "checker": ("kind", "color2", "scale"),
    "stripes": ("kind", "color2", "scale", "direction"),
    "image": ("kind", "file"),
    "builtin": ("kind", "name"),
}
TEXTURE_REQUIRED = {"checker": ("kind",), "stripes": ("kind",), "image": ("kind", "file"), "builtin": ("kind", "name")}
OBJECT_KEYS = {k.name: tuple(key.name for key in k.keys) for k in KINDS}
OBJECT_KEYS["mesh"] = ("file", "scale", "translate", "vertices", "faces")
OBJECT_REQUIRED = {k.name: tuple(key.name for key in k.keys if key.default is None) for k in KINDS}
_MESH_FILE_KEYS = ("file", "source", "scale", "translate")


class _Parser:
    def __init__(self, source: str, base_dir: str | None):
        self.source = source
        self.base_dir = base_dir
        self.shading = "classic"

    # -- files ------------------------------------------------------------------
    def _resolve(self, rel, path, what) -> str:
        if not isinstance(rel, str) or not rel:
            raise _KeyError(path, f"expected a file name (a string), got {_show(rel)}")
        base = self.base_dir if self.base_dir is not None else os.getcwd()
        full = os.path.normpath(os.path.join(base, os.path.expanduser(rel)))
        if not os.path.exists(full):
            raise _KeyError(
                path,
                f"expected an existing {what} file, found no file {full}"
                + ("" if os.path.isabs(rel) else f" ({rel!r} is read relative to {base})"),
            )
        if os.path.isdir(full):
            raise _KeyError(path, f"expected {_a(what)} {what} file, found a folder {full}")
        return full

    # -- sections ---------------------------------------------------------------
    def parse(self, data: dict, default_name: str) -> SceneDescription:
        _check_keys(data, "", TOP_KEYS)
        name = data.get("name", default_name)
        if not isinstance(name, str):
            raise _KeyError("name", f"expected a string, got {_show(name)}")
        shading = data.get("shading", "classic")
        msg = L.check_shading(shading)
        if msg:
            raise _KeyError("shading", msg)
        self.shading = shading
        camera = self.camera(data.get("camera", {}))
        render = self.render(data.get("render", {}))

        lights_raw = data.get("light", [])
        if isinstance(lights_raw, dict):
            raise _KeyError("light", "expected an array of tables ([[light]] sections), got a table ([light])")
        if not isinstance(lights_raw, list):
            raise _KeyError("light", f"expected an array of tables ([[light]] sections), got {_show(lights_raw)}")
        msg = L.check_count("light", len(lights_raw))
        if msg:
            raise _KeyError("light", msg)
        lights = [self.light(v, f"light[{i}]") for i, v in enumerate(lights_raw)]

        mats_raw = data.get("material", {})
        if isinstance(mats_raw, list):
            raise _KeyError(
                "material",
                "expected a table of named materials ([material.NAME] sections), got an array of tables ([[material]])",
            )
        if not isinstance(mats_raw, dict):
            raise _KeyError(
                "material", f"expected a table of named materials ([material.NAME] sections), got {_show(mats_raw)}"
            )
        if not mats_raw:
            raise _KeyError("material", "expected at least one material ([material.NAME] section), found none")
        msg = L.check_count("material", len(mats_raw))
        if msg:
            raise _KeyError("material", msg)
        materials = {}
        for mname, v in mats_raw.items():
            materials[mname] = self.material(v, _join("material", mname))

        objs_raw = data.get("object", [])
        if isinstance(objs_raw, dict):
            raise _KeyError("object", "expected an array of tables ([[object]] sections), got a table ([object])")
        if not isinstance(objs_raw, list):
            raise _KeyError("object", f"expected an array of tables ([[object]] sections), got {_show(objs_raw)}")
        msg = L.check_count("object", len(objs_raw))
        if msg:
            raise _KeyError("object", msg)
        objects = []
        faces_total = 0
        for i, v in enumerate(objs_raw):
            o = self.object(v, f"object[{i}]", materials)
            if o.type == "mesh":
                faces_total += int(o.params["faces"].shape[0])
                msg = L.check_mesh_faces(faces_total)
                if msg:
                    raise _KeyError(f"object[{i}]", msg)
            objects.append(o)
        return SceneDescription(
            name=name,
            shading=shading,
            camera=camera,
            render=render,
            lights=lights,
            materials=materials,
            objects=objects,
            source=self.source,
            base_dir=self.base_dir,
        )

    def camera(self, t) -> CameraDesc:
        t = _table(t, "camera", "a table ([camera] section)")
        _check_keys(t, "camera", CAMERA_KEYS, context="[camera]")
        d = CameraDesc()
        for k in ("position", "look_at", "up"):
            if k in t:
                setattr(d, k, _vec(t[k], f"camera.{k}"))
        if "fov" in t:
            d.fov = _in(t["fov"], "camera.fov", L.FOV)
        return d

    def render(self, t) -> RenderDesc:
        t = _table(t, "render", "a table ([render] section)")
        _check_keys(t, "render", RENDER_KEYS, context="[render]")
        d = RenderDesc()
        for k in ("width", "height", "spp", "max_depth", "filter_textures"):
            if k in t:
                msg = check_render_value(k, t[k])
                if msg:
                    raise _KeyError(f"render.{k}", msg)
                setattr(d, k, t[k])
        msg = L.check_pixels(d.width, d.height)
        if msg:
            raise _KeyError("render", msg)
        for k in ("background", "ambient"):
            if k in t:
                setattr(d, k, _rgb(t[k], f"render.{k}", L.ENVIRONMENT_RGB))
        return d

    def light(self, t, path) -> LightDesc:
        t = _table(t, path)
        typ = t.get("type", "point")
        if not isinstance(typ, str) or typ not in LIGHT_TYPES:
            hint = _did_you_mean(typ, LIGHT_TYPES) if isinstance(typ, str) else ""
            raise _KeyError(f"{path}.type", f"expected one of {', '.join(LIGHT_TYPES)}, got {_got(typ)}{hint}")
        spec = LIGHT_BY_NAME[typ]
        required = tuple(k.name for k in spec.keys if k.default is None)
        _check_keys(t, path, LIGHT_KEYS[typ], required=required, context=f"{_a(typ)} {typ} light")
        p = {}
        for k in spec.keys:
            p[k.name] = self.value(k, t[k.name], f"{path}.{k.name}") if k.name in t else tuple(k.default)
        return LightDesc(typ, p)

    def value(self, key, v, path):
        """One parameter of a kind or light type, read by its :class:`~raytrax.shapes.Key` type."""
        f = key.ftype
        if f == "rgb":
            return _rgb(v, path)
        if f == "positive":
            return _num(v, path, lo=0.0, lo_open=True, what=key.what or "a positive number")
        if f == "matrix":
            return _matrix(v, path, key.shape[0], key.what)
        if f == "angles3":
            return _vec(v, path, what="an array of 3 angles in degrees ([rx, ry, rz])")
        out = _vec(v, path)
        if f == "nonzero3" and not any(out):
            raise _KeyError(path, "expected a non-zero vector, got [0, 0, 0]")
        return out

    def material(self, t, path) -> MaterialDesc:
        t = _table(t, path, "a table of material properties")
        _check_keys(t, path, MATERIAL_KEYS, context="a material")
        ranges = L.material_ranges(self.shading)
        d = MaterialDesc()
        for k in ("color", "reflectivity"):
            if k in t:
                setattr(d, k, _rgb(t[k], f"{path}.{k}", ranges[k]))
        for k in ("ambient", "diffuse", "specular", "shininess", "transparency", "ior"):
            if k in t:
                setattr(d, k, _in(t[k], f"{path}.{k}", ranges[k]))
        if "texture" in t:
            d.texture = self.texture(t["texture"], f"{path}.texture")
        return d

    def texture(self, t, path) -> TextureDesc:
        t = _table(t, path, 'an inline table such as { kind = "checker", color2 = [0, 0, 0], scale = 5 }')
        kind = t.get("kind")
        if kind is None:
            raise _KeyError(path, f"missing key 'kind' (one of {', '.join(TEXTURE_KINDS)})")
        if not isinstance(kind, str) or kind not in TEXTURE_KINDS:
            hint = _did_you_mean(kind, TEXTURE_KINDS) if isinstance(kind, str) else ""
            raise _KeyError(f"{path}.kind", f"expected one of {', '.join(TEXTURE_KINDS)}, got {_got(kind)}{hint}")
        _check_keys(t, path, TEXTURE_KEYS[kind], required=TEXTURE_REQUIRED[kind], context=f"{_a(kind)} {kind} texture")
        d = TextureDesc(kind=kind)
        if kind in ("checker", "stripes"):
            if "color2" in t:
                d.color2 = _rgb(t["color2"], f"{path}.color2", L.material_ranges(self.shading)["color"])
            if "scale" in t:
                d.scale = _in(t["scale"], f"{path}.scale", L.TEXTURE_SCALE)
            if kind == "stripes" and "direction" in t:
                d.direction = _vec(t["direction"], f"{path}.direction", 2, "a [du, dv] array of 2 numbers")
                if d.direction == (0.0, 0.0):
                    raise _KeyError(f"{path}.direction", "expected a non-zero [du, dv] direction, got [0, 0]")
        elif kind == "image":
            full = self._resolve(t["file"], f"{path}.file", "image")
            from .imageio import load_image

            try:
                img = load_image(full)
            except (OSError, ValueError) as e:
                raise _KeyError(f"{path}.file", f"expected a readable image, got an error: {e}") from None
            msg = L.check_texture_pixels(img.shape[0], img.shape[1])
            if msg:
                raise _KeyError(f"{path}.file", msg)
            d.file, d.image, d.source = t["file"], img, full
        else:
            name = t["name"]
            if not isinstance(name, str) or name not in tx.BUILTIN_IMAGES:
                hint = _did_you_mean(name, tx.BUILTIN_IMAGES) if isinstance(name, str) else ""
                raise _KeyError(
                    f"{path}.name", f"expected one of {', '.join(tx.BUILTIN_IMAGES)}, got {_got(name)}{hint}"
                )
            d.name, d.image = name, _builtin(name)
        if d.image is not None and self.shading == "physical" and float(d.image.max()) > 1.0:
            raise _KeyError(
                f"{path}.{'file' if kind == 'image' else 'name'}",
                f"expected an image with values in [0, 1] in physical shading (an albedo), "
                f"found values up to {float(d.image.max()):.4g}",
            )
        return d

    def object(self, t, path, materials) -> ObjectDesc:
        t = _table(t, path)
        typ = t.get("type")
        if typ is None:
            raise _KeyError(path, f"missing key 'type' (one of {', '.join(OBJECT_TYPES)})")
        if not isinstance(typ, str) or typ not in OBJECT_TYPES:
            hint = _did_you_mean(typ, OBJECT_TYPES) if isinstance(typ, str) else ""
            raise _KeyError(f"{path}.type", f"expected one of {', '.join(OBJECT_TYPES)}, got {_got(typ)}{hint}")
        _check_keys(
            t,
            path,
            ("type", "material") + OBJECT_KEYS[typ],
            required=("type", "material") + OBJECT_REQUIRED[typ],
            context=f"{_a(typ)} {typ}",
        )
        mat = t["material"]
        if not isinstance(mat, str):
            raise _KeyError(f"{path}.material", f"expected a material name (a string), got {_show(mat)}")
        if mat not in materials:
            raise _KeyError(
                f"{path}.material",
                f"expected a defined material, got undefined material {mat!r}"
                f"{_did_you_mean(mat, materials)}; defined: {', '.join(materials)}",
            )
        p: dict[str, Any] = {}
        if typ == "mesh":
            p.update(self.mesh(t, path))
        else:
            for k in KIND_BY_NAME[typ].keys:
                if k.name in t:
                    p[k.name] = self.value(k, t[k.name], f"{path}.{k.name}")
        return ObjectDesc(typ, mat, p)

    def mesh(self, t, path) -> dict:
        has_file = "file" in t
        has_inline = "vertices" in t or "faces" in t
        if has_file and has_inline:
            raise _KeyError(path, "expected either 'file' or 'vertices' and 'faces', got both")
        if not has_file and not has_inline:
            raise _KeyError(path, "missing key 'file' (a mesh needs a file, or inline vertices and faces)")
        p: dict[str, Any] = {}
        if has_file:
            rel = t["file"]
            full = self._resolve(rel, f"{path}.file", "mesh")
            ext = os.path.splitext(full)[1].lower()
            if ext not in MESH_EXTENSIONS:
                raise _KeyError(f"{path}.file", f"expected a mesh file ({', '.join(MESH_EXTENSIONS)}), got {rel!r}")
            try:
                import trimesh

                m: Any = trimesh.load(full, force="mesh", process=False)  # a Trimesh (force="mesh")
                v = np.asarray(m.vertices, dtype=np.float64)
                f = np.asarray(m.faces, dtype=np.int64)
            except Exception as e:  # trimesh raises many types on bad input
                raise _KeyError(
                    f"{path}.file",
                    f"expected a readable mesh, got an error reading {rel!r}: {type(e).__name__}: {e}".splitlines()[0],
                ) from None
            if f.ndim != 2 or f.shape[0] == 0:
                raise _KeyError(f"{path}.file", f"expected a mesh with triangles, found none in {rel!r}")
            p["file"], p["source"] = rel, full
        else:
            for k in ("vertices", "faces"):
                if k not in t:
                    raise _KeyError(path, f"missing key {k!r} (an inline mesh needs vertices and faces)")
            vr, fr = t["vertices"], t["faces"]
            if not isinstance(vr, list) or len(vr) < 3:
                raise _KeyError(
                    f"{path}.vertices", f"expected an array of at least 3 [x, y, z] vertices, got {_show(vr)}"
                )
            if not isinstance(fr, list) or len(fr) < 1:
                raise _KeyError(
                    f"{path}.faces", f"expected an array of [i, j, k] vertex-index triples, got {_show(fr)}"
                )
            if len(fr) > LIMITS["mesh_faces"]:
                raise _KeyError(f"{path}.faces", f"expected at most {LIMITS['mesh_faces']:,} faces, got {len(fr):,}")
            v = np.asarray([_vec(x, f"{path}.vertices[{i}]") for i, x in enumerate(vr)], dtype=np.float64)
            rows = []
            for i, x in enumerate(fr):
                fp = f"{path}.faces[{i}]"
                if not isinstance(x, list) or len(x) != 3:
                    raise _KeyError(fp, f"expected an array of 3 vertex indices, got {_show(x)}")
                rows.append(
                    [
                        _int(j, f"{fp}[{k}]", lo=0, hi=len(vr) - 1, what=f"a vertex index in [0, {len(vr) - 1}]")
                        for k, j in enumerate(x)
                    ]
                )
            f = np.asarray(rows, dtype=np.int64)
        scale = (1.0, 1.0, 1.0)
        if "scale" in t:
            s = t["scale"]
            if _is_num(s):
                scale = (_num(s, f"{path}.scale"),) * 3
            else:
                scale = _vec(s, f"{path}.scale", what="a number or an array of 3 numbers")
            if any(x == 0 for x in scale):
                raise _KeyError(f"{path}.scale", f"expected non-zero scale factors, got {s}")
        translate = _vec(t["translate"], f"{path}.translate") if "translate" in t else (0.0, 0.0, 0.0)
        if has_file:
            p["scale"], p["translate"] = scale, translate
            v = v * np.asarray(scale) + np.asarray(translate)
        elif "scale" in t or "translate" in t:
            p["scale"], p["translate"] = scale, translate
            v = v * np.asarray(scale) + np.asarray(translate)
        p["vertices"], p["faces"] = v, f
        return p


def loads_description(
    text: str, *, source: str = "<string>", base_dir: str | None = None, default_name: str = "scene"
) -> SceneDescription:
    """Parse and validate scene TOML ``text`` (files are read relative to ``base_dir``)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{source}: invalid TOML: {e}") from None
    parser = _Parser(source, base_dir)
    try:
        desc = parser.parse(data, default_name)
    except _KeyError as e:
        raise SceneError(f"{source}: {e.path}: {e.msg}") from None
    desc.builder()  # the builder's own checks (degenerate quads, camera...), with the file name
    return desc


def load_description(path) -> SceneDescription:
    """Read and validate a scene file into a :class:`SceneDescription`."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise SceneError(f"{path}: scene file not found")
    if os.path.isdir(path):
        raise SceneError(f"{path}: expected a scene file, found a folder")
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise SceneError(f"{path}: cannot read the scene file: {e.strerror or e}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(
            f"{path}: invalid TOML: expected UTF-8 text, found byte {raw[e.start]:#04x} at offset {e.start}"
        ) from None
    base = os.path.dirname(os.path.abspath(path))
    return loads_description(text, source=path, base_dir=base, default_name=Path(path).stem)


def load_scene(path, *, dtype=None) -> Scene:
    """Load a scene file (TOML, see ``docs/scene-format.md``) into a :class:`Scene`."""
    return load_description(path).build(dtype)


# -----------------------------------------------------------------------------
# Sources of images and meshes (so that saving a Scene can refer to them again)
# -----------------------------------------------------------------------------

_IMAGE_SOURCES: list = []  # (float32 image, TextureDesc without image)
_MESH_SOURCES: list = []  # (vertices float64, faces, params without arrays)
_MAX_SOURCES = 32


def _push(lst, item):
    lst.append(item)
    del lst[:-_MAX_SOURCES]


@functools.cache
def _builtin(name: str) -> np.ndarray:
    """A builtin image, read once per process (read-only)."""
    img = tx.builtin_image(name)
    img.setflags(write=False)
    return img


def _remember_sources(desc: SceneDescription):
    for m in desc.materials.values():
        t = m.texture
        if t is not None and t.image is not None and t.kind in ("image", "builtin"):
            if not any(src is t.image for src, _ in _IMAGE_SOURCES):
                _push(_IMAGE_SOURCES, (t.image, dataclasses.replace(t, image=None)))
    for o in desc.objects:
        if o.type == "mesh" and "source" in o.params:
            p = o.params
            if not any(v is p["vertices"] for v, _, _ in _MESH_SOURCES):
                meta = {k: p[k] for k in ("file", "source", "scale", "translate")}
                _push(_MESH_SOURCES, (p["vertices"], p["faces"], meta))


def _find_image_source(img: np.ndarray) -> TextureDesc | None:
    for src, t in reversed(_IMAGE_SOURCES):
        if src.shape == img.shape and np.array_equal(src.astype(img.dtype), img):
            if t.kind == "builtin" or (t.source and os.path.exists(t.source)):
                return t
    for name in tx.BUILTIN_IMAGES:  # a builtin used through the Python API
        try:
            b = _builtin(name)
        except Exception:  # pragma: no cover - a sample image missing from scikit-image
            continue
        if b.shape == img.shape and np.array_equal(b.astype(img.dtype), img):
            return TextureDesc(kind="builtin", name=name)
    return None


def _find_mesh_source(v: np.ndarray, f: np.ndarray) -> dict | None:
    for sv, sf, meta in reversed(_MESH_SOURCES):
        if (
            sv.shape == v.shape
            and sf.shape == f.shape
            and np.array_equal(sf, f)
            and np.array_equal(sv.astype(v.dtype), v)
            and os.path.exists(meta["source"])
        ):
            return meta
    return None


# -----------------------------------------------------------------------------
# Scene -> description
# -----------------------------------------------------------------------------


def describe_scene(scene: Scene) -> SceneDescription:
    """The :class:`SceneDescription` of a runtime :class:`Scene`: from its arrays and
    its static names (``material_names``, ``object_index``, ``settings``, ``name``).
    Building the result gives a scene with equal leaves."""
    import jax

    f32 = np.dtype(scene.dtype) == np.float32
    S = jax.tree_util.tree_map(np.asarray, scene)  # one transfer per leaf, then numpy indexing

    def vec(x):
        return tuple(float(y) for y in np.asarray(x).reshape(-1))

    st = scene.settings
    env, cam = S.environment, S.camera
    camera = CameraDesc(vec(cam.position), vec(cam.look_at), vec(cam.up), float(cam.fov))
    render = RenderDesc(
        st.width, st.height, st.spp, st.max_depth, vec(env.background), vec(env.ambient), bool(st.filter_textures)
    )
    lights = []
    for typ, k in scene.light_index:
        spec = LIGHT_BY_NAME[typ]
        lights.append(LightDesc(typ, spec.describe(scene.light_sets[spec.field], k)))

    M = S.materials
    names = list(scene.material_names) or [f"m{k}" for k in range(M.color.shape[0])]
    materials = {}
    for k, name in enumerate(names):
        tex = None
        kind = int(M.tex_kind[k])
        if kind == tx.CHECKER:
            tex = TextureDesc("checker", color2=vec(M.tex_color2[k]), scale=float(M.tex_scale[k]))
        elif kind == tx.STRIPES:
            tex = TextureDesc(
                "stripes", color2=vec(M.tex_color2[k]), scale=float(M.tex_scale[k]), direction=vec(M.tex_direction[k])
            )
        elif kind == tx.IMAGE:
            img = M.images[int(M.tex_image[k])]
            src = _find_image_source(img)
            if src is not None:
                tex = dataclasses.replace(src, image=img)
            else:
                tex = TextureDesc("image", image=img)  # written as a sidecar EXR by save_scene
        materials[name] = MaterialDesc(
            color=vec(M.color[k]),
            ambient=float(M.ambient[k]),
            diffuse=float(M.diffuse[k]),
            specular=float(M.specular[k]),
            shininess=float(M.shininess[k]),
            reflectivity=vec(M.reflectivity[k]),
            transparency=float(M.transparency[k]),
            ior=float(M.ior[k]),
            texture=tex,
        )

    objects = []
    for kind, j in scene.object_index:
        spec = KIND_BY_NAME[kind]
        group = scene.prims[spec.field]
        p, mat = spec.describe(group, j)
        if kind == "mesh":
            meta = _find_mesh_source(group[j].vertices, group[j].faces)
            if meta is not None:
                p.update(meta)
        objects.append(ObjectDesc(kind, names[int(mat)], p))
    return SceneDescription(
        name=scene.name,
        shading=st.shading,
        camera=camera,
        render=render,
        lights=lights,
        materials=materials,
        objects=objects,
        source=f"<scene {scene.name}>",
        float32=f32,
    )


# -----------------------------------------------------------------------------
# Writing TOML
# -----------------------------------------------------------------------------


_quote = L.toml_string


class _Writer:
    def __init__(self, float32: bool):
        self.float32 = float32

    def num(self, x) -> str:
        x = float(x)
        if self.float32 and float(np.float32(x)) == x:
            s = str(np.float32(x))
        else:
            s = repr(x)
        if s in ("inf", "-inf", "nan"):
            return s
        if not any(c in s for c in ".en"):
            s += ".0"
        return s

    def val(self, v) -> str:
        if isinstance(v, (bool, np.bool_)):
            return "true" if v else "false"
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        if isinstance(v, (float, np.floating)):
            return self.num(v)
        if isinstance(v, str):
            return _quote(v)
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(self.val(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{_key(k)} = {self.val(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    def rgb(self, c):
        c = tuple(c)
        return c[0] if c[0] == c[1] == c[2] else c

    def rows(self, arr) -> str:
        arr = np.asarray(arr)
        return "[\n" + "".join(f"    {self.val(r)},\n" for r in arr) + "]"


def _relative(source: str, folder: str) -> str:
    try:
        rel = os.path.relpath(source, folder)
    except ValueError:  # another drive
        return source
    return rel.replace(os.sep, "/")


def dumps_scene(
    desc: SceneDescription, folder: str | None = None, *, sidecars: list | None = None, stem: str = "scene"
) -> str:
    """The TOML text of a description. File references are written relative to
    ``folder``; image textures with no file get sidecar names ``<stem>.<material>.exr``
    appended to ``sidecars`` as ``(name, image)`` (the caller writes them)."""
    folder = folder if folder is not None else os.getcwd()
    w = _Writer(desc.float32)
    L = ["# raytrax scene file; the format is described in docs/scene-format.md", ""]
    L.append(f"name = {w.val(desc.name)}")
    L.append(f"shading = {w.val(desc.shading)}")
    c = desc.camera
    L += [
        "",
        "[camera]",
        f"position = {w.val(c.position)}",
        f"look_at = {w.val(c.look_at)}",
        f"up = {w.val(c.up)}",
        f"fov = {w.num(c.fov)}",
    ]
    r = desc.render
    L += [
        "",
        "[render]",
        f"width = {r.width}",
        f"height = {r.height}",
        f"spp = {r.spp}",
        f"max_depth = {r.max_depth}",
        f"background = {w.val(w.rgb(r.background))}",
        f"ambient = {w.val(w.rgb(r.ambient))}",
        f"filter_textures = {w.val(r.filter_textures)}",
    ]
    for light in desc.lights:
        L += ["", "[[light]]"]
        if light.type != "point":
            L.append(f"type = {w.val(light.type)}")
        for k in LIGHT_BY_NAME[light.type].keys:
            v = light.params[k.name]
            L.append(f"{k.name} = {w.val(w.rgb(v) if k.ftype == 'rgb' else v)}")
    default = MaterialDesc()
    for name, m in desc.materials.items():
        L += ["", f"[material.{_key(name)}]", f"color = {w.val(w.rgb(m.color))}"]
        for k in ("ambient", "diffuse", "specular", "shininess", "transparency", "ior"):
            if getattr(m, k) != getattr(default, k):
                L.append(f"{k} = {w.num(getattr(m, k))}")
        if tuple(m.reflectivity) != default.reflectivity:
            L.append(f"reflectivity = {w.val(w.rgb(m.reflectivity))}")
        t = m.texture
        if t is not None:
            if t.kind == "checker":
                d = dict(kind="checker", color2=w.rgb(t.color2), scale=float(t.scale))
            elif t.kind == "stripes":
                d = dict(
                    kind="stripes",
                    color2=w.rgb(t.color2),
                    scale=float(t.scale),
                    direction=tuple(float(x) for x in t.direction),
                )
            elif t.kind == "builtin":
                d = dict(kind="builtin", name=t.name)
            elif t.source is not None:
                d = dict(kind="image", file=_relative(t.source, folder))
            elif t.file is not None and desc.base_dir is not None:
                d = dict(kind="image", file=_relative(os.path.join(desc.base_dir, t.file), folder))
            else:
                if sidecars is None:
                    raise SceneError(
                        f"{desc.source}: material.{_key(name)}.texture: an image with no file "
                        "can only be saved with save_scene (as a sidecar EXR)"
                    )
                safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
                fname = f"{stem}.{safe}.exr"
                sidecars.append((fname, t.image))
                d = dict(kind="image", file=fname)
            L.append(f"texture = {w.val(d)}")
    for o in desc.objects:
        L += ["", "[[object]]", f"type = {w.val(o.type)}", f"material = {w.val(o.material)}"]
        p = o.params
        if o.type == "mesh":
            if "source" in p:
                L.append(f"file = {w.val(_relative(p['source'], folder))}")
                if tuple(p["scale"]) != (1.0, 1.0, 1.0):
                    s = tuple(p["scale"])
                    L.append(f"scale = {w.val(s[0] if s[0] == s[1] == s[2] else s)}")
                if tuple(p["translate"]) != (0.0, 0.0, 0.0):
                    L.append(f"translate = {w.val(p['translate'])}")
            else:
                L.append(f"vertices = {w.rows(p['vertices'])}")
                L.append(f"faces = {w.rows(np.asarray(p['faces'], dtype=np.int64))}")
            continue
        for k, v in p.items():
            if k in ("corners", "vertices"):
                L.append(f"{k} = {w.rows(v)}")
            else:
                L.append(f"{k} = {w.val(v)}")
    return "\n".join(L) + "\n"


def _atomic_write(path: str, data: bytes):
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)


def save_scene(scene: Scene | SceneDescription, path) -> str:
    """Write a :class:`Scene` or :class:`SceneDescription` as a TOML scene file.

    Texture and mesh files are referred to relative to the new file's folder; an
    image texture with no known source is written beside it as
    ``<stem>.<material>.exr``. Returns the path. Loading the file gives a scene
    with equal leaves and static data.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise SceneError(f"{path}: cannot write: folder {folder} does not exist")
    desc = describe_scene(scene) if isinstance(scene, Scene) else scene
    if not isinstance(desc, SceneDescription):
        raise TypeError(f"save_scene: expected a Scene or SceneDescription, got {type(scene).__name__}")
    sidecars: list = []
    text = dumps_scene(desc, folder, sidecars=sidecars, stem=Path(path).stem)
    from .imageio import save_image

    for fname, img in sidecars:
        save_image(os.path.join(folder, fname), np.asarray(img, dtype=np.float32))
    _atomic_write(path, text.encode("utf-8"))
    return path
