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

from ..limits import LIMITS, SEED_FOV, SHADING_MODELS, check_render_value
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
    describe_scene,
)
from .errors import SceneError
from .parse import load_description, load_scene, loads_description
from .schema import json_schema
from .write import dumps_scene, save_scene

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
    "SHADING_MODELS",
    "LIGHT_TYPES",
    "MESH_EXTENSIONS",
    "OBJECT_TYPES",
    "TEXTURE_KINDS",
    "check_render_value",
    "json_schema",
]
