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
from raytrax.testing import jittered_central_differences, smooth_weights

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

    def loss(q, **kw):  # q (1,): the height of the box's base
        return jnp.mean(wgt * rt.render(rt.with_parameters(s, {NAME: p0.at[1].set(q[0])}), **kw))

    grad = jax.jit(jax.grad(lambda q: loss(q, edge_gradients=True)))
    h, spp, keys = 0.02, 1024, 4

    # Resting on the floor: lifting changes the image, sinking does not.
    ref = jax.jit(lambda q, k: loss(q, spp=spp, key=k))
    y0 = jnp.zeros(1, jnp.float64)
    one_sided = []
    for k in (jax.random.key(i) for i in range(keys)):
        f0 = ref(y0, k)
        one_sided.append([ref(y0 + h, k) - f0, f0 - ref(y0 - h, k)])
    lift, sink = np.mean(one_sided, 0) / h
    assert lift > 5e-3, lift  # a real kink: the lifting side's derivative is far from zero
    assert abs(sink) < 1e-6 * lift, sink
    g = float(grad(y0)[0])
    assert abs(g) < 1e-6 * lift, (g, lift, sink)

    # Lifted by 0.1 the same edge is a silhouette over the floor seen under the box.
    y1 = y0 + 0.1
    fd, _ = jittered_central_differences(loss, y1, h, spp, keys)
    g1 = float(grad(y1)[0])
    assert fd[0] > 5e-3, fd
    np.testing.assert_allclose(g1, fd[0], rtol=0.05)
