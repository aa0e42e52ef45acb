"""Writing scenes and descriptions as TOML scene files (with EXR sidecars for images
that came from no file)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .. import limits as L
from .._atomic import atomic_path
from ..lights import BY_NAME as LIGHT_BY_NAME
from ..scene import Scene
from .description import MaterialDesc, SceneDescription, describe_scene
from .errors import SceneError
from .values import quote_key

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
            return "{ " + ", ".join(f"{quote_key(k)} = {self.val(x)}" for k, x in v.items()) + " }"
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
        L += ["", f"[material.{quote_key(name)}]", f"color = {w.val(w.rgb(m.color))}"]
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
                        f"{desc.source}: material.{quote_key(name)}.texture: an image with no file "
                        "can only be saved with save_scene (as a sidecar EXR)"
                    )
                safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
                fname = f"{stem}.{safe}.exr"
                # Names that differ only in characters replaced above ("'", '"', "é")
                # would share a file: later ones get a counter.
                used = {f for f, _ in sidecars}
                k = 2
                while fname in used:
                    fname = f"{stem}.{safe}.{k}.exr"
                    k += 1
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
    from ..imageio import save_image

    for fname, img in sidecars:
        save_image(os.path.join(folder, fname), np.asarray(img, dtype=np.float32))
    _atomic_write(path, text.encode("utf-8"))
    return path
