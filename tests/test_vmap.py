"""``jax.vmap`` of a render over scene parameters equals a Python loop of renders.

One batch varies every kind of parameter at once (an IOR, a colour, a radius,
the camera position and a light position), so one vmapped compilation and one
single-render compilation cover them all (such a batch is rendered as a
sequence of single renders; a batch over colours is batched inside the render,
below, and over lights in tests/test_devices.py::test_vmap_over_light_positions). The images
must be the loop's to float32 rounding, and gradients through a batch each
member's own.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt


def _scene():
    b = rt.SceneBuilder("physical", width=24, height=18, spp=4, max_depth=4, background=(0.05, 0.05, 0.1))
    b.camera(position=(0.0, 1.5, 6.0), look_at=(0.0, 0.6, 0.0), fov=40.0)
    b.light((2.0, 5.0, 3.0), (60.0, 55.0, 50.0))
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("red", color=(0.8, 0.2, 0.2))
    b.material("glass", color=(0.0, 0.0, 0.0), transparency=1.0, ior=1.5)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere((-0.9, 0.6, 0.0), 0.6, "red")
    b.sphere((0.8, 0.7, 0.8), 0.7, "glass")
    b.box((-0.4, 0.0, -1.2), (0.4, 0.8, -0.4), "red", rotation=(0.0, 25.0, 0.0))
    return b.build()


BASE = _scene()


def _with(p):
    s = BASE
    s = eqx.tree_at(lambda s: s.materials.ior, s, s.materials.ior.at[2].set(p["ior"]))
    s = eqx.tree_at(lambda s: s.materials.color, s, s.materials.color.at[1].set(p["red"]))
    s = eqx.tree_at(lambda s: s.spheres.radius, s, s.spheres.radius.at[1].set(p["radius"]))
    s = eqx.tree_at(lambda s: s.camera.position, s, p["eye"])
    s = eqx.tree_at(lambda s: s.lights.position, s, s.lights.position.at[0].set(p["light"]))
    return s


BATCH = {
    "ior": jnp.array([1.5, 1.2, 1.9], jnp.float32),
    "red": jnp.array([[0.8, 0.2, 0.2], [0.2, 0.8, 0.3], [0.5, 0.5, 0.9]], jnp.float32),
    "radius": jnp.array([0.7, 0.5, 0.9], jnp.float32),
    "eye": jnp.array([[0.0, 1.5, 6.0], [1.0, 2.0, 5.5], [-1.5, 1.0, 6.5]], jnp.float32),
    "light": jnp.array([[2.0, 5.0, 3.0], [-3.0, 4.0, 2.0], [0.0, 6.0, -2.0]], jnp.float32),
}


def test_vmap_over_every_kind_of_parameter_matches_a_loop():
    render = jax.jit(lambda p: rt.render(_with(p)))
    loop = np.stack([np.asarray(render(jax.tree.map(lambda a: a[i], BATCH))) for i in range(3)])
    batched = np.asarray(jax.jit(jax.vmap(lambda p: rt.render(_with(p))))(BATCH))
    assert batched.shape == (3, 18, 24, 3)
    assert np.all(np.isfinite(batched))
    # The members differ from each other (the batch really varies), and each equals its loop render.
    assert np.abs(loop[0] - loop[1]).max() > 0.05 and np.abs(loop[0] - loop[2]).max() > 0.05
    np.testing.assert_allclose(batched, loop, rtol=0, atol=2e-5)


def test_gradient_of_a_vmapped_render_matches_a_loop_of_gradients():
    """Reverse mode through a batch (``jax.grad`` of a sum over ``jax.vmap``) gives
    each member's own gradient. A batch of radii is rendered as a sequence of
    single renders and differentiated through the plain render's JVP; the
    renderer's skipped-work conds must stay conds there (a cond whose predicate
    is batched becomes a select whose ``stop_gradient`` JAX cannot transpose)."""

    def mean_image(r):
        s = eqx.tree_at(lambda s: s.spheres.radius, BASE, BASE.spheres.radius.at[1].set(r))
        return jnp.mean(rt.render(s, width=12, height=9, max_depth=2))

    radii = jnp.array([0.6, 0.7], jnp.float32)
    loop = np.array([float(jax.jit(jax.grad(mean_image))(r)) for r in radii])
    batched = np.asarray(jax.jit(jax.grad(lambda rs: jnp.sum(jax.vmap(mean_image)(rs))))(radii))
    assert np.all(np.isfinite(batched)) and np.all(np.abs(loop) > 1e-3)
    np.testing.assert_allclose(batched, loop, rtol=1e-4, atol=1e-7)


def test_a_batch_over_colours_is_batched_inside_and_matches_a_loop():
    """A batch over what only colours a hit's own light (a material's colour, the
    background, lights) is batched inside the render: the camera, reflected and
    refracted rays are shared by the batch; the material fields that decide the
    children are read apart from the colours, so that they stay unbatched. Anything that moves a ray (an IOR, a reflectivity, a
    radius, the camera) is rendered as a sequence."""
    from raytrax.materials import CHILD_FIELDS, COLOUR_FIELDS
    from raytrax.renderer.tiles import _only_shading_batched

    none = jax.tree.map(lambda _: False, BASE)

    def flags(where):
        return eqx.tree_at(where, none, replace_fn=lambda n: jax.tree.map(lambda _: True, n)), False

    inside = [lambda s: s.materials.color, lambda s: s.environment.background, lambda s: s.light_sets]
    outside = [
        lambda s: s.materials.ior,
        lambda s: s.materials.reflectivity,
        lambda s: s.materials.transparency,
        lambda s: s.spheres.radius,
        lambda s: s.camera.position,
    ]
    assert [_only_shading_batched(flags(w)) for w in inside] == [True] * 3
    # The two kinds of material field are disjoint, and both are fields of the materials.
    fields = {f.name for f in dataclasses.fields(rt.Materials)}
    assert not set(CHILD_FIELDS) & set(COLOUR_FIELDS) and set(CHILD_FIELDS + COLOUR_FIELDS) <= fields
    assert [_only_shading_batched(flags(w)) for w in outside] == [False] * 5

    def with_colour(c, bg):
        s = eqx.tree_at(lambda s: s.materials.color, BASE, BASE.materials.color.at[1].set(c))
        return eqx.tree_at(lambda s: s.environment.background, s, bg)

    bgs = jnp.array([[0.05, 0.05, 0.1], [0.3, 0.1, 0.0], [0.0, 0.2, 0.2]], jnp.float32)
    render = jax.jit(lambda c, bg: rt.render(with_colour(c, bg)))
    loop = np.stack([np.asarray(render(BATCH["red"][i], bgs[i])) for i in range(3)])
    batched = np.asarray(jax.jit(jax.vmap(lambda c, bg: rt.render(with_colour(c, bg))))(BATCH["red"], bgs))
    assert np.abs(loop[0] - loop[1]).max() > 0.05 and np.abs(loop[0] - loop[2]).max() > 0.05
    np.testing.assert_allclose(batched, loop, rtol=0, atol=2e-5)
