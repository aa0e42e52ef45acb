"""The golden cases: what ``make_golden.py`` records and ``test_golden.py`` recomputes.

Every case is float64 and small (a few seconds of compilation each) so that the whole
golden test stays cheap; the edge-mode gradients use the regular sample grid (no key).
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = sorted(p.stem for p in (ROOT / "scenes").glob("*.toml"))
RENDER_SIZE = dict(width=12, height=9, spp=4)
EDGE_SCENES = ("edge_occluders", "edge_sphere")
EDGE_SIZE = dict(width=8, height=6, spp=4)


def _scene(name):
    jax.config.update("jax_enable_x64", True)
    return rt.load_scene(ROOT / "scenes" / f"{name}.toml").astype(jnp.float64)


def _weights(shape):
    """Fixed weights of the image sum (deterministic, no RNG)."""
    h, w, _ = shape
    y, x = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    base = 1.0 + 0.5 * np.sin(0.7 * x + 1.3 * y)
    return jnp.asarray(np.stack([base, 0.8 * base[::-1], 1.2 - 0.4 * base], -1))


def render_case(name):
    return np.asarray(rt.render(_scene(name), **RENDER_SIZE))


def gradient_case(name, edge):
    scene = _scene(name)
    params = rt.parameters(scene)
    wgt = _weights((EDGE_SIZE["height"], EDGE_SIZE["width"], 3))

    def loss(p):
        img = rt.render(rt.with_parameters(scene, p), edge_gradients=edge, **EDGE_SIZE)
        return jnp.sum(wgt * img)

    g = jax.grad(loss)(params)
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
