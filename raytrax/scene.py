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
from . import limits as L
from . import textures as tx
from .camera import Camera
from .lights import BY_FIELD as LIGHT_BY_FIELD
from .lights import BY_NAME as LIGHT_BY_NAME
from .lights import LIGHTS, LightSpec
from .materials import Materials
from .shapes import BY_FIELD, BY_NAME, KINDS

SHADING_MODELS = L.SHADING_MODELS
_R, _C, _M = L.RENDER_DEFAULTS, L.CAMERA_DEFAULTS, L.MATERIAL_DEFAULTS


@dataclasses.dataclass(frozen=True)
class Settings:
    """Static render settings (they fix shapes and the traced program).

    - ``shading``: ``"classic"`` or ``"physical"``.
    - ``width``, ``height``: image size in pixels (default 640 x 480, as in scene
      files: :data:`raytrax.limits.RENDER_DEFAULTS`).
    - ``spp``: samples per pixel, a square number (``n x n`` stratified grid).
    - ``max_depth``: number of specular interactions a path may have.
    - ``filter_textures``: box-filter procedural textures over the footprint.
    - ``branches``: specular branches kept per camera sample at each depth
      (1 when no material can split a path into a reflected and a refracted ray;
      2 otherwise). Branches beyond this budget, the lightest first, are dropped.
    """

    shading: str = _R.shading
    width: int = _R.width
    height: int = _R.height
    spp: int = _R.spp
    max_depth: int = _R.max_depth
    filter_textures: bool = _R.filter_textures
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


def _text(a) -> str:
    """An array's values as messages write them: ``2.0`` or ``[2.0, 1.0, 1.0]``."""
    a = np.asarray(a)
    if a.ndim == 0:
        return L.show_number(a.item())
    return str(np.asarray(a, dtype=np.float64).tolist())


def _finite(a, what):
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: expected finite numbers, got {_text(a)}")


def _number(x, what, rng: L.Range) -> float:
    """``x`` as a float, checked against ``rng`` (message as in scene files)."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected {rng.what}, got {x!r}") from None
    if a.shape != ():
        raise ValueError(f"{what}: expected {rng.what}, got an array of shape {a.shape}")
    _check_number(x if isinstance(x, (int, np.integer)) and not isinstance(x, bool) else float(a), what, rng)
    return float(a)


def _check_number(x, what, rng: L.Range):
    msg = L.number_problem(x, rng)
    if msg:
        raise ValueError(f"{what}: {msg}")


def _rgb(x, what, rng: L.Range | None = None):
    """``x`` (an RGB triple or one number for grey) as a ``(3,)`` float64 array; checked
    against ``rng`` when given (otherwise only shape and finiteness)."""
    expected = L.rgb_what(rng or L.RGB_NON_NEGATIVE)
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected {expected}, got {x!r}") from None
    if a.shape == ():
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise ValueError(f"{what}: expected {expected}, got an array of shape {a.shape}")
    _finite(a, what)
    if rng is not None:
        _check_rgb(a, what, rng, x if np.ndim(x) == 0 else None)
    return a


def _check_rgb(a, what, rng: L.Range, found=None):
    _finite(a, what)
    msg = L.rgb_problem(a, rng, found)
    if msg:
        raise ValueError(f"{what}: {msg}")


def _check_camera(pos, at, up, fov):
    """The camera checks (also run on the values as stored, see :meth:`SceneBuilder.build`)."""
    for name, v in (("position", pos), ("look_at", at), ("up", up)):
        _finite(v, f"camera.{name}")
    if np.linalg.norm(at - pos) == 0:
        raise ValueError("camera.look_at: must differ from camera.position")
    if np.linalg.norm(np.cross(at - pos, up)) < 1e-9 * np.linalg.norm(at - pos) * max(np.linalg.norm(up), 1e-300):
        raise ValueError("camera.up: must not be parallel to the viewing direction")
    _check_number(fov, "camera.fov", L.FOV)


def _check_render(shading, render: dict):
    """Shading model and ``[render]`` settings against :mod:`raytrax.limits` (the
    scene file's messages)."""
    msg = L.check_shading(shading)
    if msg:
        raise ValueError(f"shading: {msg}")
    for k in ("width", "height", "spp", "max_depth", "filter_textures"):
        msg = L.check_render_value(k, render[k])
        if msg:
            raise ValueError(f"render.{k}: {msg}")
    msg = L.check_pixels(render["width"], render["height"])
    if msg:
        raise ValueError(f"render: {msg}")


def _plain_int(v):
    """NumPy integers and booleans as Python ones (the render settings are static)."""
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    return v


@dataclasses.dataclass
class _Tex:
    """A material's texture as validated: ``kind`` (:data:`raytrax.textures.CHECKER`, ...),
    the procedural parameters and the image (``None`` unless an image texture)."""

    kind: int
    color2: np.ndarray
    scale: float
    direction: np.ndarray
    image: np.ndarray | None = None


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
    texture: _Tex | None


def _texture(t, w, color_range: L.Range) -> _Tex | None:
    """A texture description as a :class:`_Tex` (``color2`` in ``color_range``, the
    material colour's; the rest of the ranges are checked by :func:`_check_material`)."""
    if t is None:
        return None
    d = L.TEXTURE_DEFAULTS
    if isinstance(t, (tx.Checker, tx.Stripes)):
        c2 = _rgb(t.color2, f"{w}.color2", color_range)
        scale = _number(t.scale, f"{w}.scale", L.TEXTURE_SCALE)
        if isinstance(t, tx.Checker):
            return _Tex(tx.CHECKER, c2, scale, np.asarray(d.direction, np.float64))
        what = f"{w}.direction"
        try:
            direction = np.asarray(t.direction, dtype=np.float64)
        except (TypeError, ValueError):
            direction = None
        if direction is None or direction.shape != (2,):
            raise ValueError(f"{what}: expected a [du, dv] array of 2 numbers, got {t.direction!r}")
        _finite(direction, what)
        return _Tex(tx.STRIPES, c2, scale, direction)
    if isinstance(t, tx.ImageTexture):
        img = np.asarray(t.image)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
            raise ValueError(f"{w}: expected an (H, W, 3) image, got shape {img.shape}")
        msg = L.check_texture_pixels(img.shape[0], img.shape[1])
        if msg:
            raise ValueError(f"{w}: {msg}")
        return _Tex(tx.IMAGE, np.zeros(3), d.scale, np.asarray(d.direction, np.float64), img)
    raise ValueError(f"{w}: expected Checker, Stripes or ImageTexture, got {t!r}")


class _AsStored:
    """Values as a scene of float ``dtype`` stores them (``None``: as they are):
    ``rnd(x)`` is a float64 copy of ``x`` rounded to ``dtype``, ``rnd.image(img)`` the
    image in ``dtype`` itself (no float64 copy of a large image)."""

    def __init__(self, dtype=None):
        self.dtype = dtype

    def __call__(self, a):
        if self.dtype is None:
            return a
        with np.errstate(over="ignore", under="ignore"):
            return np.asarray(np.asarray(a, dtype=self.dtype), dtype=np.float64)

    def image(self, img):
        if self.dtype is None:
            return img
        with np.errstate(over="ignore", under="ignore"):
            return np.asarray(img, dtype=self.dtype)


def _check_material(m: _Mat, shading: str, w: str, rnd: _AsStored = _AsStored()):
    """Range checks of material ``m`` in ``shading`` (:func:`raytrax.limits.material_ranges`)
    on the values ``rnd(value)`` (the values as stored, in :meth:`SceneBuilder.build`)."""
    ranges = L.material_ranges(shading)
    _check_rgb(rnd(m.color), f"{w}.color", ranges["color"])
    for k in ("ambient", "diffuse", "specular", "shininess"):
        _check_number(float(rnd(getattr(m, k))), f"{w}.{k}", ranges[k])
    _check_rgb(rnd(m.reflectivity), f"{w}.reflectivity", ranges["reflectivity"])
    for k in ("transparency", "ior"):
        _check_number(float(rnd(getattr(m, k))), f"{w}.{k}", ranges[k])
    t = m.texture
    if t is None:
        return
    if t.kind in (tx.CHECKER, tx.STRIPES):
        _check_rgb(rnd(t.color2), f"{w}.texture.color2", ranges["color"])
        _check_number(float(rnd(t.scale)), f"{w}.texture.scale", L.TEXTURE_SCALE)
        direction = rnd(t.direction)
        _finite(direction, f"{w}.texture.direction")
        if not np.any(direction):
            raise ValueError(f"{w}.texture.direction: expected a non-zero [du, dv] direction, got [0, 0]")
    elif t.image is not None:  # an image texture
        img = rnd.image(t.image)
        if not np.all(np.isfinite(img)):
            raise ValueError(f"{w}.texture: expected an image of finite values, found NaN or infinite values")
        if shading == "physical" and img.size and float(img.max()) > 1.0:
            raise ValueError(
                f"{w}.texture: expected an image with values in [0, 1] in physical shading (an albedo), "
                f"found values up to {float(img.max()):.4g}"
            )


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

    Limits, defaults and value ranges are those of scene files
    (:mod:`raytrax.limits`), so that every scene the builder accepts can be saved
    with :func:`raytrax.save_scene` and loaded back; out-of-range values raise
    ``ValueError`` naming the key path the scene file would use
    (``material.red.color: expected an [r, g, b] array of numbers in [0, 1] in
    physical shading (or one number for grey), got [2.0, 1.0, 1.0]``).

    Arguments: ``shading`` (``"classic"`` or ``"physical"``), ``width``, ``height``
    (pixels), ``spp`` (samples per pixel, a square number), ``max_depth`` (specular
    bounces), ``background`` (RGB radiance of escaped rays), ``ambient`` (RGB
    classic ambient light), ``filter_textures`` (box-filter procedural textures over
    each sample's footprint), ``name``. Objects are added with one method per
    primitive kind (``sphere``, ``plane``, ``quad``, ``disk``, ``triangle``,
    ``tetrahedron``, ``mesh``, ``box``; generated from :data:`raytrax.shapes.KINDS`)
    or :meth:`add`; lights with ``light`` (point), ``directional_light`` or
    :meth:`add_light`. Every method returns the builder, so calls chain.

    The default image is **640 x 480** (as in scene files), one sample per pixel,
    ``max_depth`` 5; the default camera is the seed raytracer's (at the origin looking
    down -z, vertical field of view :data:`raytrax.limits.SEED_FOV`, about 28.07
    degrees). :meth:`build` checks the camera, environment and material values
    again as they will be stored (float32 by default), so that e.g. a field of view
    that rounds to 180 degrees is refused there rather than by the file loader.
    """

    def __init__(
        self,
        shading=_R.shading,
        *,
        width=_R.width,
        height=_R.height,
        spp=_R.spp,
        max_depth=_R.max_depth,
        background=_R.background,
        ambient=_R.ambient,
        filter_textures=_R.filter_textures,
        name="scene",
    ):
        if not isinstance(name, str):
            raise ValueError(f"name: expected a string, got {name!r}")
        self.shading = shading
        self.render = dict(
            width=_plain_int(width),
            height=_plain_int(height),
            spp=_plain_int(spp),
            max_depth=_plain_int(max_depth),
            filter_textures=_plain_int(filter_textures),
        )
        _check_render(shading, self.render)
        self.background = _rgb(background, "render.background", L.ENVIRONMENT_RGB)
        self.ambient = _rgb(ambient, "render.ambient", L.ENVIRONMENT_RGB)
        self.name = name
        self._camera = {k: np.array(v, dtype=np.float64) for k, v in dataclasses.asdict(_C).items()}
        self._lights: list = []
        self._mats: dict[str, _Mat] = {}
        self._objects: list = []  # (kind, params dict, material name)

    # -- camera, lights, materials ------------------------------------------
    def camera(
        self,
        position=_C.position,
        look_at=_C.look_at,
        up=_C.up,
        fov=_C.fov,
    ):
        """Place the camera: ``position``, the point ``look_at`` it looks at, the ``up``
        direction and the *vertical* field of view ``fov`` in degrees, in (0, 180)
        (default :data:`raytrax.limits.SEED_FOV`)."""
        pos = _arr(position, None, (3,), "camera.position")
        at = _arr(look_at, None, (3,), "camera.look_at")
        upv = _arr(up, None, (3,), "camera.up")
        fov = _number(fov, "camera.fov", L.FOV)
        _check_camera(pos, at, upv, fov)
        self._camera = dict(position=pos, look_at=at, up=upv, fov=np.float64(fov))
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
        color=_M.color,
        *,
        ambient=_M.ambient,
        diffuse=_M.diffuse,
        specular=_M.specular,
        shininess=_M.shininess,
        reflectivity=_M.reflectivity,
        transparency=_M.transparency,
        ior=_M.ior,
        texture=None,
    ):
        """Define material ``name``. The values' ranges depend on the shading model
        (:func:`raytrax.limits.material_ranges`): ``ambient``, ``diffuse``,
        ``specular``, ``shininess`` >= 0, ``transparency`` in [0, 1], ``ior`` in
        [1, 10]; ``color`` and ``reflectivity`` (RGB, or one number for grey) >= 0,
        and at most 1 in physical shading (as are a texture's ``color2`` and image
        values). ``texture``: a :class:`raytrax.Checker`, :class:`raytrax.Stripes`
        (``scale`` > 0, non-zero ``direction``) or :class:`raytrax.ImageTexture`."""
        if not isinstance(name, str):
            raise ValueError(f"material: expected a material name (a string), got {name!r}")
        w = f"material.{L.toml_key(name)}"
        if name in self._mats:
            raise ValueError(f"{w}: defined twice")
        shading = self.shading if self.shading in L.SHADING_MODELS else _R.shading  # build() reports it
        ranges = L.material_ranges(shading)
        m = _Mat(
            name,
            _rgb(color, f"{w}.color", ranges["color"]),
            _number(ambient, f"{w}.ambient", ranges["ambient"]),
            _number(diffuse, f"{w}.diffuse", ranges["diffuse"]),
            _number(specular, f"{w}.specular", ranges["specular"]),
            _number(shininess, f"{w}.shininess", ranges["shininess"]),
            _rgb(reflectivity, f"{w}.reflectivity", ranges["reflectivity"]),
            _number(transparency, f"{w}.transparency", ranges["transparency"]),
            _number(ior, f"{w}.ior", ranges["ior"]),
            _texture(texture, f"{w}.texture", ranges["color"]),
        )
        _check_material(m, shading, w)  # the texture's colour, scale, direction and image in this shading model
        self._mats[name] = m
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
        self._check_counts()
        # The settings and values again (they are attributes: they may have been
        # changed since), then as they will be stored: a value that passes in float64
        # can round to one that does not in float32 (a field of view of 179.999999
        # rounds to 180, 1e-50 to 0, 1e39 to inf); the file loader would refuse it.
        _check_render(self.shading, self.render)
        self._check_values(_AsStored())
        stored = np.dtype(jax.dtypes.canonicalize_dtype(dt))
        if stored != np.float64:
            try:
                self._check_values(_AsStored(stored))
            except ValueError as e:
                raise ValueError(f"{e} (the value as stored in {stored.name})") from None
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
            else:
                tex_kind.append(t.kind)
                tex_c2.append(t.color2)
                tex_scale.append(t.scale)
                tex_dir.append(t.direction)
                img_ids.append(len(images) if t.kind == tx.IMAGE else 0)
                if t.image is not None:
                    images.append(F(t.image))
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

        # From the stored values: a transparency that rounds to 0 does not split paths
        # (and a loaded copy of the scene sees 0).
        splits = bool(np.any(np.asarray(materials.transparency) > 0))
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

    def _check_counts(self):
        """The counts of :data:`raytrax.limits.LIMITS` (lights, materials, objects,
        mesh triangles in all), with the scene file's messages."""
        for what, n in (("light", len(self._lights)), ("material", len(self._mats)), ("object", len(self._objects))):
            msg = L.check_count(what, n)
            if msg:
                raise ValueError(f"{what}: {msg}")
        faces = 0
        for i, (kind, p, _) in enumerate(self._objects):
            if kind == "mesh":
                faces += int(np.shape(p["faces"])[0])
                msg = L.check_mesh_faces(faces)
                if msg:
                    raise ValueError(f"object[{i}]: {msg}")

    def _check_values(self, rnd: _AsStored):
        """Range checks of the camera, the environment and the materials on the
        values ``rnd(value)``."""
        c = self._camera
        _check_camera(rnd(c["position"]), rnd(c["look_at"]), rnd(c["up"]), float(rnd(c["fov"])))
        for k in ("background", "ambient"):
            _check_rgb(rnd(getattr(self, k)), f"render.{k}", L.ENVIRONMENT_RGB)
        for name, m in self._mats.items():
            _check_material(m, self.shading, f"material.{L.toml_key(name)}", rnd)


def _builder_method(spec, args, optional, doc):
    """A :class:`SceneBuilder` method for a registered kind or light type: positional
    ``args``, then (objects) the material, then keyword ``optional`` parameters."""
    is_light = isinstance(spec, LightSpec)
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
