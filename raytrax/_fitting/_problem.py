"""The fitting problem: the scene, the target and the fitted parameters as one pytree.

Its arrays are traced and the rest is static, so compiled steps are reused across
fits of the same structure (new values, new target).
"""

from __future__ import annotations

import re
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..renderer import render
from ..scene import Scene


class _Frozen:
    """A hashable pytree of (integer) NumPy arrays, kept static under ``jit``.

    The scene's integer leaves (material ids, texture kinds) are passed this
    way so that they stay concrete inside compiled steps (the renderer and
    :func:`raytrax.with_parameters` read them) while the float leaves are
    traced; equal contents hit the same compiled step.
    """

    def __init__(self, tree):
        self.tree = jax.tree_util.tree_map(np.asarray, tree)
        leaves, treedef = jax.tree_util.tree_flatten(self.tree)
        self._key = (treedef, tuple((a.shape, a.dtype.str, a.tobytes()) for a in leaves))
        self._hash = hash(self._key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, _Frozen) and self._hash == other._hash and self._key == other._key


def _is_float_array(x):
    """Whether ``x`` is a float (or complex) array: the leaves that are traced."""
    return eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.inexact)


class _Problem(eqx.Module):
    """The scene (float leaves traced, the rest static), the target, the weights and
    the fitted parameters' bounds, with the functions optimistix solves.

    The solver works on unconstrained values ``z`` (a dict name -> array);
    :meth:`values` maps them into the bounds.
    """

    floats: Scene  # the scene's float leaves (None elsewhere)
    ints: _Frozen = eqx.field(static=True)  # and the rest
    target: jax.Array  # (H, W, 3), or (V * H, W, 3): V views stacked along the height
    weights: jax.Array  # shaped like target, sums to 1
    scale: jax.Array  # () 1 / loss at the start
    lo: dict  # name -> array (finite where the parameter has a lower bound)
    hi: dict
    key: jax.Array | None
    names: tuple = eqx.field(static=True)
    dtypes: tuple = eqx.field(static=True)  # the scene's dtype of each fitted parameter
    maps: tuple = eqx.field(static=True)  # per name: "none" | "lower" | "upper" | "both"
    by_path: bool = eqx.field(static=True)  # names are pytree paths (selector), not raytrax.parameters names
    render_opts: tuple = eqx.field(static=True)
    loss_fn: Callable | None = eqx.field(static=True)
    reg_fn: Callable | None = eqx.field(static=True, default=None)
    cameras: tuple | None = None  # per view a camera (traced) or None (the scene's); None: one view

    @property
    def views(self) -> int:
        """The number of views stacked in the image."""
        return 1 if self.cameras is None else len(self.cameras)

    # z (unconstrained) -> parameter values
    def values(self, z):
        out = {}
        for name, kind in zip(self.names, self.maps):
            x = z[name]
            if kind == "lower":
                x = self.lo[name] + jax.nn.softplus(x)
            elif kind == "upper":
                x = self.hi[name] - jax.nn.softplus(x)
            elif kind == "both":
                x = self.lo[name] + (self.hi[name] - self.lo[name]) * jax.nn.sigmoid(x)
            out[name] = x
        return out

    def scene_values(self, z):
        """The parameter values at ``z`` in the scene's dtype (what goes into the scene)."""
        v = self.values(z)
        return {n: v[n].astype(dt) for n, dt in zip(self.names, self.dtypes)}

    def scene_at(self, z):
        vals = self.scene_values(z)
        # Integer leaves as NumPy while the values are written (raytrax.with_parameters
        # reads the texture kinds), then as JAX arrays for the renderer.
        scene = _set_values(eqx.combine(self.floats, self.ints.tree), vals, self.by_path)
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x) if isinstance(x, np.ndarray) else x, scene)

    def image(self, z):
        """The render at ``z``; with several views, one render per camera stacked along the height."""
        kw = dict(self.render_opts)
        scene = self.scene_at(z)
        if self.cameras is None:
            return render(scene, key=self.key, **kw)
        return jnp.concatenate(
            [
                render(scene if cam is None else eqx.tree_at(lambda s: s.camera, scene, cam), key=self.key, **kw)
                for cam in self.cameras
            ],
            axis=0,
        )

    def raw_loss(self, img):
        if self.loss_fn is not None:
            return self.loss_fn(img, self.target)
        d = img - self.target
        return jnp.sum(self.weights * d * d)

    # optimistix-facing functions: fn(y, args) -> (out, aux)
    def residual(self, z, args):
        d = self.image(z) - self.target
        r = (jnp.sqrt(self.weights) * d).reshape(-1).astype(self.scale.dtype)
        return jnp.sqrt(self.scale) * r, None

    def total_loss(self, img, z):
        out = self.raw_loss(img).astype(self.scale.dtype)
        if self.reg_fn is not None:
            out = out + jnp.asarray(self.reg_fn(self.values(z))).astype(self.scale.dtype)
        return out

    def objective(self, z, args):
        return self.scale * self.total_loss(self.image(z), z), None


def _set_values(scene, values, by_path):
    """``scene`` with the fitted ``values`` put in, by :func:`raytrax.parameters` name or by pytree path."""
    if not by_path:
        from ..params import with_parameters

        return with_parameters(scene, values)
    flat, treedef = jax.tree_util.tree_flatten_with_path(scene)
    leaves = []
    for path, leaf in flat:
        name = _path_name(path)
        leaves.append(values[name].astype(leaf.dtype) if name in values else leaf)
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _path_name(path):
    """A pytree path as a parameter name: ``"lights.position"`` (the scene's kind and
    light-type groups by their attribute names, ``spheres.center``, not
    ``prims['spheres'].center``)."""
    name = jax.tree_util.keystr(path).lstrip(".")
    return re.sub(r"^(?:prims|light_sets)\['([A-Za-z_]+)'\]", r"\1", name)
