"""Shared helpers for the test-suite: tiny scenes used by several test files."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import raytrax as rt


def one_sphere_scene(shading="classic", *, width=16, height=16, spp=1, dtype=jnp.float32, **mat):
    """A unit sphere at the origin seen from +z, one light; ``mat`` overrides the material."""
    b = rt.SceneBuilder(shading, width=width, height=height, spp=spp, max_depth=2,
                        background=(0.0, 0.0, 0.0), ambient=(0.1, 0.1, 0.1))
    b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=30)
    b.light((0, 0, 10), intensity=(1.0, 1.0, 1.0))
    b.material("m", **({"color": (0.8, 0.5, 0.2)} | mat))
    b.sphere((0, 0, 0), 1.0, "m")
    return b.build(dtype)


def to_np(x):
    return np.asarray(x)
