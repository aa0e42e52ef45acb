"""Edge gradients where a solid rests on the floor (a contact).

The box's bottom edge lies where its sides meet the floor. Lifting the box reveals
the floor under it, which neither neighbouring sample sees; sinking it changes
nothing. The image is continuous there with a kink in the box's height: edge mode
returns the sinking side's derivative (zero), not a boundary term whose jump is
measured against the floor beside the box. Off the floor, the same edge is a
silhouette and its boundary term is checked against central differences.
"""

import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt
from raytrax.testing import smooth_weights

W, H = 24, 18
NAME = "object[1].min"


def scene():
    b = rt.SceneBuilder("classic", width=W, height=H, spp=16, max_depth=0)
    b.camera(position=(0.0, 2.5, 6.0), look_at=(0.0, 0.0, 0.0), fov=40)
    b.light((3.0, 6.0, 4.0))
    b.material("floor", color=(0.8, 0.8, 0.8))
    b.material("red", color=(0.8, 0.2, 0.2))
    b.plane((0, 0, 0), (0, 1, 0), "floor")
    b.box((-1.0, 0.0, -1.0), (1.0, 1.5, 1.0), "red", rotation=(0.0, 30.0, 0.0))
    return b.build(jnp.float64)


def test_a_box_resting_on_the_floor_has_the_sinking_sides_derivative():
    s = scene()
    wgt = jnp.asarray(smooth_weights(H, W), jnp.float64)
    p0 = rt.parameters(s)[NAME]

    def loss(v, **kw):
        return jnp.mean(wgt * rt.render(rt.with_parameters(s, {NAME: v}), **kw))

    grad = jax.jit(jax.grad(lambda v: loss(v, edge_gradients=True)))
    ref = jax.jit(lambda v, k: loss(v, spp=1024, key=k))
    keys = [jax.random.key(i) for i in range(4)]
    h = 0.02
    up = jnp.asarray([0.0, h, 0.0])

    # Resting on the floor: lifting changes the image, sinking does not.
    at = np.asarray([[ref(p0 + up, k) - ref(p0, k), ref(p0, k) - ref(p0 - up, k)] for k in keys]) / h
    lift, sink = at[:, 0].mean(), at[:, 1].mean()
    assert lift > 5e-3, lift  # a real kink: the lifting side's derivative is far from zero
    assert abs(sink) < 1e-6 * lift, sink
    g = float(grad(p0)[1])
    assert abs(g) < 1e-6 * lift, (g, lift, sink)

    # Lifted by 0.1 the same edge is a silhouette over the floor seen under the box.
    p1 = p0 + jnp.asarray([0.0, 0.1, 0.0])
    fd = np.mean([(ref(p1 + up, k) - ref(p1 - up, k)) / (2 * h) for k in keys])
    g1 = float(grad(p1)[1])
    assert fd > 5e-3, fd
    np.testing.assert_allclose(g1, fd, rtol=0.05)
