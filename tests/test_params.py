"""raytrax.parameters / raytrax.with_parameters: names, round trips, errors, transformations.

No rendering here: every check is on the scene pytree itself, so the file runs in
a couple of seconds.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt


def every_kind_scene(dtype=jnp.float32):
    b = rt.SceneBuilder("classic", width=8, height=6)
    b.camera(position=(0, 1, 5), look_at=(0, 0, 0), fov=40)
    b.light((1, 5, 2), intensity=(0.5, 0.6, 0.7))
    b.light((-1, 4, 2))
    b.material("floor", color=(0.5, 0.5, 0.5), texture=rt.Checker(color2=(0.1, 0.1, 0.1), scale=2.0))
    b.material("glass", color=(0, 0, 0), transparency=1.0, ior=1.5)
    b.material("striped", texture=rt.Stripes(color2=(0, 1, 0), scale=3.0, direction=(1.0, 0.0)))
    b.material("planet", texture=rt.ImageTexture(np.full((2, 3, 3), 0.5)))
    b.plane((0, -1, 0), (0, 1, 0), "floor")  # object[0]
    b.sphere((0, 0, 0), 1.0, "glass")  # object[1]
    b.box((-1, -1, -1), (0, 0, 0), "striped", rotation=(0, 30, 0))  # object[2]
    b.sphere((2, 0, 0), 0.5, "planet")  # object[3]
    b.tetrahedron((0, 2, 0), 1.0, "striped")  # object[4]
    b.triangle([(0, 0, 0), (1, 0, 0), (0, 1, 0)], "floor")  # object[5]
    b.quad([(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], "floor")  # object[6]
    b.mesh([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], [(0, 1, 2), (0, 2, 3)], "glass")  # object[7]
    return b.build(dtype)


SCENE = every_kind_scene()

MATERIAL_FIELDS = ["color", "ambient", "diffuse", "specular", "shininess", "reflectivity", "transparency", "ior"]


def test_names_and_shapes():
    p = rt.parameters(SCENE)
    expected = {
        "camera.position": (3,),
        "camera.look_at": (3,),
        "camera.up": (3,),
        "camera.fov": (),
        "light[0].position": (3,),
        "light[0].intensity": (3,),
        "light[1].position": (3,),
        "light[1].intensity": (3,),
        "material.floor.texture.color2": (3,),
        "material.floor.texture.scale": (),
        "material.striped.texture.color2": (3,),
        "material.striped.texture.scale": (),
        "material.striped.texture.direction": (2,),
        "material.planet.texture.image": (2, 3, 3),
        "object[0].point": (3,),
        "object[0].normal": (3,),
        "object[1].center": (3,),
        "object[1].radius": (),
        "object[2].min": (3,),
        "object[2].max": (3,),
        "object[2].rotation": (3,),
        "object[3].center": (3,),
        "object[3].radius": (),
        "object[4].center": (3,),
        "object[4].size": (),
        "object[5].vertices": (3, 3),
        "object[6].corners": (4, 3),
        "object[7].vertices": (4, 3),
        "render.background": (3,),
        "render.ambient": (3,),
    }
    for m in ("floor", "glass", "striped", "planet"):
        for f in MATERIAL_FIELDS:
            expected[f"material.{m}.{f}"] = (3,) if f in ("color", "reflectivity") else ()
    assert {k: tuple(v.shape) for k, v in p.items()} == expected
    assert list(p)[:4] == ["camera.position", "camera.look_at", "camera.up", "camera.fov"]
    assert list(p)[-2:] == ["render.background", "render.ambient"]
    assert rt.params.parameter_names(SCENE) == list(p)
    assert all(v.dtype == jnp.float32 for v in p.values())


def test_values_follow_the_scene_description():
    p = rt.parameters(SCENE)
    np.testing.assert_allclose(p["light[0].intensity"], [0.5, 0.6, 0.7])
    np.testing.assert_allclose(p["object[3].center"], [2, 0, 0])  # the second sphere, by object order
    np.testing.assert_allclose(p["object[3].radius"], 0.5)
    np.testing.assert_allclose(p["object[2].min"], [-1, -1, -1])
    np.testing.assert_allclose(p["object[2].rotation"], [0, 30, 0])
    np.testing.assert_allclose(p["material.glass.ior"], 1.5)
    np.testing.assert_allclose(p["material.floor.texture.scale"], 2.0)
    np.testing.assert_allclose(p["camera.fov"], 40.0)
    np.testing.assert_allclose(p["object[7].vertices"][3], [0, 0, 1])


def test_round_trip_is_identity():
    p = rt.parameters(SCENE)
    s2 = rt.with_parameters(SCENE, p)
    a, b = jax.tree_util.tree_leaves(SCENE), jax.tree_util.tree_leaves(s2)
    assert jax.tree_util.tree_structure(SCENE) == jax.tree_util.tree_structure(s2)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert rt.with_parameters(SCENE, {}) is SCENE


def test_replace_changes_only_that_leaf():
    s2 = rt.with_parameters(
        SCENE,
        {
            "object[3].radius": 0.25,
            "object[1].center": [0.0, 0.5, 0.0],
            "light[1].position": (9.0, 9.0, 9.0),
            "material.planet.texture.image": np.zeros((2, 3, 3)),
            "object[6].corners": np.ones((4, 3)),
        },
    )
    np.testing.assert_allclose(s2.spheres.radius, [1.0, 0.25])
    np.testing.assert_allclose(s2.spheres.center, [[0, 0.5, 0], [2, 0, 0]])
    np.testing.assert_allclose(s2.lights.position[1], [9, 9, 9])
    np.testing.assert_allclose(s2.lights.position[0], [1, 5, 2])
    np.testing.assert_allclose(s2.materials.images[0], 0.0)
    np.testing.assert_allclose(s2.quads.corners[0], 1.0)
    p1, p2 = rt.parameters(SCENE), rt.parameters(s2)
    changed = {k for k in p1 if not np.array_equal(p1[k], p2[k])}
    assert changed == {
        "object[3].radius",
        "object[1].center",
        "light[1].position",
        "material.planet.texture.image",
        "object[6].corners",
    }
    assert s2.materials.images[0].dtype == jnp.float32  # cast to the leaf's dtype


def test_rgb_accepts_a_scalar():
    s2 = rt.with_parameters(SCENE, {"material.floor.reflectivity": 0.5, "render.background": 1.0})
    np.testing.assert_allclose(s2.materials.reflectivity[0], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(s2.environment.background, [1.0, 1.0, 1.0])


def test_unknown_name_lists_near_matches():
    with pytest.raises(
        ValueError, match=r"unknown parameter 'material\.glas\.ior'.*did you mean 'material\.glass\.ior'"
    ):
        rt.with_parameters(SCENE, {"material.glas.ior": 1.4})
    with pytest.raises(ValueError, match=r"unknown parameter 'object\[1\]\.radious'.*'object\[1\]\.radius'"):
        rt.with_parameters(SCENE, {"object[1].radious": 1.4})
    with pytest.raises(ValueError, match=r"unknown parameter 'light\[2\]\.position'.*light\[.\]\.position"):
        rt.with_parameters(SCENE, {"light[2].position": [0, 0, 0]})
    # A name that exists in the table but not for this material / object kind.
    with pytest.raises(ValueError, match=r"unknown parameter 'material\.glass\.texture\.scale'"):
        rt.with_parameters(SCENE, {"material.glass.texture.scale": 1.0})
    with pytest.raises(ValueError, match=r"unknown parameter 'object\[0\]\.radius'"):
        rt.with_parameters(SCENE, {"object[0].radius": 1.0})


def test_wrong_shape_is_a_clear_error():
    with pytest.raises(ValueError, match=r"'object\[1\]\.center': expected shape \(3,\), got \(2,\)"):
        rt.with_parameters(SCENE, {"object[1].center": [1.0, 2.0]})
    with pytest.raises(
        ValueError, match=r"'material\.planet\.texture\.image': expected shape \(2, 3, 3\), got \(3, 3, 3\)"
    ):
        rt.with_parameters(SCENE, {"material.planet.texture.image": np.zeros((3, 3, 3))})
    with pytest.raises(ValueError, match=r"'camera\.fov': expected shape \(\), got \(1,\)"):
        rt.with_parameters(SCENE, {"camera.fov": [30.0]})


def test_under_jit_grad_jacfwd_vmap():
    ior = jax.jit(lambda v: rt.with_parameters(SCENE, {"material.glass.ior": v}).materials.ior)(jnp.float32(1.25))
    np.testing.assert_allclose(ior, [1.0, 1.25, 1.0, 1.0])

    def f(r):
        s = rt.with_parameters(SCENE, {"object[3].radius": r, "camera.fov": 10.0 * r})
        p = rt.parameters(s)
        return p["object[3].radius"] ** 2 + p["camera.fov"]

    assert float(jax.grad(f)(jnp.float32(0.5))) == pytest.approx(11.0)
    assert float(jax.jit(jax.grad(f))(jnp.float32(0.5))) == pytest.approx(11.0)

    def pos(c):
        return rt.parameters(rt.with_parameters(SCENE, {"object[4].center": c}))["object[4].center"] * 2.0

    np.testing.assert_allclose(jax.jacfwd(pos)(jnp.zeros(3, jnp.float32)), 2.0 * np.eye(3))
    np.testing.assert_allclose(jax.jacrev(pos)(jnp.zeros(3, jnp.float32)), 2.0 * np.eye(3))

    batch = jax.vmap(lambda v: rt.with_parameters(SCENE, {"light[0].intensity": v}).lights.intensity)(
        jnp.arange(6, dtype=jnp.float32).reshape(2, 3)
    )
    assert batch.shape == (2, 2, 3)
    np.testing.assert_allclose(batch[1, 0], [3, 4, 5])
    np.testing.assert_allclose(batch[:, 1], 1.0)

    # Gradients of a function of the whole scene reach the leaf a name points at.
    g = eqx.filter_grad(lambda s: jnp.sum(rt.parameters(s)["object[2].max"] * jnp.arange(3.0, dtype=jnp.float32)))(
        SCENE
    )
    np.testing.assert_allclose(g.boxes.hi, [[0, 1, 2]])
    np.testing.assert_allclose(g.boxes.lo, 0.0)


def test_parameters_of_a_traced_scene():
    # Without textures the names depend only on static structure: fine under filter_jit.
    b = rt.SceneBuilder("physical", width=4, height=4)
    b.light((0, 3, 0), intensity=10.0)
    b.material("m")
    b.sphere((0, 0, -3), 1.0, "m")
    plain = b.build()
    out = eqx.filter_jit(lambda s: rt.parameters(s)["object[0].radius"] * 2.0)(plain)
    assert float(out) == 2.0
    s2 = eqx.filter_jit(lambda s: rt.with_parameters(s, {"object[0].radius": 3.0}))(plain)
    assert float(s2.spheres.radius[0]) == 3.0
    # With textures the per-material texture kinds are traced too: a clear error.
    with pytest.raises(ValueError, match="texture parameter names cannot be determined"):
        eqx.filter_jit(lambda s: rt.parameters(s))(SCENE)
    # ... but with_parameters of non-texture names still works on a traced scene.
    s3 = eqx.filter_jit(lambda s: rt.with_parameters(s, {"object[1].radius": 2.0}))(SCENE)
    assert float(s3.spheres.radius[0]) == 2.0


def test_float64_scene_keeps_float64():
    s64 = SCENE.astype(jnp.float64)
    p = rt.parameters(s64)
    assert all(v.dtype == jnp.float64 for v in p.values())
    s2 = rt.with_parameters(s64, {"camera.fov": np.float32(30.0)})
    assert s2.camera.fov.dtype == jnp.float64
