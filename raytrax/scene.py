"""The runtime scene pytree and the plain-Python builder that makes it.

A :class:`Scene` is an :class:`equinox.Module` of arrays: every float in it is a
JAX array leaf that can be differentiated (use :func:`equinox.filter_grad`, or
:func:`raytrax.parameters` for named leaves; the integer material ids are
leaves too, so plain ``jax.grad`` on a whole scene is not possible).
Structure (counts, shading model, default render settings, the names the
scene file gave) is static.

Build scenes with :class:`SceneBuilder` (plain Python, validated once), or load
them from TOML files with :func:`raytrax.load_scene`.
"""

from __future__ import annotations

import dataclasses
import inspect
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import bvh as bvh_mod
from . import textures as tx
from .camera import Camera
from .lights import BY_FIELD as LIGHT_BY_FIELD
from .lights import BY_NAME as LIGHT_BY_NAME
from .lights import LIGHTS
from .materials import Materials
from .shapes import BY_FIELD, BY_NAME, KINDS

SHADING_MODELS = ("classic", "physical")


@dataclasses.dataclass(frozen=True)
class Settings:
    """Static render settings (they fix shapes and the traced program).

    - ``shading``: ``"classic"`` or ``"physical"``.
    - ``width``, ``height``: image size in pixels.
    - ``spp``: samples per pixel, a square number (``n x n`` stratified grid).
    - ``max_depth``: number of specular interactions a path may have.
    - ``filter_textures``: box-filter procedural textures over the footprint.
    - ``branches``: specular branches kept per camera sample at each depth
      (1 when no material can split a path into a reflected and a refracted ray;
      2 otherwise). Branches beyond this budget, the lightest first, are dropped.
    """

    shading: str = "classic"
    width: int = 64
    height: int = 48
    spp: int = 1
    max_depth: int = 5
    filter_textures: bool = True
    branches: int = 1

    def __post_init__(self):
        if self.shading not in SHADING_MODELS:
            raise ValueError(f"render.shading: expected one of {SHADING_MODELS}, got {self.shading!r}")
        for name in ("width", "height", "spp"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"render.{name}: expected a positive integer, got {v!r}")
        if math.isqrt(self.spp) ** 2 != self.spp:
            raise ValueError(f"render.spp: expected a square number (1, 4, 9, ...), got {self.spp}")
        if not isinstance(self.max_depth, int) or self.max_depth < 0:
            raise ValueError(f"render.max_depth: expected an integer >= 0, got {self.max_depth!r}")
        if self.branches < 1:
            raise ValueError(f"render.branches: expected an integer >= 1, got {self.branches!r}")


class Environment(eqx.Module):
    """``background (3,)``: radiance of escaped rays; ``ambient (3,)``: classic ambient light."""

    background: Float[Array, 3]
    ambient: Float[Array, 3]


class Scene(eqx.Module):
    """Everything :func:`raytrax.render` needs.

    Primitives are held per kind (``scene.spheres``, ``scene.boxes``, ... one
    attribute per entry of the kind registry :data:`raytrax.shapes.KINDS`, stored
    in ``prims``), lights per type (``scene.lights`` for point lights,
    ``scene.directional_lights``; stored in ``light_sets``).
    ``object_index`` maps the i-th object of the scene description to
    ``(kind, index within kind)``, ``light_index`` the j-th light to ``(type,
    index within type)``; ``material_names`` names the rows of the material table.
    ``bvh`` is the topology of the triangle acceleration structure
    (:mod:`raytrax.bvh`), built by :class:`SceneBuilder` for scenes with many
    triangles.
    """

    camera: Camera
    materials: Materials
    environment: Environment
    prims: dict
    light_sets: dict
    settings: Settings = eqx.field(static=True)
    object_index: tuple = eqx.field(static=True, default=())
    light_index: tuple = eqx.field(static=True, default=())
    material_names: tuple = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="scene")
    bvh: bvh_mod.TriangleBVH | None = None  # leaf order of the merged triangle list (raytrax.bvh); None: brute force

    def __getattr__(self, name):
        # Only reached when normal lookup fails: the kinds' and light types' fields.
        if name in BY_FIELD:
            return self.prims[name]
        if name in LIGHT_BY_FIELD:
            return self.light_sets[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def dtype(self):
        return self.camera.position.dtype

    def merged_triangles(self):
        """Every triangle-family primitive as one list: ``vertices (T, 3, 3)`` and
        ``material (T,)``, in registry order (triangles, tetrahedron faces, mesh
        faces: the order of intersection indices and of :mod:`raytrax.bvh`)."""
        parts = [k.triangles(self.prims[k.field]) for k in KINDS if k.triangle_family]
        parts = [p for p in parts if p is not None]
        return jnp.concatenate([t for t, _ in parts], 0), jnp.concatenate([m for _, m in parts], 0)

    @property
    def n_lights(self) -> int:
        """Number of lights of every type."""
        return sum(s.count(self.light_sets[s.field]) for s in LIGHTS)

    def replace_settings(self, **kw) -> Scene:
        """A copy with some static render settings changed."""
        return dataclasses.replace(self, settings=dataclasses.replace(self.settings, **kw))

    def astype(self, dtype) -> Scene:
        """A copy with every floating-point leaf cast to ``dtype`` (e.g. float64 for
        gradient checks; needs ``jax.config.update("jax_enable_x64", True)``)."""

        def cast(x):
            if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating):
                return x.astype(dtype)
            return x

        return jax.tree_util.tree_map(cast, self)


def _arr(x, dtype, shape, what):
    a = np.asarray(x, dtype=np.float64)
    if shape is not None and a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: expected finite numbers, got {x!r}")
    return a


def _rgb(x, what):
    a = np.asarray(x, dtype=np.float64)
    if a.shape == ():
        a = np.full(3, float(a))
    return _arr(a, None, (3,), what)


@dataclasses.dataclass
class _Mat:
    name: str
    color: np.ndarray
    ambient: float
    diffuse: float
    specular: float
    shininess: float
    reflectivity: np.ndarray
    transparency: float
    ior: float
    texture: object


class SceneBuilder:
    """Build a :class:`Scene` in plain Python.

    Example::

        b = SceneBuilder(shading="physical", width=64, height=48)
        b.camera(position=(0, 1, 5), look_at=(0, 0, 0), fov=40)
        b.light((2, 5, 2), intensity=(50, 50, 50))
        b.material("white", color=(0.8, 0.8, 0.8))
        b.plane((0, 0, 0), (0, 1, 0), "white")
        b.sphere((0, 1, 0), 1.0, "white")
        scene = b.build()
    """

    def __init__(
        self,
        shading="classic",
        *,
        width=64,
        height=48,
        spp=1,
        max_depth=5,
        background=(0.0, 0.0, 0.0),
        ambient=(0.2, 0.2, 0.2),
        filter_textures=True,
        name="scene",
    ):
        self.shading = shading
        self.render = dict(width=width, height=height, spp=spp, max_depth=max_depth, filter_textures=filter_textures)
        self.background = _rgb(background, "render.background")
        self.ambient = _rgb(ambient, "render.ambient")
        self.name = name
        self._camera = dict(
            position=np.zeros(3),
            look_at=np.array([0.0, 0.0, -1.0]),
            up=np.array([0.0, 1.0, 0.0]),
            fov=2 * math.degrees(math.atan(10 / 40)),
        )
        self._lights: list = []
        self._mats: dict[str, _Mat] = {}
        self._objects: list = []  # (kind, params dict, material name)

    # -- camera, lights, materials ------------------------------------------
    def camera(self, position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0), fov=28.0725):
        pos = _arr(position, None, (3,), "camera.position")
        at = _arr(look_at, None, (3,), "camera.look_at")
        upv = _arr(up, None, (3,), "camera.up")
        if np.linalg.norm(at - pos) == 0:
            raise ValueError("camera.look_at: must differ from camera.position")
        if np.linalg.norm(np.cross(at - pos, upv)) < 1e-9 * np.linalg.norm(at - pos) * max(np.linalg.norm(upv), 1e-300):
            raise ValueError("camera.up: must not be parallel to the viewing direction")
        fov = float(fov)
        if not (0.0 < fov < 180.0):
            raise ValueError(f"camera.fov: expected degrees in (0, 180), got {fov}")
        self._camera = dict(position=pos, look_at=at, up=upv, fov=fov)
        return self

    def add_light(self, type: str, **params):
        """Add a light of registered ``type`` (``"point"``, ``"directional"``; see
        :data:`raytrax.lights.LIGHTS`) with its parameters as keywords."""
        j = len(self._lights)
        spec = LIGHT_BY_NAME.get(type)
        if spec is None:
            raise ValueError(f"light[{j}].type: expected one of {', '.join(LIGHT_BY_NAME)}, got {type!r}")
        unknown = set(params) - {k.name for k in spec.keys}
        if unknown:
            raise ValueError(f"light[{j}]: unknown key(s) {sorted(unknown)} for a {type} light")
        self._lights.append((type, spec.validate(params, f"light[{j}]")))
        return self

    def material(
        self,
        name,
        color=(1.0, 1.0, 1.0),
        *,
        ambient=1.0,
        diffuse=1.0,
        specular=0.0,
        shininess=10.0,
        reflectivity=0.0,
        transparency=0.0,
        ior=1.0,
        texture=None,
    ):
        w = f"material.{name}"
        if name in self._mats:
            raise ValueError(f"{w}: defined twice")
        t = float(transparency)
        if not 0.0 <= t <= 1.0:
            raise ValueError(f"{w}.transparency: expected a number in [0, 1], got {t}")
        if float(ior) < 1.0:
            raise ValueError(f"{w}.ior: expected a number >= 1, got {ior}")
        if float(shininess) < 0:
            raise ValueError(f"{w}.shininess: expected a number >= 0, got {shininess}")
        if texture is not None and not isinstance(texture, (tx.Checker, tx.Stripes, tx.ImageTexture)):
            raise ValueError(f"{w}.texture: expected Checker, Stripes or ImageTexture, got {texture!r}")
        if isinstance(texture, tx.ImageTexture):
            img = np.asarray(texture.image)
            if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
                raise ValueError(f"{w}.texture: expected an (H, W, 3) image, got shape {img.shape}")
        self._mats[name] = _Mat(
            name,
            _rgb(color, f"{w}.color"),
            float(ambient),
            float(diffuse),
            float(specular),
            float(shininess),
            _rgb(reflectivity, f"{w}.reflectivity"),
            t,
            float(ior),
            texture,
        )
        return self

    # -- objects ------------------------------------------------------------
    def add(self, kind: str, material: str, **params):
        """Add an object of registered ``kind`` (``"sphere"``, ``"disk"``, ...; see
        :data:`raytrax.shapes.KINDS`) with its parameters as keywords (the scene
        file's keys)."""
        i = len(self._objects)
        spec = BY_NAME.get(kind)
        if spec is None:
            raise ValueError(f"object[{i}].type: expected one of {', '.join(BY_NAME)}, got {kind!r}")
        if not isinstance(material, str):
            raise ValueError(f"object[{i}].material: expected a material name, got {material!r}")
        self._objects.append((kind, spec.validate(params, f"object[{i}]"), material))
        return self

    # -- build --------------------------------------------------------------
    def build(self, dtype=None) -> Scene:
        """Validate and assemble the :class:`Scene` (float leaves in ``dtype``,
        default float32, or float64 when jax's x64 mode is on and asked for)."""
        dt = jnp.dtype(dtype) if dtype is not None else jnp.dtype(jnp.float32)
        if not self._mats:
            raise ValueError("material: a scene needs at least one material")
        names = list(self._mats)
        mid = {n: k for k, n in enumerate(names)}
        for i, (_kind, _, m) in enumerate(self._objects):
            if m not in mid:
                from difflib import get_close_matches

                near = get_close_matches(m, names, n=1)
                hint = f" (did you mean {near[0]!r}?)" if near else ""
                raise ValueError(f"object[{i}].material: undefined material {m!r}{hint}; defined: {names}")

        def F(x, shape=None):
            a = np.asarray(x, dtype=np.float64)
            if shape is not None:
                a = a.reshape(shape)
            return jnp.asarray(a, dtype=dt)

        def I(x):
            return jnp.asarray(np.asarray(x, dtype=np.int32).reshape(-1))

        mats = [self._mats[n] for n in names]
        images, img_ids, kinds = [], [], set()
        tex_kind, tex_c2, tex_scale, tex_dir = [], [], [], []
        for m in mats:
            t = m.texture
            if t is None:
                tex_kind.append(tx.NONE)
                tex_c2.append((0, 0, 0))
                tex_scale.append(1.0)
                tex_dir.append((0, 1))
                img_ids.append(0)
            elif isinstance(t, tx.Checker):
                tex_kind.append(tx.CHECKER)
                tex_c2.append(_rgb(t.color2, f"material.{m.name}.texture.color2"))
                tex_scale.append(float(t.scale))
                tex_dir.append((0, 1))
                img_ids.append(0)
            elif isinstance(t, tx.Stripes):
                tex_kind.append(tx.STRIPES)
                tex_c2.append(_rgb(t.color2, f"material.{m.name}.texture.color2"))
                tex_scale.append(float(t.scale))
                tex_dir.append(tuple(t.direction))
                img_ids.append(0)
            else:
                tex_kind.append(tx.IMAGE)
                tex_c2.append((0, 0, 0))
                tex_scale.append(1.0)
                tex_dir.append((0, 1))
                img_ids.append(len(images))
                images.append(F(np.asarray(t.image)))  # pyright: ignore
            kinds.add(tex_kind[-1])
        materials = Materials(
            color=F([m.color for m in mats], (-1, 3)),
            ambient=F([m.ambient for m in mats]),
            diffuse=F([m.diffuse for m in mats]),
            specular=F([m.specular for m in mats]),
            shininess=F([m.shininess for m in mats]),
            reflectivity=F([m.reflectivity for m in mats], (-1, 3)),
            transparency=F([m.transparency for m in mats]),
            ior=F([m.ior for m in mats]),
            tex_kind=I(tex_kind),
            tex_color2=F(tex_c2, (-1, 3)),
            tex_scale=F(tex_scale),
            tex_direction=F(tex_dir, (-1, 2)),
            tex_image=I(img_ids),
            images=tuple(images),
            kinds_present=tuple(sorted(k for k in kinds if k != tx.NONE)),
        )

        groups: dict[str, list] = {k.name: [] for k in KINDS}
        index = []
        for kind, p, m in self._objects:
            index.append((kind, len(groups[kind])))
            groups[kind].append((p, mid[m]))
        prims = {k.field: k.build(groups[k.name], F, I) for k in KINDS}

        splits = any(m.transparency > 0 for m in mats)
        settings = Settings(shading=self.shading, branches=2 if splits else 1, **self.render)  # pyright: ignore
        lgroups: dict[str, list] = {s.name: [] for s in LIGHTS}
        light_index = []
        for typ, p in self._lights:
            light_index.append((typ, len(lgroups[typ])))
            lgroups[typ].append(p)
        light_sets = {s.field: s.build(lgroups[s.name], F) for s in LIGHTS}
        c = self._camera
        scene = Scene(
            camera=Camera(F(c["position"]), F(c["look_at"]), F(c["up"]), F(c["fov"])),
            materials=materials,
            environment=Environment(F(self.background), F(self.ambient)),
            prims=prims,
            light_sets=light_sets,
            settings=settings,
            object_index=tuple(index),
            light_index=tuple(light_index),
            material_names=tuple(names),
            name=self.name,
        )
        # Triangle acceleration structure (raytrax.bvh) over the merged triangle list
        # (triangles, tetrahedron faces, mesh faces), above the brute-force threshold.
        n_tri = sum(k.n_ids(prims[k.field]) for k in KINDS if k.triangle_family)
        if n_tri > bvh_mod.MIN_TRIANGLES:
            scene = dataclasses.replace(scene, bvh=bvh_mod.for_scene(scene))
        return scene


def _builder_method(spec, args, optional, doc):
    """A :class:`SceneBuilder` method for a registered kind or light type: positional
    ``args``, then (objects) the material, then keyword ``optional`` parameters."""
    is_light = not hasattr(spec, "triangle_family")
    params = [inspect.Parameter("self", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
    params += [inspect.Parameter(a, inspect.Parameter.POSITIONAL_OR_KEYWORD) for a in args]
    if not is_light:
        params.append(inspect.Parameter("material", inspect.Parameter.POSITIONAL_OR_KEYWORD))
    for k in optional:
        params.append(inspect.Parameter(k.name, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=k.default))
    sig = inspect.Signature(params)

    def method(self, *a, **kw):
        bound = sig.bind(self, *a, **kw)
        bound.apply_defaults()
        values = dict(bound.arguments)
        values.pop("self")
        if is_light:
            return self.add_light(spec.name, **values)
        material = values.pop("material")
        return self.add(spec.name, material, **values)

    method.__signature__ = sig  # type: ignore[attr-defined]
    method.__name__ = method.__qualname__ = spec.builder if is_light else spec.name
    method.__doc__ = doc
    return method


def _install_builder_methods():
    for spec in KINDS:
        keys = spec.keys or ()
        args = [k.name for k in keys if k.default is None] or list(spec.builder_args)
        optional = [k for k in keys if k.default is not None]
        shapes = ", ".join(f"``{k.name}`` {k.shape}" for k in keys) or "``vertices (V, 3)``, ``faces (F, 3)`` int"
        doc = (
            f"Add a {spec.name} (:class:`{spec.module.__module__}.{spec.module.__name__}`): {shapes}, "
            f"and the name of its material. Same as ``add({spec.name!r}, material, ...)``; returns the builder."
        )
        setattr(SceneBuilder, spec.name, _builder_method(spec, args, optional, doc))
    for spec in LIGHTS:
        args = [k.name for k in spec.keys if k.default is None]
        optional = [k for k in spec.keys if k.default is not None]
        shapes = ", ".join(f"``{k.name}`` {k.shape}" for k in spec.keys)
        doc = (
            f"Add a {spec.name} light (:class:`{spec.module.__module__}.{spec.module.__name__}`): {shapes}. "
            f"Same as ``add_light({spec.name!r}, ...)``; returns the builder."
        )
        setattr(SceneBuilder, spec.builder, _builder_method(spec, args, optional, doc))


_install_builder_methods()
