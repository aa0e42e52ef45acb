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
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import bvh as _bvh
from . import textures as tx
from .camera import Camera
from .lights import PointLights
from .materials import Materials
from .shapes import Boxes, Mesh, Planes, Quads, Spheres, Tetrahedra, Triangles

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

    ``object_index`` maps the i-th object of the scene description to
    ``(kind, index within kind)``; ``material_names`` names the rows of the
    material table; ``light`` rows follow the description's order. ``bvh`` is
    the topology of the triangle acceleration structure (:mod:`raytrax.bvh`),
    built by :class:`SceneBuilder` for scenes with many triangles.
    """

    camera: Camera
    lights: PointLights
    materials: Materials
    environment: Environment
    spheres: Spheres
    planes: Planes
    quads: Quads
    triangles: Triangles
    tetrahedra: Tetrahedra
    boxes: Boxes
    meshes: tuple
    settings: Settings = eqx.field(static=True)
    object_index: tuple = eqx.field(static=True, default=())
    material_names: tuple = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="scene")
    bvh: _bvh.TriangleBVH | None = None  # leaf order of the merged triangle list (raytrax.bvh); None: brute force

    @property
    def dtype(self):
        return self.camera.position.dtype

    def merged_triangles(self):
        """Every triangle-based primitive as one list: ``vertices (T, 3, 3)`` and
        ``material (T,)``, in the order triangles, tetrahedron faces, mesh faces
        (the order of intersection indices and of :mod:`raytrax.bvh`)."""
        parts = [(self.triangles.vertices, self.triangles.material), self.tetrahedra.triangles()]
        parts += [m.triangles() for m in self.meshes]
        return jnp.concatenate([t for t, _ in parts], 0), jnp.concatenate([m for _, m in parts], 0)

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

    def light(self, position, intensity=(1.0, 1.0, 1.0)):
        i = len(self._lights)
        self._lights.append(
            (_arr(position, None, (3,), f"light[{i}].position"), _rgb(intensity, f"light[{i}].intensity"))
        )
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
    def _add(self, kind, material, **params):
        i = len(self._objects)
        if not isinstance(material, str):
            raise ValueError(f"object[{i}].material: expected a material name, got {material!r}")
        self._objects.append((kind, params, material))
        return self

    def sphere(self, center, radius, material):
        i = len(self._objects)
        r = float(radius)
        if not r > 0:
            raise ValueError(f"object[{i}].radius: expected a positive number, got {radius}")
        return self._add("sphere", material, center=_arr(center, None, (3,), f"object[{i}].center"), radius=r)

    def plane(self, point, normal, material):
        i = len(self._objects)
        n = _arr(normal, None, (3,), f"object[{i}].normal")
        if np.linalg.norm(n) == 0:
            raise ValueError(f"object[{i}].normal: expected a non-zero vector")
        return self._add("plane", material, point=_arr(point, None, (3,), f"object[{i}].point"), normal=n)

    def quad(self, corners, material):
        i = len(self._objects)
        c = _arr(corners, None, (4, 3), f"object[{i}].corners")
        n = np.cross(c[2] - c[0], c[3] - c[1])
        size = max(np.ptp(c, axis=0).max(), 1e-300)
        if np.linalg.norm(n) <= 1e-9 * size * size:
            raise ValueError(
                f"object[{i}].corners: expected a convex quad with non-zero area and corners in "
                f"order around its edge, got a degenerate or self-intersecting quad"
            )
        n = n / np.linalg.norm(n)
        off = np.abs((c - c[0]) @ n).max()
        if off > 1e-6 * size:
            raise ValueError(f"object[{i}].corners: the four corners are not coplanar (off by {off:.3g})")
        for k in range(4):
            e = c[(k + 1) % 4] - c[k]
            if np.dot(np.cross(n, e), c[(k + 2) % 4] - c[k]) < -1e-9 * size * size:
                raise ValueError(f"object[{i}].corners: expected a convex quad with corners in order around its edge")
        return self._add("quad", material, corners=c)

    def triangle(self, vertices, material):
        i = len(self._objects)
        v = _arr(vertices, None, (3, 3), f"object[{i}].vertices")
        size = max(np.ptp(v, axis=0).max(), 1e-300)
        if np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0])) <= 1e-9 * size * size:
            raise ValueError(f"object[{i}].vertices: degenerate triangle (zero area)")
        return self._add("triangle", material, vertices=v)

    def tetrahedron(self, center, size, material):
        i = len(self._objects)
        s = float(size)
        if not s > 0:
            raise ValueError(f"object[{i}].size: expected a positive number, got {size}")
        return self._add("tetrahedron", material, center=_arr(center, None, (3,), f"object[{i}].center"), size=s)

    def box(self, min, max, material, rotation=(0.0, 0.0, 0.0)):
        i = len(self._objects)
        lo = _arr(min, None, (3,), f"object[{i}].min")
        hi = _arr(max, None, (3,), f"object[{i}].max")
        if np.any(hi <= lo):
            raise ValueError(
                f"object[{i}].max: expected every component greater than min, got min={lo.tolist()} max={hi.tolist()}"
            )
        return self._add("box", material, lo=lo, hi=hi, rotation=_arr(rotation, None, (3,), f"object[{i}].rotation"))

    def mesh(self, vertices, faces, material):
        i = len(self._objects)
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
            raise ValueError(f"object[{i}].vertices: expected a (V, 3) array with V >= 3, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"object[{i}].faces: expected an integer (F, 3) array, got shape {f.shape} of {f.dtype}")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"object[{i}].faces: vertex index out of range [0, {v.shape[0]})")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"object[{i}].vertices: expected finite numbers")
        return self._add("mesh", material, vertices=v, faces=f.astype(np.int32))

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
                images.append(F(np.asarray(t.image)))
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

        groups: dict[str, list] = {k: [] for k in ("sphere", "plane", "quad", "triangle", "tetrahedron", "box", "mesh")}
        index = []
        for kind, p, m in self._objects:
            index.append((kind, len(groups[kind])))
            groups[kind].append((p, mid[m]))

        def col(kind, key, shape):
            return F([p[key] for p, _ in groups[kind]], shape)

        def mcol(kind):
            return I([m for _, m in groups[kind]])

        spheres = Spheres(col("sphere", "center", (-1, 3)), col("sphere", "radius", (-1,)), mcol("sphere"))
        planes = Planes(col("plane", "point", (-1, 3)), col("plane", "normal", (-1, 3)), mcol("plane"))
        quads = Quads(col("quad", "corners", (-1, 4, 3)), mcol("quad"))
        triangles = Triangles(col("triangle", "vertices", (-1, 3, 3)), mcol("triangle"))
        tetra = Tetrahedra(
            col("tetrahedron", "center", (-1, 3)), col("tetrahedron", "size", (-1,)), mcol("tetrahedron")
        )
        boxes = Boxes(
            col("box", "lo", (-1, 3)), col("box", "hi", (-1, 3)), col("box", "rotation", (-1, 3)), mcol("box")
        )
        meshes = tuple(
            Mesh(F(p["vertices"]), jnp.asarray(p["faces"]), jnp.asarray(m, dtype=jnp.int32)) for p, m in groups["mesh"]
        )

        splits = any(m.transparency > 0 for m in mats)
        settings = Settings(shading=self.shading, branches=2 if splits else 1, **self.render)
        if self._lights:
            lp = F([p for p, _ in self._lights], (-1, 3))
            li = F([i for _, i in self._lights], (-1, 3))
        else:
            lp = jnp.zeros((0, 3), dt)
            li = jnp.zeros((0, 3), dt)
        c = self._camera
        scene = Scene(
            camera=Camera(F(c["position"]), F(c["look_at"]), F(c["up"]), F(c["fov"])),
            lights=PointLights(lp, li),
            materials=materials,
            environment=Environment(F(self.background), F(self.ambient)),
            spheres=spheres,
            planes=planes,
            quads=quads,
            triangles=triangles,
            tetrahedra=tetra,
            boxes=boxes,
            meshes=meshes,
            settings=settings,
            object_index=tuple(index),
            material_names=tuple(names),
            name=self.name,
        )
        # Triangle acceleration structure (raytrax.bvh) over the merged triangle list
        # (triangles, tetrahedron faces, mesh faces), above the brute-force threshold.
        n_tri = triangles.vertices.shape[0] + 4 * tetra.center.shape[0] + sum(m.faces.shape[0] for m in meshes)
        if n_tri > _bvh.MIN_TRIANGLES:
            scene = dataclasses.replace(scene, bvh=_bvh.for_scene(scene))
        return scene
