"""Edge gradients through glass onto many box edges: the refractive index of a
glass ball over a 10 x 10 checker of thin boxes (five small balls behind it, one
point light, depth 6: ``scenes/glass_over_boxes.toml``, also benchmarked by
benchmarks/bench_edges.py ``glass``).

What the ball shows of the checker moves with the index; each moving box edge
seen through the glass is a boundary term that plain automatic differentiation
misses. The derivative of the MSE against the image at the true index (1.5) is
compared near the truth (ior 1.45) with central differences of jittered renders at
many more samples (converged: see the standard error asserted below).

At this size (40 x 30, spp 16) the checker seen through the ball is shrunk to a few
samples per box, and far from the truth the estimate is off more: at ior 1.30
edge mode gives -0.00175 against -0.00215 +- 0.00004 (-18 %), plain AD -0.00002
(measured once; at 160 x 120 the issue measured +2 %).

The test takes about 70 s on two cores (most of it compiling the edge-mode
gradient; the reference, 8 float64 renders at spp 256, about 13 s)."""

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

import raytrax as rt
from raytrax.testing import jittered_central_differences

W, H = 40, 30
SPP = 16  # the edge gradient's 4 x 4 grid per pixel
REF_SPP = 256
STEP = 0.004
KEYS = 4
NAME = "material.glass.ior"
SCENES = Path(__file__).resolve().parent.parent / "scenes"


def glass_scene(ior, depth=6):
    """``scenes/glass_over_boxes.toml`` (a glass ball over a 10 x 10 checker of thin
    boxes, five small balls behind it, one point light; 107 objects) at this test's
    size, float64."""
    s = rt.load_scene(SCENES / "glass_over_boxes.toml", dtype=jnp.float64)
    return rt.with_parameters(s.replace_settings(width=W, height=H, spp=SPP, max_depth=depth), {NAME: ior})


@functools.cache
def _scene():
    return glass_scene(1.5)


@functools.cache
def _target():
    return rt.render(_scene(), spp=REF_SPP)


def _loss(q, **kw):
    s = rt.with_parameters(_scene(), {NAME: q[0]})
    return jnp.mean((rt.render(s, **kw) - _target()) ** 2)


@pytest.mark.parametrize("ior", [1.45])
def test_ior_through_glass_onto_box_edges(ior):
    q0 = jnp.asarray([ior], jnp.float64)
    edge = float(jax.grad(lambda q: _loss(q, edge_gradients=True))(q0)[0])
    ref, se = jittered_central_differences(_loss, q0, STEP, REF_SPP, KEYS)
    msg = f"ior {ior}: CD {ref[0]:+.6f} +- {se[0]:.6f}  edge {edge:+.6f}"
    assert se[0] < 0.02 * abs(ref[0]), msg  # the reference has converged
    assert abs(edge - ref[0]) <= 0.05 * abs(ref[0]), msg
