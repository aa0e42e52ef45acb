"""Watertight triangle tests: a ray through an edge or a vertex shared by triangles of a
mesh hits at least one of them (``raytrax.shapes.tri_t``), in the brute-force search and
through the BVH, for closest hits and for shadow rays, in float32 and float64."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from helpers import grid_mesh

import raytrax as rt
from raytrax import bvh as B
from raytrax import intersect as I


def _height_field(k, seed=0):
    """A k x k grid of cells over [-2, 2]^2 (two triangles each), rolling heights."""
    rng = np.random.default_rng(seed)
    return grid_mesh(
        k, 2.0, lambda x, z: 0.3 * np.sin(1.7 * x + 0.4) * np.cos(1.1 * z) + 0.05 * rng.standard_normal(x.shape)
    )


def _scene(v, f, dtype):
    b = rt.SceneBuilder("classic", width=8, height=6)
    b.light((0, 5, 0), (1, 1, 1))
    b.material("m", color=(0.5, 0.5, 0.5))
    b.mesh(v, f, "m")
    return b.build(dtype)


def _targets(v, f, rng):
    """Points on the mesh where triangles meet: every vertex used by a face, and points
    along every edge (its midpoint and a random point), as float64 ``(m, 3)``."""
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    s = rng.uniform(0.05, 0.95, size=(edges.shape[0], 1))
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    return np.concatenate([v[np.unique(f)], 0.5 * (a + b), a + s * (b - a)])


@jax.jit
def _query(scene, o, d):
    """Closest distance of the triangle kind (through the scene's BVH where it has one,
    and by brute force) and the shadow crossings of the open segments of length 100."""
    kinds = I.prepare(scene)
    tri = next(k for k in kinds if k.name == "triangle")
    ray = (o[0], o[1], o[2], d[0], d[1], d[2])
    t_acc, _ = I.closest_kind(tri, ray, 0.0)
    t_brute, _ = I.closest_kind(tri._replace(accel=None), ray, 0.0)
    tmax = jnp.full(o.shape[1:], 100.0, o.dtype)
    return t_acc, t_brute, I.occluder_counts(kinds, o, d, tmax, 1)[:, 0]


def _rays_at(targets, origins, dtype):
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return jnp.asarray(origins.T, dtype), jnp.asarray(d.T, dtype)


def _assert_all_hit(scene, o, d, what):
    t_acc, t_brute, crossings = map(np.asarray, _query(scene, o, d))
    n = t_brute.size
    assert np.isfinite(t_brute).all(), f"{what}: {n - np.isfinite(t_brute).sum()} of {n} rays miss (brute force)"
    if scene.bvh is not None:
        assert np.isfinite(t_acc).all(), f"{what}: {n - np.isfinite(t_acc).sum()} of {n} rays miss (BVH)"
    assert (crossings >= 1).all(), f"{what}: {(crossings < 1).sum()} of {n} shadow rays cross nothing"


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("k", [3, 12])  # 18 triangles (brute force), 288 (BVH)
def test_rays_through_shared_edges_and_vertices_of_a_height_field_hit_it(k, dtype):
    v, f = _height_field(k)
    scene = _scene(v, f, dtype)
    assert (scene.bvh is not None) == (f.shape[0] > B.MIN_TRIANGLES)
    rng = np.random.default_rng(k)
    targets = _targets(v, f, rng)
    # Only interior points: a ray through the border of the grid may pass beside it.
    targets = targets[np.max(np.abs(targets[:, [0, 2]]), 1) < 2 - 1e-6]
    # From above, at random positions and from straight above (axis-aligned directions).
    above = rng.uniform(-3, 3, size=targets.shape) * [1, 0, 1] + [0, 4, 0]
    for origins, what in ((above, "from random points above"), (targets + [0, 3, 0], "straight down")):
        o, d = _rays_at(targets, origins, dtype)
        _assert_all_hit(scene, o, d, what)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_every_ray_from_inside_a_closed_mesh_hits_it(dtype):
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)  # 320 faces
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    scene = _scene(v, f, dtype)
    rng = np.random.default_rng(0)
    targets = _targets(v, f, rng)
    # From the centre and from random points inside, through its vertices and edges.
    inside = rng.uniform(-0.4, 0.4, size=targets.shape)
    for origins, what in ((np.zeros_like(targets), "from the centre"), (inside, "from inside")):
        o, d = _rays_at(targets, origins, dtype)
        _assert_all_hit(scene, o, d, what)
