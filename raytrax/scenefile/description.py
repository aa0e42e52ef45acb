"""The scene description: plain dataclasses between a file and the runtime scene, and
:func:`describe_scene` (a runtime :class:`~raytrax.scene.Scene` back to a description)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import limits as L
from .. import textures as tx
from ..lights import BY_NAME as LIGHT_BY_NAME
from ..lights import LIGHT_TYPES as _LIGHT_TYPES
from ..limits import check_render_value
from ..scene import Scene, SceneBuilder
from ..shapes import BY_NAME as KIND_BY_NAME
from ..shapes import OBJECT_TYPES as _KINDS_OBJECT_TYPES
from .errors import SceneError
from .sources import find_image_source, find_mesh_source, remember_sources

OBJECT_TYPES = _KINDS_OBJECT_TYPES  # every registered kind (raytrax.shapes.registry)
LIGHT_TYPES = _LIGHT_TYPES  # every registered light type (raytrax.lights.registry)
TEXTURE_KINDS = ("checker", "stripes", "image", "builtin")
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off")
_R, _C, _M, _T = L.RENDER_DEFAULTS, L.CAMERA_DEFAULTS, L.MATERIAL_DEFAULTS, L.TEXTURE_DEFAULTS

MESH_FILE_KEYS = ("file", "source", "scale", "translate")


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
                params = {k: v for k, v in o.params.items() if k not in MESH_FILE_KEYS}
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
        remember_sources(self)
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
            src = find_image_source_for(img)
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
            meta = find_mesh_source(group[j].vertices, group[j].faces)
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


def find_image_source_for(img: np.ndarray) -> TextureDesc | None:
    return find_image_source(img, lambda name: TextureDesc(kind="builtin", name=name))
