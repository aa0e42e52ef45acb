"""Reading TOML scene files into a validated :class:`SceneDescription`."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from .. import limits as L
from .. import textures as tx
from ..lights import BY_NAME as LIGHT_BY_NAME
from ..lights import LIGHTS
from ..limits import LIMITS, check_render_value
from ..scene import Scene
from ..shapes import BY_NAME as KIND_BY_NAME
from ..shapes import KINDS
from .description import (
    LIGHT_TYPES,
    MESH_EXTENSIONS,
    OBJECT_TYPES,
    TEXTURE_KINDS,
    CameraDesc,
    LightDesc,
    MaterialDesc,
    ObjectDesc,
    RenderDesc,
    SceneDescription,
    TextureDesc,
)
from .errors import SceneError
from .sources import builtin
from .values import (
    KeyProblem,
    article,
    check_keys,
    did_you_mean,
    got,
    in_range,
    integer,
    is_num,
    join,
    matrix,
    num,
    rgb,
    show,
    table,
    vec,
)

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


def _array_of_tables(data: dict, key: str) -> list:
    """``data[key]`` as a list of ``[[key]]`` sections (empty when absent), within its count limit."""
    raw = data.get(key, [])
    if isinstance(raw, dict):
        raise KeyProblem(key, f"expected an array of tables ([[{key}]] sections), got a table ([{key}])")
    if not isinstance(raw, list):
        raise KeyProblem(key, f"expected an array of tables ([[{key}]] sections), got {show(raw)}")
    msg = L.check_count(key, len(raw))
    if msg:
        raise KeyProblem(key, msg)
    return raw


class _Parser:
    def __init__(self, source: str, base_dir: str | None):
        self.source = source
        self.base_dir = base_dir
        self.shading = "classic"

    # -- files ------------------------------------------------------------------
    def _resolve(self, rel, path, what) -> str:
        if not isinstance(rel, str) or not rel:
            raise KeyProblem(path, f"expected a file name (a string), got {show(rel)}")
        base = self.base_dir if self.base_dir is not None else os.getcwd()
        full = os.path.normpath(os.path.join(base, os.path.expanduser(rel)))
        if not os.path.exists(full):
            raise KeyProblem(
                path,
                f"expected an existing {what} file, found no file {full}"
                + ("" if os.path.isabs(rel) else f" ({rel!r} is read relative to {base})"),
            )
        if os.path.isdir(full):
            raise KeyProblem(path, f"expected {article(what)} {what} file, found a folder {full}")
        return full

    # -- sections ---------------------------------------------------------------
    def parse(self, data: dict, default_name: str) -> SceneDescription:
        check_keys(data, "", TOP_KEYS)
        name = data.get("name", default_name)
        if not isinstance(name, str):
            raise KeyProblem("name", f"expected a string, got {show(name)}")
        shading = data.get("shading", "classic")
        msg = L.check_shading(shading)
        if msg:
            raise KeyProblem("shading", msg)
        self.shading = shading
        camera = self.camera(data.get("camera", {}))
        render = self.render(data.get("render", {}))

        lights_raw = _array_of_tables(data, "light")
        lights = [self.light(v, f"light[{i}]") for i, v in enumerate(lights_raw)]

        mats_raw = data.get("material", {})
        if isinstance(mats_raw, list):
            raise KeyProblem(
                "material",
                "expected a table of named materials ([material.NAME] sections), got an array of tables ([[material]])",
            )
        if not isinstance(mats_raw, dict):
            raise KeyProblem(
                "material", f"expected a table of named materials ([material.NAME] sections), got {show(mats_raw)}"
            )
        if not mats_raw:
            raise KeyProblem("material", "expected at least one material ([material.NAME] section), found none")
        msg = L.check_count("material", len(mats_raw))
        if msg:
            raise KeyProblem("material", msg)
        materials = {}
        for mname, v in mats_raw.items():
            materials[mname] = self.material(v, join("material", mname))

        objs_raw = _array_of_tables(data, "object")
        objects = []
        faces_total = 0
        for i, v in enumerate(objs_raw):
            o = self.object(v, f"object[{i}]", materials)
            if o.type == "mesh":
                faces_total += int(o.params["faces"].shape[0])
                msg = L.check_mesh_faces(faces_total)
                if msg:
                    raise KeyProblem(f"object[{i}]", msg)
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
        t = table(t, "camera", "a table ([camera] section)")
        check_keys(t, "camera", CAMERA_KEYS, context="[camera]")
        d = CameraDesc()
        for k in ("position", "look_at", "up"):
            if k in t:
                setattr(d, k, vec(t[k], f"camera.{k}"))
        if "fov" in t:
            d.fov = in_range(t["fov"], "camera.fov", L.FOV)
        return d

    def render(self, t) -> RenderDesc:
        t = table(t, "render", "a table ([render] section)")
        check_keys(t, "render", RENDER_KEYS, context="[render]")
        d = RenderDesc()
        for k in ("width", "height", "spp", "max_depth", "filter_textures"):
            if k in t:
                msg = check_render_value(k, t[k])
                if msg:
                    raise KeyProblem(f"render.{k}", msg)
                setattr(d, k, t[k])
        msg = L.check_pixels(d.width, d.height)
        if msg:
            raise KeyProblem("render", msg)
        for k in ("background", "ambient"):
            if k in t:
                setattr(d, k, rgb(t[k], f"render.{k}", L.ENVIRONMENT_RGB))
        return d

    def light(self, t, path) -> LightDesc:
        t = table(t, path)
        typ = t.get("type", "point")
        if not isinstance(typ, str) or typ not in LIGHT_TYPES:
            hint = did_you_mean(typ, LIGHT_TYPES) if isinstance(typ, str) else ""
            raise KeyProblem(f"{path}.type", f"expected one of {', '.join(LIGHT_TYPES)}, got {got(typ)}{hint}")
        spec = LIGHT_BY_NAME[typ]
        required = tuple(k.name for k in spec.keys if k.default is None)
        check_keys(t, path, LIGHT_KEYS[typ], required=required, context=f"{article(typ)} {typ} light")
        p = {}
        for k in spec.keys:
            p[k.name] = self.value(k, t[k.name], f"{path}.{k.name}") if k.name in t else tuple(k.default)
        return LightDesc(typ, p)

    def value(self, key, v, path):
        """One parameter of a kind or light type, read by its :class:`~raytrax.shapes.Key` type."""
        f = key.ftype
        if f == "rgb":
            return rgb(v, path)
        if f == "positive":
            return num(v, path, lo=0.0, lo_open=True, what=key.what or "a positive number")
        if f == "matrix":
            return matrix(v, path, key.shape[0], key.what)
        if f == "angles3":
            return vec(v, path, what="an array of 3 angles in degrees ([rx, ry, rz])")
        out = vec(v, path)
        if f == "nonzero3" and not any(out):
            raise KeyProblem(path, "expected a non-zero vector, got [0, 0, 0]")
        return out

    def material(self, t, path) -> MaterialDesc:
        t = table(t, path, "a table of material properties")
        check_keys(t, path, MATERIAL_KEYS, context="a material")
        ranges = L.material_ranges(self.shading)
        d = MaterialDesc()
        for k in ("color", "reflectivity"):
            if k in t:
                setattr(d, k, rgb(t[k], f"{path}.{k}", ranges[k]))
        for k in ("ambient", "diffuse", "specular", "shininess", "transparency", "ior"):
            if k in t:
                setattr(d, k, in_range(t[k], f"{path}.{k}", ranges[k]))
        if "texture" in t:
            d.texture = self.texture(t["texture"], f"{path}.texture")
        return d

    def texture(self, t, path) -> TextureDesc:
        t = table(t, path, 'an inline table such as { kind = "checker", color2 = [0, 0, 0], scale = 5 }')
        kind = t.get("kind")
        if kind is None:
            raise KeyProblem(path, f"missing key 'kind' (one of {', '.join(TEXTURE_KINDS)})")
        if not isinstance(kind, str) or kind not in TEXTURE_KINDS:
            hint = did_you_mean(kind, TEXTURE_KINDS) if isinstance(kind, str) else ""
            raise KeyProblem(f"{path}.kind", f"expected one of {', '.join(TEXTURE_KINDS)}, got {got(kind)}{hint}")
        check_keys(
            t, path, TEXTURE_KEYS[kind], required=TEXTURE_REQUIRED[kind], context=f"{article(kind)} {kind} texture"
        )
        d = TextureDesc(kind=kind)
        if kind in ("checker", "stripes"):
            if "color2" in t:
                d.color2 = rgb(t["color2"], f"{path}.color2", L.material_ranges(self.shading)["color"])
            if "scale" in t:
                d.scale = in_range(t["scale"], f"{path}.scale", L.TEXTURE_SCALE)
            if kind == "stripes" and "direction" in t:
                d.direction = vec(t["direction"], f"{path}.direction", 2, "a [du, dv] array of 2 numbers")
                if d.direction == (0.0, 0.0):
                    raise KeyProblem(f"{path}.direction", "expected a non-zero [du, dv] direction, got [0, 0]")
        elif kind == "image":
            full = self._resolve(t["file"], f"{path}.file", "image")
            from ..imageio import load_image

            try:
                img = load_image(full)
            except (OSError, ValueError) as e:
                raise KeyProblem(f"{path}.file", f"expected a readable image, got an error: {e}") from None
            msg = L.check_texture_pixels(img.shape[0], img.shape[1])
            if msg:
                raise KeyProblem(f"{path}.file", msg)
            d.file, d.image, d.source = t["file"], img, full
        else:
            name = t["name"]
            if not isinstance(name, str) or name not in tx.BUILTIN_IMAGES:
                hint = did_you_mean(name, tx.BUILTIN_IMAGES) if isinstance(name, str) else ""
                raise KeyProblem(
                    f"{path}.name", f"expected one of {', '.join(tx.BUILTIN_IMAGES)}, got {got(name)}{hint}"
                )
            d.name, d.image = name, builtin(name)
        if d.image is not None and self.shading == "physical" and float(d.image.max()) > 1.0:
            raise KeyProblem(
                f"{path}.{'file' if kind == 'image' else 'name'}",
                f"expected an image with values in [0, 1] in physical shading (an albedo), "
                f"found values up to {float(d.image.max()):.4g}",
            )
        return d

    def object(self, t, path, materials) -> ObjectDesc:
        t = table(t, path)
        typ = t.get("type")
        if typ is None:
            raise KeyProblem(path, f"missing key 'type' (one of {', '.join(OBJECT_TYPES)})")
        if not isinstance(typ, str) or typ not in OBJECT_TYPES:
            hint = did_you_mean(typ, OBJECT_TYPES) if isinstance(typ, str) else ""
            raise KeyProblem(f"{path}.type", f"expected one of {', '.join(OBJECT_TYPES)}, got {got(typ)}{hint}")
        check_keys(
            t,
            path,
            ("type", "material") + OBJECT_KEYS[typ],
            required=("type", "material") + OBJECT_REQUIRED[typ],
            context=f"{article(typ)} {typ}",
        )
        mat = t["material"]
        if not isinstance(mat, str):
            raise KeyProblem(f"{path}.material", f"expected a material name (a string), got {show(mat)}")
        if mat not in materials:
            raise KeyProblem(
                f"{path}.material",
                f"expected a defined material, got undefined material {mat!r}"
                f"{did_you_mean(mat, materials)}; defined: {', '.join(materials)}",
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
            raise KeyProblem(path, "expected either 'file' or 'vertices' and 'faces', got both")
        if not has_file and not has_inline:
            raise KeyProblem(path, "missing key 'file' (a mesh needs a file, or inline vertices and faces)")
        p: dict[str, Any] = {}
        if has_file:
            rel = t["file"]
            full = self._resolve(rel, f"{path}.file", "mesh")
            ext = os.path.splitext(full)[1].lower()
            if ext not in MESH_EXTENSIONS:
                raise KeyProblem(f"{path}.file", f"expected a mesh file ({', '.join(MESH_EXTENSIONS)}), got {rel!r}")
            try:
                import trimesh

                m: Any = trimesh.load(full, force="mesh", process=False)  # a Trimesh (force="mesh")
                v = np.asarray(m.vertices, dtype=np.float64)
                f = np.asarray(m.faces, dtype=np.int64)
            except Exception as e:  # trimesh raises many types on bad input
                raise KeyProblem(
                    f"{path}.file",
                    f"expected a readable mesh, got an error reading {rel!r}: {type(e).__name__}: {e}".splitlines()[0],
                ) from None
            if f.ndim != 2 or f.shape[0] == 0:
                raise KeyProblem(f"{path}.file", f"expected a mesh with triangles, found none in {rel!r}")
            p["file"], p["source"] = rel, full
        else:
            for k in ("vertices", "faces"):
                if k not in t:
                    raise KeyProblem(path, f"missing key {k!r} (an inline mesh needs vertices and faces)")
            vr, fr = t["vertices"], t["faces"]
            if not isinstance(vr, list) or len(vr) < 3:
                raise KeyProblem(
                    f"{path}.vertices", f"expected an array of at least 3 [x, y, z] vertices, got {show(vr)}"
                )
            if not isinstance(fr, list) or len(fr) < 1:
                raise KeyProblem(
                    f"{path}.faces", f"expected an array of [i, j, k] vertex-index triples, got {show(fr)}"
                )
            if len(fr) > LIMITS["mesh_faces"]:
                raise KeyProblem(f"{path}.faces", f"expected at most {LIMITS['mesh_faces']:,} faces, got {len(fr):,}")
            v = np.asarray([vec(x, f"{path}.vertices[{i}]") for i, x in enumerate(vr)], dtype=np.float64)
            rows = []
            for i, x in enumerate(fr):
                fp = f"{path}.faces[{i}]"
                if not isinstance(x, list) or len(x) != 3:
                    raise KeyProblem(fp, f"expected an array of 3 vertex indices, got {show(x)}")
                rows.append(
                    [
                        integer(j, f"{fp}[{k}]", lo=0, hi=len(vr) - 1, what=f"a vertex index in [0, {len(vr) - 1}]")
                        for k, j in enumerate(x)
                    ]
                )
            f = np.asarray(rows, dtype=np.int64)
        scale = (1.0, 1.0, 1.0)
        if "scale" in t:
            s = t["scale"]
            if is_num(s):
                scale = (num(s, f"{path}.scale"),) * 3
            else:
                scale = vec(s, f"{path}.scale", what="a number or an array of 3 numbers")
            if any(x == 0 for x in scale):
                raise KeyProblem(f"{path}.scale", f"expected non-zero scale factors, got {s}")
        translate = vec(t["translate"], f"{path}.translate") if "translate" in t else (0.0, 0.0, 0.0)
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
    except KeyProblem as e:
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
    """Load the scene file at ``path`` (TOML, see ``docs/scene-format.md``) into a
    :class:`~raytrax.scene.Scene` whose float leaves have ``dtype`` (default float32).
    Any problem raises :class:`SceneError` naming the file, the key path, what was
    expected and what was found."""
    return load_description(path).build(dtype)
