"""The triangle BVH (raytrax.bvh) gives the same answers as the brute-force search."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from helpers import grid_mesh

import raytrax as rt
from raytrax import bvh as B
from raytrax import intersect as I


def _soup(n=400, seed=0):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-1.0, 1.0, size=(n, 1, 3))
    v = c + rng.uniform(-0.2, 0.2, size=(n, 3, 3))
    return v.reshape(-1, 3), np.arange(3 * n).reshape(n, 3)


def _sphere():
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)  # 320 faces
    return np.asarray(m.vertices), np.asarray(m.faces)


def _grid(k=10):
    """A flat k x k grid of 2 k^2 triangles in the plane y = 0 (zero-thickness leaf boxes)."""
    return grid_mesh(k, 1.5)


def _scene(verts, faces, *, width=16, height=12, extra_triangles=True):
    b = rt.SceneBuilder("classic", width=width, height=height, max_depth=1, ambient=(0.2, 0.2, 0.2))
    b.camera(position=(0.3, 0.5, 4.0), look_at=(0, 0, 0), fov=45)
    b.light((2.0, 4.0, 3.0), intensity=(1.0, 1.0, 1.0))
    b.material("a", color=(0.8, 0.5, 0.2))
    b.material("b", color=(0.2, 0.5, 0.8))
    b.plane((0, -1.5, 0), (0, 1, 0), "a")
    b.mesh(verts, faces, "a")
    if extra_triangles:  # a second material and the other triangle kinds in the merged list
        b.triangle([(-1.5, -1, 0.5), (1.5, -1, 0.5), (0, 1.2, 0.3)], "b")
        b.tetrahedron((0.5, 0.2, 0.4), 0.6, "b")
    return b.build()


def _brute(scene):
    return dataclasses.replace(scene, bvh=None)


def _rays(n=600, seed=1, inside=0.3):
    """Random rays: origins around and (a fraction) inside the unit ball, random directions."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2.5, 2.5, size=(n, 3))
    k = int(inside * n)
    o[:k] = rng.uniform(-0.4, 0.4, size=(k, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return jnp.asarray(o.T, jnp.float32), jnp.asarray(d.T, jnp.float32)


def _search_impl(scene, o, d, tmax):
    """(t, idx) of the triangle kind and occluder counts, with the scene's BVH and by brute force."""
    kinds = I.prepare(scene)
    brute = [k._replace(accel=None) for k in kinds]
    tri = next(k for k in kinds if k.name == "triangle")
    assert tri.accel is not None  # the BVH is in use (checked at trace time)
    ray = (o[0], o[1], o[2], d[0], d[1], d[2])
    nm = scene.materials.color.shape[0]
    return (
        I.closest_kind(tri, ray, 0.0),
        I.closest_kind(tri._replace(accel=None), ray, 0.0),
        I.occluder_counts(kinds, o, d, tmax, nm),
        I.occluder_counts(brute, o, d, tmax, nm),
    )


_search = jax.jit(_search_impl)


def _check_search(scene, o, d, search=_search):
    tmax = jnp.asarray(np.random.default_rng(2).uniform(0.1, 4.0, o.shape[1]), o.dtype)
    (t, i), (tb, ib), c, cb = search(scene, o, d, tmax)
    t, i, tb, ib = map(np.asarray, (t, i, tb, ib))
    hit = np.isfinite(tb)
    assert 0.1 * hit.size < hit.sum() < hit.size  # hits and misses
    np.testing.assert_array_equal(np.isfinite(t), hit)
    np.testing.assert_allclose(t[hit], tb[hit], rtol=1e-6)
    np.testing.assert_array_equal(i[hit], ib[hit])
    np.testing.assert_array_equal(np.asarray(c), np.asarray(cb))
    assert np.asarray(cb).sum() > 0


def test_topology_is_a_permutation_in_whole_leaves():
    c = np.random.default_rng(0).normal(size=(1000, 3))
    order, pad = B.build_topology(c)
    assert order.shape == pad.shape == (B.LEAF * 32,)
    np.testing.assert_array_equal(np.sort(order[pad == 0]), np.arange(1000))
    assert pad.sum() == B.LEAF * 32 - 1000
    leaves = order.reshape(-1, B.LEAF)
    assert all(np.all(np.diff(leaf[p == 0]) > 0) for leaf, p in zip(leaves, pad.reshape(-1, B.LEAF)))
    # Spatially coherent: leaf boxes are much smaller than the whole cloud.
    ext = np.ptp(c[leaves], axis=1).prod(-1)
    assert np.median(ext) < 0.05 * np.ptp(c, axis=0).prod()


def test_builder_makes_a_bvh_only_for_many_triangles():
    v, f = _sphere()
    s = _scene(v, f)
    assert s.bvh is not None and s.bvh.n_triangles == 320 + 1 + 4
    assert _scene(v, f[: B.MIN_TRIANGLES - 5]).bvh is None


@pytest.mark.parametrize("mesh", ["soup", "icosphere", "grid"])
def test_search_and_occluders_match_brute_force(mesh):
    v, f = {"soup": _soup, "icosphere": _sphere, "grid": _grid}[mesh]()
    s = _scene(v, f)
    o, d = _rays()
    _check_search(s, o, d)


def test_topology_runs_of_branch_leaves_are_subtrees():
    """Aligned runs of BRANCH leaves (the inner nodes) are compact in space, as the leaves are."""
    c = np.random.default_rng(1).uniform(size=(5000, 3))
    order, pad = B.build_topology(c, leaf=8, branch=4)
    leaves = order.reshape(-1, 8)
    assert leaves.shape[0] == 625
    np.testing.assert_array_equal(np.sort(order[pad == 0]), np.arange(5000))
    for run in (4, 16, 64):  # levels 1, 2, 3
        full = leaves.shape[0] // run * run
        groups = c[leaves[:full].reshape(-1, run * 8)]  # (runs, run * 8, 3)
        vol = np.ptp(groups, axis=1).prod(-1)
        # a subtree of k leaves of a uniform cloud spans about k / 625 of its volume
        assert np.median(vol) < 3 * run / 625, run


def test_several_levels_match_brute_force(monkeypatch):
    """With a small branching factor the soup's 13 leaves get three inner levels (7, 4, 2 nodes); search,
    shadow crossings (also under vmap over vertex sets) equal brute force."""
    monkeypatch.setattr(B, "BRANCH", 2)
    monkeypatch.setattr(B, "TOP_MAX", 2)
    v, f = _soup()
    s = _scene(v, f)
    acc = next(k for k in I.prepare(s) if k.name == "triangle").accel
    assert acc is not None and [lv["lox"].shape[0] for lv in acc.levels] == [7, 4, 2]
    search = jax.jit(_search_impl)  # traced with the patched constants
    o, d = _rays()
    _check_search(s, o, d, search)
    v2 = v * np.array([1.0, 0.5, 1.5]) + 0.3
    s2 = rt.with_parameters(s, {"object[1].vertices": v2})
    tmax = jnp.full((o.shape[1],), 3.0, o.dtype)

    def one(vert):
        return search(eqx.tree_at(lambda x: x.meshes[0].vertices, s, vert), o, d, tmax)

    (t, i), (tb, ib), c, cb = jax.vmap(one)(jnp.stack([s.meshes[0].vertices, s2.meshes[0].vertices]))
    hit = np.isfinite(np.asarray(tb))
    assert 0.1 * hit.size < hit.sum() < hit.size
    np.testing.assert_array_equal(np.isfinite(np.asarray(t)), hit)
    np.testing.assert_array_equal(np.asarray(i)[hit], np.asarray(ib)[hit])
    np.testing.assert_array_equal(np.asarray(c), np.asarray(cb))


def test_refit_after_moving_vertices_and_vmap():
    """The topology is built once; the boxes follow the vertices (here scrambled far
    from where the topology was built), also under vmap over vertex sets."""
    v, f = _soup()
    s = _scene(v, f)
    rng = np.random.default_rng(5)
    v2 = v[rng.permutation(v.shape[0])] * np.array([1.0, 0.5, 1.5]) + 0.3  # every leaf now spans the cloud
    s2 = rt.with_parameters(s, {"object[1].vertices": v2})
    np.testing.assert_array_equal(np.asarray(s2.bvh.order), np.asarray(s.bvh.order))
    o, d = _rays(seed=3)  # same shapes as above: reuses the compiled search
    _check_search(s2, o, d)

    tmax = jnp.full((o.shape[1],), 3.0, o.dtype)
    vs = jnp.stack([s.meshes[0].vertices, s2.meshes[0].vertices])

    def one(vert):
        sc = eqx.tree_at(lambda x: x.meshes[0].vertices, s, vert)
        return _search(sc, o, d, tmax)

    (t, i), (tb, ib), c, cb = jax.vmap(one)(vs)
    hit = np.isfinite(np.asarray(tb))
    np.testing.assert_array_equal(np.isfinite(np.asarray(t)), hit)
    np.testing.assert_array_equal(np.asarray(i)[hit], np.asarray(ib)[hit])
    np.testing.assert_array_equal(np.asarray(c), np.asarray(cb))


def test_render_matches_brute_force():
    v, f = _sphere()
    s = _scene(v, f)
    img, img_b = rt.render(s), rt.render(_brute(s))
    assert np.asarray(img).std() > 0.05
    # The hits are the same (test above, exactly); the two programs fuse the shading
    # differently, so XLA may round a multiply-add differently: a few float32 ulps.
    np.testing.assert_allclose(np.asarray(img), np.asarray(img_b), rtol=1e-6, atol=1e-6)


def test_vertex_gradient_matches_brute_force():
    """The search is stop-gradient; the hit recomputed with the primitive it found
    carries the gradient, so the gradient wrt mesh vertices is the brute-force one."""
    v, f = _sphere()
    s = _scene(v, f)
    o, d = _rays(n=400, seed=6)
    rng = np.random.default_rng(7)
    wt, wn = (jnp.asarray(rng.normal(size=sh), jnp.float32) for sh in ((400,), (3, 400)))

    @jax.jit
    def grad(scene):
        def loss(vert):
            hit = I.closest_hit(I.prepare(eqx.tree_at(lambda x: x.meshes[0].vertices, scene, vert)), o, d)
            return jnp.sum(jnp.where(hit.valid, hit.t, 0.0) * wt) + jnp.sum(hit.normal * wn)

        return jax.grad(loss)(scene.meshes[0].vertices)

    g, g_b = np.asarray(grad(s)), np.asarray(grad(_brute(s)))
    assert np.abs(g_b).sum() > 0
    np.testing.assert_allclose(g, g_b, rtol=1e-5, atol=1e-6)


def test_gradients_through_a_mesh_larger_than_the_ray_batch_match_finite_differences():
    """A flat grid mesh of 800 triangles seen by batches of 64 rays (``tile_rays=64``): the
    hit is recomputed from the rays' triangles gathered before it and kept per ray by the
    shading checkpoint (``intersect.hit_args``). d mean / d (light position, the mesh's
    height) against central differences; the grid fills the view and its faces share
    one normal, so no edge moves."""
    v, f = _grid(20)
    b = rt.SceneBuilder("physical", width=12, height=9, spp=1, max_depth=1)
    b.camera(position=(0.013, 3.0, 0.517), look_at=(0.01, 0, 0.02), fov=30)
    b.light((0.5, 2.0, 0.3), intensity=(5.0, 5.0, 5.0))
    b.material("a", color=(0.8, 0.5, 0.2))
    b.mesh(v, f, "a")
    s = b.build(jnp.float64)
    tri = next(k for k in I.prepare(s) if k.name == "triangle")
    assert tri.accel is not None and I.hit_args(tri, jnp.zeros((64,), jnp.int32)).shape == (64, 3, 3)

    def loss(light, dy):
        q = {
            "light[0].position": light,
            "object[0].vertices": s.meshes[0].vertices + jnp.stack([0.0, dy, 0.0])[None, :],
        }
        return jnp.mean(rt.render(rt.with_parameters(s, q), tile_rays=64))

    x0 = (s.lights.position[0], jnp.asarray(0.0, jnp.float64))
    g_light, g_dy = jax.jit(jax.grad(loss, argnums=(0, 1)))(*x0)
    f = jax.jit(loss)
    h = 1e-4
    fd = [float(f(x0[0].at[c].add(h), x0[1]) - f(x0[0].at[c].add(-h), x0[1])) / (2 * h) for c in range(3)]
    fd_dy = float(f(x0[0], x0[1] + h) - f(x0[0], x0[1] - h)) / (2 * h)
    assert abs(fd_dy) > 1e-3 and max(abs(x) for x in fd) > 1e-3
    np.testing.assert_allclose(np.asarray(g_light), fd, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(float(g_dy), fd_dy, rtol=1e-5, atol=1e-8)
