"""What every light type shares: the :class:`LightSpec` interface that the light
registry (:mod:`raytrax.lights.registry`) lists.

A light type is one module of :mod:`raytrax.lights` holding an
:class:`equinox.Module` with the stacked parameters of all lights of that type and a
:class:`LightSpec` subclass that says how the type is validated, built, described,
named by :func:`raytrax.parameters`, and how it lights a point: the direction
towards it, the length of the shadow segment and the falloff of irradiance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import ClassVar, NamedTuple

import jax
import numpy as np

from ..shapes.base import F64, Key, check_stored


class LightSample(NamedTuple):
    """How light ``l`` reaches points ``p (3, n)``: the unit direction towards it
    ``(3, n)``, the length of the shadow segment ``(n,)`` (``inf``: no end), its
    strength ``(3,)`` (colour in classic shading; radiant intensity in W/sr or
    irradiance in W/m^2 in physical shading) and the physical falloff ``(n,)`` that
    multiplies ``strength * cos`` (``1 / r^2`` for a point light, ``1`` for a
    directional one)."""

    direction: jax.Array
    distance: jax.Array
    strength: jax.Array
    falloff: jax.Array


@dataclasses.dataclass(frozen=True)
class LightSpec:
    """One light type. Defaults implement a stacked type whose module's fields are
    the keys' ``attr`` in order, each ``(L,) + shape``."""

    name: ClassVar[str]  # the scene file's ``type``
    field: ClassVar[str]  # the Scene attribute (``scene.lights``)
    builder: ClassVar[str]  # the SceneBuilder method (``b.light``)
    module: ClassVar[type]
    keys: ClassVar[tuple[Key, ...]]
    directional: ClassVar[bool] = False  # at infinity: raytrax.edges follows its direction

    def validate(self, params: dict, where: str) -> dict:
        out = {}
        for k in self.keys:
            v = params.get(k.name, k.default)
            if v is None:
                raise ValueError(f"{where}.{k.name}: missing")
            a = np.asarray(v, dtype=np.float64)
            if k.ftype == "rgb" and a.shape == ():
                a = np.full(3, float(a))
            try:
                out[k.name] = F64(a, k.shape)
            except ValueError as e:
                raise ValueError(f"{where}.{k.name}: {e}") from None
            if k.ftype == "rgb" and np.any(out[k.name] < 0):
                raise ValueError(f"{where}.{k.name}: expected non-negative numbers, got {out[k.name].tolist()}")
        self.check(out, where)
        check_stored(self, out, where)
        return out

    def check(self, p: dict, where: str) -> None:
        """Value checks beyond shapes and finiteness."""

    def build(self, items: list, F: Callable):
        return self.module(*[F([p[k.name] for p in items], (-1,) + k.shape) for k in self.keys])

    def count(self, group) -> int:
        return int(getattr(group, self.keys[0].attr).shape[0])

    def describe(self, group, j: int) -> dict:
        return {k.name: tuple(float(x) for x in np.asarray(getattr(group, k.attr)[j])) for k in self.keys}

    def slots(self, group, j: int) -> list:
        """``(key, get(group) -> leaf, row, shape, rgb)`` of light ``j``'s named parameters."""
        return [(k.name, (lambda g, a=k.attr: getattr(g, a)), j, k.shape, k.ftype == "rgb") for k in self.keys]

    def sample(self, group, l: int, p) -> LightSample:
        """How light ``l`` of the group reaches points ``p (3, n)``."""
        raise NotImplementedError

    def edge_geometry(self, group):
        """``(L, 3)`` for :mod:`raytrax.edges`: positions, or travel directions if
        ``directional``."""
        raise NotImplementedError
