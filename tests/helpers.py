"""Shared helpers for the test-suite: tiny scenes used by several test files."""

from __future__ import annotations

import contextlib
import logging
import re

import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt


def grid_mesh(k, half, height=None):
    """A k x k grid of cells over ``[-half, half]^2`` in the xz plane, two triangles each:
    vertices ``((k + 1)^2, 3)`` (y from ``height(x, z)``, else 0) and faces ``(2 k^2, 3)``;
    the triangles of a cell, and neighbouring cells, share edges and vertices."""
    x, z = np.meshgrid(np.linspace(-half, half, k + 1), np.linspace(-half, half, k + 1))
    y = np.zeros_like(x) if height is None else height(x, z)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    i = np.arange(k * (k + 1)).reshape(k, k + 1)[:, :k].ravel()
    f = np.concatenate([np.stack([i, i + k + 1, i + 1], 1), np.stack([i + 1, i + k + 1, i + k + 2], 1)])
    return v, f


def jit_grad(loss):
    """``jax.grad(loss)`` as one jitted program with raytrax's compiler options: the plain
    gradients that edge tests compare with (an eager ``jax.grad`` compiles the forward and
    the backward half of a render apart, about a fifth longer)."""
    return jax.jit(jax.grad(loss), compiler_options=rt.compiler_options())


def one_sphere_scene(shading="classic", *, width=16, height=16, spp=1, dtype=jnp.float32, **mat):
    """A unit sphere at the origin seen from +z, one light; ``mat`` overrides the material."""
    b = rt.SceneBuilder(
        shading, width=width, height=height, spp=spp, max_depth=2, background=(0.0, 0.0, 0.0), ambient=(0.1, 0.1, 0.1)
    )
    b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=30)
    b.light((0, 0, 10), intensity=(1.0, 1.0, 1.0))
    b.material("m", **({"color": (0.8, 0.5, 0.2)} | mat))
    b.sphere((0, 0, 0), 1.0, "m")
    return b.build(dtype)


def to_np(x):
    return np.asarray(x)


def camera_rays_np(position, look_at, up, fov, width, height):
    """Pixel-centre ray directions ``(height * width, 3)`` (row-major, row 0 at the
    top) of a pinhole camera, computed independently of raytrax in numpy float64:
    ``d = normalize(fwd + x tan(fov/2) (W/H) right + y tan(fov/2) up)``."""
    import math

    pos = np.asarray(position, np.float64)
    fwd = np.asarray(look_at, np.float64) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, np.float64))
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    row, col = np.divmod(np.arange(width * height), width)
    x = (col + 0.5) / width * 2 - 1
    y = 1 - (row + 0.5) / height * 2
    th = math.tan(math.radians(fov) / 2)
    d = fwd + (x * th * width / height)[:, None] * right + (y * th)[:, None] * upv
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def ray_sphere_np(o, d, center, radius):
    """Nearest ``t > 0`` of rays ``o, d (n, 3)`` (``d`` unit) with a sphere, inf on a miss."""
    oc = np.asarray(o, np.float64) - np.asarray(center, np.float64)
    b = (d * oc).sum(-1)
    c = (oc * oc).sum(-1) - radius * radius
    disc = b * b - c
    sq = np.sqrt(np.maximum(disc, 0.0))
    t1, t2 = -b - sq, -b + sq
    t = np.where(t1 > 0, t1, np.where(t2 > 0, t2, np.inf))
    return np.where(disc >= 0, t, np.inf)


_JAX_SETUP = ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES", "RAYTRAX_CPU_DEVICES", "RAYTRAX_XLA_FLAGS")


def python_output(code: str, **env) -> str:
    """stdout of ``python -c code`` in a fresh interpreter whose environment has none
    of the jax and raytrax setup variables of this one (the suite's conftest sets
    some), plus ``env``."""
    import os
    import subprocess
    import sys

    clean = {k: v for k, v in os.environ.items() if k not in _JAX_SETUP}
    out = subprocess.run(
        [sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True, timeout=120, check=True
    )
    return out.stdout


@contextlib.contextmanager
def compiled_programs():
    """Within the block, the names of the programs XLA compiles (``jit(name)``, in order)
    are appended to the yielded list (jax's ``jax_log_compiles`` messages)."""
    names: list[str] = []

    class Handler(logging.Handler):
        def emit(self, record):
            m = re.search(r"Finished XLA compilation of (\S+) in", record.getMessage())
            if m:
                names.append(m.group(1))

    handler = Handler(logging.DEBUG)
    loggers = [logging.getLogger(n) for n in ("jax._src.interpreters.pxla", "jax._src.dispatch")]
    before = jax.config.values["jax_log_compiles"]
    jax.config.update("jax_log_compiles", True)
    for lg in loggers:
        lg.addHandler(handler)
    try:
        yield names
    finally:
        for lg in loggers:
            lg.removeHandler(handler)
        jax.config.update("jax_log_compiles", before)
