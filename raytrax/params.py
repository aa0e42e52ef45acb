"""Scene parameters by name.

:func:`parameters` flattens every differentiable float of a :class:`~raytrax.Scene`
into a dict keyed by the path a scene file would use for it, and
:func:`with_parameters` writes such values back::

    p = raytrax.parameters(scene)
    p["light[0].position"]          # (3,)
    p["material.glass.ior"]         # ()
    p["object[2].radius"]           # ()  (the third [[object]] of the file)
    scene2 = raytrax.with_parameters(scene, {"material.glass.ior": 1.4})

Names
-----
=====================================  ============  =========================================
name                                   shape         meaning
=====================================  ============  =========================================
``camera.position`` / ``.look_at``     ``(3,)``      camera centre / target point
``camera.up``                          ``(3,)``      up vector
``camera.fov``                         ``()``        vertical field of view, degrees
``light[i].position`` / ``.intensity`` ``(3,)``      the i-th ``[[light]]``, a point light
``light[i].direction`` / ``.irradiance`` ``(3,)``    a directional light
``material.NAME.color``                ``(3,)``      colour / albedo
``material.NAME.ambient`` ...          ``()``        ``ambient``, ``diffuse``, ``specular``,
                                                     ``shininess``, ``transparency``, ``ior``
``material.NAME.reflectivity``         ``(3,)``      mirror weight / reflectance
``material.NAME.texture.color2``       ``(3,)``      checker / stripes second colour
``material.NAME.texture.scale``        ``()``        checker / stripes frequency
``material.NAME.texture.direction``    ``(2,)``      stripes direction in ``(u, v)``
``material.NAME.texture.image``        ``(H, W, 3)`` image texture texels (linear RGB)
``object[i].center``, ``.radius``      ``(3,)``,()   sphere
``object[i].point``, ``.normal``       ``(3,)``      plane
``object[i].corners``                  ``(4, 3)``    quad
``object[i].vertices``                 ``(3, 3)``    triangle; ``(V, 3)`` for a mesh
``object[i].center``, ``.size``        ``(3,)``,()   tetrahedron
``object[i].center``, ``.normal``,     ``(3,)``,()   disk
``.radius``
``object[i].min``, ``.max``            ``(3,)``      box corners before rotation
``object[i].rotation``                 ``(3,)``      box Euler angles, degrees
``render.background``                  ``(3,)``      radiance of escaped rays
``render.ambient``                     ``(3,)``      classic ambient light
=====================================  ============  =========================================

Texture entries exist only for materials that have that kind of texture.
``object[i]`` counts the objects in the order they were added (the scene
file's ``[[object]]`` order), whatever their kind.

Both functions are pure and work inside ``jax.jit``, ``jax.grad``,
``jax.jacfwd`` and ``jax.vmap``: values are slices of the scene's stacked
arrays, and replacements are ``.at[i].set`` updates assembled with
:func:`equinox.tree_at`. The one thing they read from the scene's *values*
is the per-material texture kind (an integer leaf), which decides which
``texture.*`` names exist; if a scene with textures is traced as a whole (a
``jit`` argument, not a closure) that is unknown and a clear error says so.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import textures as tx
from .lights import BY_NAME as LIGHT_BY_NAME
from .shapes import BY_NAME

__all__ = ["parameters", "with_parameters", "parameter_names"]

_MAT_SCALARS = ("ambient", "diffuse", "specular", "shininess", "transparency", "ior")


class _Slot(NamedTuple):
    """Where a named parameter lives: ``get(scene)`` is the whole leaf, ``index`` the
    row within it (``None``: the whole leaf), ``shape`` the parameter's shape."""

    get: Callable[[Any], Any]
    index: Any
    shape: tuple
    rgb: bool = False


def _concrete(x) -> np.ndarray | None:
    """``x`` as a NumPy array, or ``None`` when it is a tracer."""
    try:
        return np.asarray(x)
    except Exception:  # jax.errors.TracerArrayConversionError and friends
        return None


def _texture_info(scene):
    """Per material: texture kind and image index (NumPy), or ``None`` when unknowable."""
    m = scene.materials
    if not m.kinds_present and not m.images:
        n = m.color.shape[0]
        return np.zeros(n, np.int32), np.zeros(n, np.int32)
    kind, img = _concrete(m.tex_kind), _concrete(m.tex_image)
    if kind is None or img is None:
        return None
    return kind, img


def _slots(scene, need_textures: bool = True) -> dict[str, _Slot]:
    """Every named parameter of ``scene`` and where it lives (insertion order is the
    order of :func:`parameters`)."""
    S: dict[str, _Slot] = {}
    for f in ("position", "look_at", "up"):
        S[f"camera.{f}"] = _Slot(lambda s, f=f: getattr(s.camera, f), None, (3,))
    S["camera.fov"] = _Slot(lambda s: s.camera.fov, None, ())

    for j, (typ, k) in enumerate(scene.light_index):
        spec = LIGHT_BY_NAME[typ]
        for key, get, row, shape, rgb in spec.slots(scene.light_sets[spec.field], k):
            S[f"light[{j}].{key}"] = _Slot(lambda s, f=spec.field, get=get: get(s.light_sets[f]), row, shape, rgb)

    mats = scene.materials
    info = _texture_info(scene) if need_textures else None
    if need_textures and info is None:
        raise ValueError(
            "raytrax.parameters: this scene has textures and its integer leaves (the per-material "
            "texture kinds) are traced, so the texture parameter names cannot be determined. Call "
            "parameters()/with_parameters() on a concrete scene: close over the scene in the function "
            "you jit/grad/vmap and pass only the parameter values through the transformation."
        )
    for m, name in enumerate(scene.material_names):
        p = f"material.{name}"
        S[f"{p}.color"] = _Slot(lambda s: s.materials.color, m, (3,), True)
        for f in _MAT_SCALARS[:4]:
            S[f"{p}.{f}"] = _Slot(lambda s, f=f: getattr(s.materials, f), m, ())
        S[f"{p}.reflectivity"] = _Slot(lambda s: s.materials.reflectivity, m, (3,), True)
        for f in _MAT_SCALARS[4:]:
            S[f"{p}.{f}"] = _Slot(lambda s, f=f: getattr(s.materials, f), m, ())
        if info is None:
            continue
        kind = int(info[0][m])
        if kind in (tx.CHECKER, tx.STRIPES):
            S[f"{p}.texture.color2"] = _Slot(lambda s: s.materials.tex_color2, m, (3,), True)
            S[f"{p}.texture.scale"] = _Slot(lambda s: s.materials.tex_scale, m, ())
        if kind == tx.STRIPES:
            S[f"{p}.texture.direction"] = _Slot(lambda s: s.materials.tex_direction, m, (2,))
        if kind == tx.IMAGE:
            j = int(info[1][m])
            S[f"{p}.texture.image"] = _Slot(lambda s, j=j: s.materials.images[j], None, tuple(mats.images[j].shape))

    for i, (kind, k) in enumerate(scene.object_index):
        spec = BY_NAME[kind]
        for key, get, row, shape in spec.slots(scene.prims[spec.field], k):
            S[f"object[{i}].{key}"] = _Slot(lambda s, f=spec.field, get=get: get(s.prims[f]), row, shape)

    S["render.background"] = _Slot(lambda s: s.environment.background, None, (3,), True)
    S["render.ambient"] = _Slot(lambda s: s.environment.ambient, None, (3,), True)
    return S


def _read(scene, slot: _Slot):
    leaf = slot.get(scene)
    return leaf if slot.index is None else leaf[slot.index]


def parameters(scene) -> dict[str, jax.Array]:
    """Every differentiable float of ``scene``, keyed by its scene-file path.

    Returns a new ``dict`` (insertion order: camera, lights, materials, objects,
    render) of arrays in the scene's float dtype; see the module docstring for
    the names and shapes. Pure: under ``jax.grad`` the values carry the scene's
    tangents.
    """
    return {name: _read(scene, slot) for name, slot in _slots(scene).items()}


def parameter_names(scene) -> list[str]:
    """The names :func:`parameters` would return, in the same order."""
    return list(_slots(scene))


def _unknown(name, known) -> ValueError:
    if not isinstance(name, str):
        return ValueError(f"raytrax.with_parameters: parameter names are strings, got {name!r}")
    near = difflib.get_close_matches(name, known, n=4, cutoff=0.6)
    if not near:  # e.g. "object[7].center" in a 3-object scene: suggest by prefix
        head = name.split(".")[0]
        near = [k for k in known if k.startswith(head + ".")][:4]
    hint = f"; did you mean {', '.join(repr(n) for n in near)}?" if near else ""
    return ValueError(
        f"raytrax.with_parameters: unknown parameter {name!r}{hint} "
        f"(this scene has {len(known)} parameters; list them with raytrax.parameters(scene))"
    )


def with_parameters(scene, values: Mapping[str, Any]):
    """A copy of ``scene`` with the named parameters replaced by ``values``.

    ``values`` maps names (as returned by :func:`parameters`) to arrays or
    numbers of that parameter's shape (an RGB parameter also accepts a scalar,
    broadcast to the three channels); each is cast to the leaf's dtype.
    Unknown names and wrong shapes raise :class:`ValueError`. Pure and
    traceable: values may be tracers of ``jit``, ``grad``, ``jacfwd``, ``vmap``.
    """
    if not values:
        return scene
    needs_tex = any(isinstance(k, str) and ".texture." in k for k in values)
    slots = _slots(scene, need_textures=needs_tex)
    known = list(slots)
    # Group the updates by the leaf they write to (several rows of one stacked array).
    groups: dict[int, list] = {}
    order: list = []
    for name, value in values.items():
        slot = slots.get(name) if isinstance(name, str) else None
        if slot is None:
            raise _unknown(name, known)
        leaf = slot.get(scene)
        v = jnp.asarray(value)
        if not (jnp.issubdtype(v.dtype, jnp.floating) or jnp.issubdtype(v.dtype, jnp.integer) or v.dtype == jnp.bool_):
            raise ValueError(f"raytrax.with_parameters: {name!r}: expected a real number array, got dtype {v.dtype}")
        if slot.rgb and v.shape == ():
            v = jnp.broadcast_to(v, (3,))
        if tuple(v.shape) != slot.shape:
            raise ValueError(f"raytrax.with_parameters: {name!r}: expected shape {slot.shape}, got {tuple(v.shape)}")
        if v.dtype != leaf.dtype:
            v = v.astype(leaf.dtype)
        key = id(leaf)
        if key not in groups:
            groups[key] = [slot.get, leaf, []]
            order.append(key)
        groups[key][2].append((slot.index, v))
    getters, new_leaves = [], []
    for key in order:
        get, leaf, updates = groups[key]
        if updates[0][0] is None:  # a whole leaf (camera fields, images, mesh vertices...)
            new = updates[0][1]
        else:
            rows = {i: v for i, v in updates}
            if sorted(rows) == list(range(leaf.shape[0])):  # every row: one stack, no scatter
                new = jnp.stack([rows[i] for i in range(leaf.shape[0])])
            elif len(rows) == 1:
                new = leaf.at[updates[0][0]].set(updates[0][1])
            else:
                idx = np.asarray(sorted(rows), dtype=np.int32)
                new = leaf.at[idx].set(jnp.stack([rows[int(i)] for i in idx]))
        getters.append(get)
        new_leaves.append(new)
    return eqx.tree_at(lambda s: [g(s) for g in getters], scene, new_leaves)
