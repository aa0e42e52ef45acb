"""Edge mode sharded over devices: the sample grid and the silhouette quadrature's
rays are traced in one pass over tiles, sharded like the plain render; the grid's
records are split over the devices, and the events' chunks dealt to them in turn."""

import jax
import numpy as np
import pytest
from golden import cases

import raytrax as rt

# In one worker with the golden test, whose single-device gradient this test reuses.
pytestmark = pytest.mark.xdist_group(cases.GROUP)


KW = dict(devices=4, tile_rays=64)


def test_sharded_edge_gradient_equals_single_device():
    # scenes/edge_sphere.toml (a sphere's silhouette, so the quadrature's rays are traced
    # too; 8 x 6, spp 256), float64; tile_rays=64 makes several tiles per device. The
    # single-device gradient is the golden case's (default tiles).
    scene = cases.edge_scene("edge_sphere")
    g4 = jax.grad(lambda p: cases.weighted_mean(rt.with_parameters(scene, p), edge_gradients=True, **KW))(
        rt.parameters(scene)
    )
    g1 = cases.gradient_case("edge_sphere", True)
    assert set(g4) == set(g1)
    for k in g1:
        np.testing.assert_allclose(np.asarray(g4[k]), g1[k], rtol=1e-9, atol=1e-12, err_msg=k)
    # The radius moves only the silhouette: its derivative is all boundary term.
    assert abs(float(g1["object[1].radius"])) > 1e-3


def test_budget_error_of_a_sharded_finder_is_raised_cleanly():
    # The options of the test above at half the budget the scene needs, inside jax.jit
    # (where the finder raises the error itself, at run time): every device raises it.
    # A check on one device only would leave the others waiting for it at their next
    # collective, and the process would abort.
    scene = cases.edge_scene("edge_sphere")
    need = rt.edge_pairs(scene, **KW)
    assert need >= 4
    render = jax.jit(lambda s: rt.render(s, edge_gradients=True, edge_budget=need // 2, **KW))
    with pytest.raises(Exception, match="edge_budget"):
        jax.block_until_ready(render(scene))
