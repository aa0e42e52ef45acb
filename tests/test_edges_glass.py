"""Edge gradients through glass onto many box edges: the refractive index of a
glass ball over a 10 x 10 checker of thin boxes (five small balls behind it, one
point light, depth 6; the scene of benchmarks/bench_edges.py ``glass``).

What the ball shows of the checker moves with the index; each moving box edge
seen through the glass is a boundary term that plain automatic differentiation
misses. The derivative of the MSE against the image at the true index (1.5) is
compared near the truth (ior 1.45) with central differences of jittered renders at
many more samples (converged: see the standard error asserted below).

At this size (40 x 30, spp 16) the checker seen through the ball is shrunk to a few
samples per box, and far from the truth the estimate is off more: at ior 1.30
edge mode gives -0.00175 against -0.00215 +- 0.00004 (-18 %), plain AD -0.00002
(measured once; at 160 x 120 the issue measured +2 %).

The test takes about 6 minutes on two cores (the reference: 8 float64 renders at
spp 256 of 107 objects at depth 6; the edge-mode compile), more than the whole
rest of the suite on one worker, so it runs only with ``RAYTRAX_SLOW_TESTS=1``:

    RAYTRAX_SLOW_TESTS=1 python -m pytest -q tests/test_edges_glass.py"""

import functools
import os

import jax
import jax.numpy as jnp
import pytest
from helpers import jittered_central_differences

import raytrax as rt

W, H = 40, 30
SPP = 16  # the edge gradient's 4 x 4 grid per pixel
REF_SPP = 256
STEP = 0.004
KEYS = 4
NAME = "material.glass.ior"


def glass_scene(ior, depth=6):
    """A glass ball over a 10 x 10 checker of thin red and blue boxes, five small balls
    behind it, one point light (107 objects), float64."""
    b = rt.SceneBuilder("physical", width=W, height=H, spp=SPP, max_depth=depth, background=(0.05, 0.05, 0.08))
    b.camera(position=(0, 4.0, 5.5), look_at=(0, 0, 0), fov=40)
    b.light((3.0, 6.0, 2.0), intensity=(60, 60, 60))
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("red", color=(0.8, 0.15, 0.1))
    b.material("blue", color=(0.1, 0.2, 0.8))
    b.material("glass", color=(0, 0, 0), transparency=1.0, ior=ior)
    b.material("ball", color=(0.8, 0.8, 0.2))
    b.plane((0, -0.05, 0), (0, 1, 0), "floor")
    n, s = 10, 0.5
    for i in range(n):
        for j in range(n):
            x0, z0 = (i - n / 2) * s, (j - n / 2) * s
            b.box((x0, 0.0, z0), (x0 + s, 0.08, z0 + s), "red" if (i + j) % 2 else "blue")
    b.sphere((0, 0.9, 0.0), 0.8, "glass")
    for k in range(5):
        b.sphere((-1.6 + 0.8 * k, 0.35, -1.6), 0.25, "ball")
    return b.build(jnp.float64)


@functools.cache
def _scene():
    return glass_scene(1.5)


@functools.cache
def _target():
    return rt.render(_scene(), spp=REF_SPP)


def _loss(q, **kw):
    s = rt.with_parameters(_scene(), {NAME: q[0]})
    return jnp.mean((rt.render(s, **kw) - _target()) ** 2)


@pytest.mark.skipif(
    os.environ.get("RAYTRAX_SLOW_TESTS", "") in ("", "0"),
    reason="about 6 min on 2 cores; set RAYTRAX_SLOW_TESTS=1 to run it",
)
@pytest.mark.parametrize("ior", [1.45])
def test_ior_through_glass_onto_box_edges(ior):
    q0 = jnp.asarray([ior], jnp.float64)
    edge = float(jax.grad(lambda q: _loss(q, edge_gradients=True))(q0)[0])
    plain = float(jax.grad(_loss)(q0)[0])
    ref, se = jittered_central_differences(_loss, q0, STEP, REF_SPP, KEYS)
    msg = f"ior {ior}: CD {ref[0]:+.5f} +- {se[0]:.5f}  edge {edge:+.5f}  plain {plain:+.5f}"
    assert se[0] < 0.02 * abs(ref[0]), msg  # the reference has converged
    assert abs(edge - ref[0]) <= 0.05 * abs(ref[0]), msg
