"""Edge mode sharded over devices: the sample grid and the silhouette quadrature's
rays are traced in one pass over tiles, sharded like the plain render; the grid's
records are split over the devices, and the events' chunks dealt to them in turn."""

import os

import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt


def test_sharded_edge_gradient_equals_single_device():
    # scenes/edge_sphere.toml (a sphere's silhouette, so the quadrature's rays are traced
    # too), small, float32; tile_rays=64 makes several tiles per device.
    scene = rt.load_scene(os.path.join(os.path.dirname(__file__), "..", "scenes", "edge_sphere.toml"))
    p = rt.parameters(scene)
    names = ["object[1].center", "object[1].radius", "light[0].position"]

    def loss(q, dev):
        s = rt.with_parameters(scene, {**p, **q})
        img = rt.render(s, width=6, height=4, spp=4, tile_rays=64, edge_gradients=True, devices=dev)
        return jnp.mean(img**2)

    q = {k: p[k] for k in names}
    v1, g1 = jax.value_and_grad(lambda q: loss(q, None))(q)
    v4, g4 = jax.value_and_grad(lambda q: loss(q, 4))(q)
    np.testing.assert_allclose(float(v4), float(v1), rtol=1e-6)
    for k in names:
        np.testing.assert_allclose(np.asarray(g4[k]), np.asarray(g1[k]), rtol=1e-4, atol=1e-7, err_msg=k)
    # The radius moves only the silhouette: its derivative is all boundary term.
    assert abs(float(g1["object[1].radius"])) > 1e-3
