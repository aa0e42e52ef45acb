"""Edge gradients at the silhouette and the shadow of a coarse closed mesh.

Next to the outline of a tessellated sphere its faces are seen almost edge-on, so
that most pairs of neighbouring samples straddle a crease and the outline at once:
the edge located between the two samples is the front face's (the crease), and the
outline lies beyond a third face that neither sample sees. Both crossings are found
(the second from the probe beside the first), so the translation derivative matches
central differences of jittered renders at the same low sample count as a smooth
object's.

A closed mesh's shadow segment crosses a front and a back face, both recorded as
occluders; its shadow's edge is the outline seen from the light, which the faces
next to it share. It is counted once, and followed face by face where the edge
first located is a crease.
"""

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

import raytrax as rt
from raytrax.testing import jittered_central_differences, smooth_weights

W, H = 16, 12


OCTAHEDRON = (
    [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)],
    [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)],
)


def scene(subdivisions=1, floor=False):
    """An icosphere of radius 0.8 (``subdivisions`` 1: 80 faces), or with ``None`` an
    octahedron; with ``floor``, over a floor lit by one point light."""
    if subdivisions is None:
        m = trimesh.Trimesh(0.8 * np.asarray(OCTAHEDRON[0], float), OCTAHEDRON[1], process=False)
    else:
        m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.8)
    ambient = 0.2 if floor else 0.6
    b = rt.SceneBuilder(
        "classic", width=W, height=H, spp=64, max_depth=0, background=(0.2, 0.2, 0.25), ambient=(ambient,) * 3
    )
    b.camera(position=(0.5, 3.0, 5.5), look_at=(0.0, 0.6, 0.0), fov=38.0)
    b.material("ball", color=(0.8, 0.3, 0.2))
    b.mesh([tuple(v + np.array([0.0, 1.0, 0.0])) for v in m.vertices], [tuple(f) for f in m.faces], "ball")
    if floor:
        b.light((2.0, 5.0, 1.5), intensity=(0.7, 0.7, 0.7))
        b.material("floor", color=(0.9, 0.9, 0.85))
        b.plane((0, 0, 0), (0, 1, 0), "floor")
    return b.build(jnp.float64)


def _translation(s, spp):
    wgt = jnp.asarray(smooth_weights(H, W), jnp.float64)
    (name,) = [k for k in rt.parameters(s) if k.endswith(".vertices")]
    v0 = rt.parameters(s)[name]

    def loss(q, **kw):  # q (3,): a translation of the whole mesh
        return jnp.mean(wgt * rt.render(rt.with_parameters(s, {name: v0 + q[None]}), **kw))

    q0 = jnp.zeros(3, jnp.float64)
    fd, se = jittered_central_differences(loss, q0, 0.04, 576, 8)
    g = np.asarray(jax.grad(lambda q: loss(q, spp=spp, edge_gradients=True))(q0))
    scale = np.max(np.abs(fd))
    assert np.all(se < 0.02 * scale), (fd, se)  # the reference is converged enough to judge by
    return g, fd, scale


def test_translating_a_coarse_mesh_matches_central_differences():
    g, fd, scale = _translation(scene(), 64)
    np.testing.assert_allclose(g, fd, atol=0.05 * scale)


def test_the_shadow_of_a_closed_mesh_is_counted_once():
    g, fd, scale = _translation(scene(subdivisions=None, floor=True), 256)
    np.testing.assert_allclose(g, fd, atol=0.06 * scale)
