"""The golden cases: what ``make_golden.py`` records and ``test_golden.py`` recomputes.

Every case is float64. The renders are small (a few seconds of compilation each). The
gradients are those that ``tests/test_edges.py`` checks against finite differences (and
``tests/test_edges_devices.py`` against a sharded render): the edge scenes at their
files' own settings (regular sample grid, no key), the loss ``mean(smooth_weights *
image)``, with respect to every named parameter. :func:`gradient_case` is cached, so
that the test files that use it, run in one process (the suite puts them in one
``xdist_group``, see ``tests/conftest.py``), compile and compute each gradient once.
"""

from __future__ import annotations

import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
from helpers import jit_grad

import raytrax as rt
from raytrax.testing import smooth_weights

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = sorted(p.stem for p in (ROOT / "scenes").glob("*.toml"))
RENDER_SIZE = dict(width=12, height=9, spp=4)
EDGE_SCENES = ("edge_occluders", "edge_sphere")
GROUP = "edge_cases"
"""The ``xdist_group`` of the tests that share :func:`gradient_case`."""


def _scene(name):
    jax.config.update("jax_enable_x64", True)
    return rt.load_scene(ROOT / "scenes" / f"{name}.toml").astype(jnp.float64)


def render_case(name):
    return np.asarray(rt.render(_scene(name), **RENDER_SIZE))


@functools.cache
def edge_scene(name):
    """The edge scene ``name`` as its file sets it (size, spp, depth), parsed in float64."""
    jax.config.update("jax_enable_x64", True)
    return rt.load_scene(ROOT / "scenes" / f"{name}.toml", dtype=jnp.float64)


def weighted_mean(scene, **render_kwargs):
    """``mean(smooth_weights * render(scene))``: the loss of the gradient cases."""
    st = scene.settings
    return jnp.mean(jnp.asarray(smooth_weights(st.height, st.width)) * rt.render(scene, **render_kwargs))


@functools.cache
def gradient_case(name, edge):
    """``{parameter name: gradient}`` (NumPy) of :func:`weighted_mean` of the edge scene
    ``name`` with respect to every named parameter, plain or (``edge``) edge mode."""
    scene = edge_scene(name)

    def loss(p):
        return weighted_mean(rt.with_parameters(scene, p), edge_gradients=edge)

    # Plain AD as one jitted program (an eager jax.grad compiles its forward and backward
    # halves apart: 14 s against 17 s for edge_occluders); edge mode eagerly (its three
    # programs compile apart, which costs less than one).
    grad = jax.grad(loss) if edge else jit_grad(loss)
    g = grad(rt.parameters(scene))
    return {k: np.asarray(v) for k, v in g.items()}


def compute_all():
    out = {}
    for name in SCENES:
        out[f"render/{name}"] = render_case(name)
    for name in EDGE_SCENES:
        for edge in (False, True):
            for k, v in gradient_case(name, edge).items():
                out[f"grad/{name}/{'edge' if edge else 'plain'}/{k}"] = v
    return out
