"""The code layout's rules: one registry per concept that every consumer agrees with,
and no module importing another module's private names (the layer contracts are
checked by import-linter in CI, configured in pyproject.toml)."""

from __future__ import annotations

import ast
import pathlib

import jax.numpy as jnp
import numpy as np

import raytrax as rt
from raytrax import edges, intersect, scenefile
from raytrax.lights import LIGHTS
from raytrax.shapes import KINDS

PKG = pathlib.Path(rt.__file__).parent


def _module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def test_no_module_imports_a_private_name_of_another():
    """``from .x import _name`` across modules is refused; inside one private package
    (``raytrax._fitting``) its modules share private names, as optimistix's do."""
    bad = []
    for path in PKG.rglob("*.py"):
        mod = _module_name(path)
        pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom) or not node.level:
                continue
            base = pkg.split(".")
            base = base[: len(base) - (node.level - 1)]
            target = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:
                private_pkg = any(p.startswith("_") for p in target.split(".")[1:2])
                same_private = private_pkg and target.split(".")[:2] == mod.split(".")[:2]
                if alias.name.startswith("_") and not alias.name.startswith("__") and not same_private:
                    bad.append(f"{mod}: from {target} import {alias.name}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


def _every_kind_scene():
    b = rt.SceneBuilder("classic", width=8, height=6)
    b.camera(position=(0, 2, 8), look_at=(0, 0, 0), fov=50)
    b.light((3, 5, 3))
    b.directional_light((0.2, -1, -0.3), irradiance=0.5)
    b.material("m", color=(0.7, 0.6, 0.5))
    # One object of every kind, in reverse registry order (object order is not kind order).
    b.box((-3, 0, -1), (-2, 1, 0), "m", rotation=(0, 20, 0))
    b.mesh([[0, 0, -3], [1, 0, -3], [0, 1, -3]], [[0, 1, 2]], "m")
    b.tetrahedron((2, 0.5, -1), 1.0, "m")
    b.triangle([[-1, 0, 1], [0, 0, 1], [-1, 1, 1]], "m")
    b.disk((1, 1, 1), (0, 0, 1), 0.4, "m")
    b.quad([[-2, 2, 0], [-1, 2, 0], [-1, 3, 0], [-2, 3, 0]], "m")
    b.plane((0, -1, 0), (0, 1, 0), "m")
    b.sphere((0, 1, 0), 0.5, "m")
    return b.build()


def test_every_consumer_follows_the_registry_order():
    scene = _every_kind_scene()
    assert [k.name for k in KINDS] == list(scenefile.OBJECT_TYPES)
    assert {k.field for k in KINDS} == set(scene.prims)
    # The search: the kinds in registry order, the triangle family merged at its first member.
    expected = []
    for k in KINDS:
        name = "triangle" if k.triangle_family else k.name
        if name not in expected:
            expected.append(name)
    assert [k.name for k in intersect.prepare(scene)] == expected
    # Global ids of the boundary terms: consecutive spans in registry order, matching the
    # number of edge primitives build_prims makes.
    off = edges.id_offsets(scene)
    g = 0
    for k in KINDS:
        assert off[k.name] == g
        g += k.n_ids(scene.prims[k.field])
    assert off["total"] == g
    P, _ = edges.build_prims(scene)
    assert P.r.shape[0] + P.finite.shape[0] == g
    assert P.mat.shape[0] == g
    # Every global id's material is the material of the object it belongs to (one here).
    np.testing.assert_array_equal(np.asarray(P.mat), 0)
    # Parameter names: every object and light by its file keys.
    names = rt.parameters(scene)
    for i, (kind, _) in enumerate(scene.object_index):
        spec = next(k for k in KINDS if k.name == kind)
        keys = [k.name for k in spec.keys] or ["vertices"]
        assert all(f"object[{i}].{key}" in names for key in keys)
    for j, (typ, _) in enumerate(scene.light_index):
        spec = next(s for s in LIGHTS if s.name == typ)
        assert all(f"light[{j}].{k.name}" in names for k in spec.keys)


def test_every_kind_renders_hit_by_its_own_search():
    """Each kind's stop-gradient search and differentiable hit agree: rays aimed at
    each object hit it at the distance the recomputation gives."""
    scene = _every_kind_scene()
    kinds = intersect.prepare(scene)
    o = jnp.asarray([[0.0, 2.0, 8.0]] * 2, jnp.float32).T
    targets = jnp.asarray([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0]], jnp.float32)  # the sphere's and the disk's centres
    d = targets.T - o
    d = d / jnp.linalg.norm(d, axis=0, keepdims=True)
    hit = intersect.closest_hit(kinds, o, d)
    assert bool(jnp.all(hit.valid))
    t_sphere = float(jnp.linalg.norm(targets[0] - o[:, 0])) - 0.5
    np.testing.assert_allclose(float(hit.t[0]), t_sphere, rtol=1e-5)
    np.testing.assert_allclose(float(hit.t[1]), float(jnp.linalg.norm(targets[1] - o[:, 1])), rtol=1e-5)
