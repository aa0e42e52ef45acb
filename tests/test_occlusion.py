"""Shadow-ray queries (``intersect.occluded``, ``intersect.occluder_counts``) against
a NumPy count of ray-sphere crossings, for kinds small enough to be tested one
primitive at a time, as one (rays, N) tile, and in blocks of ``intersect.BLOCK``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import raytrax as rt
from raytrax import intersect as I


def _spheres(n, seed):
    rng = np.random.default_rng(seed)
    b = rt.SceneBuilder("classic", width=8, height=6, max_depth=1)
    b.camera(position=(0, 0, 6), look_at=(0, 0, 0), fov=45)
    b.light((2.0, 4.0, 3.0), intensity=(1.0, 1.0, 1.0))
    for m in range(3):
        b.material(f"m{m}", color=(0.2 + 0.2 * m, 0.5, 0.5))
    centres = rng.uniform(-2.0, 2.0, size=(n, 3))
    radii = rng.uniform(0.1, 0.4, size=n) * (60 / n) ** (1 / 3)  # about as many rays blocked at any n
    mats = rng.integers(0, 3, size=n)
    for c, r, m in zip(centres, radii, mats):
        b.sphere(tuple(c), float(r), f"m{m}")
    return b.build(), centres, radii


def _reference(o, d, tmax, centres, radii, scene):
    """Per ray and material: crossings of the open segment (0, tmax); and a mask of
    the rays that pass no sphere surface within 1e-3 of 0, tmax or a tangent."""
    q = o.T[:, None, :] - centres[None]  # (n, N, 3)
    b = np.einsum("nk,nmk->nm", d.T, q)
    c = np.sum(q * q, -1) - radii[None] ** 2
    disc = b * b - c
    s = np.sqrt(np.maximum(disc, 0.0))
    roots = np.stack([-b - s, -b + s])  # (2, n, N)
    inside = (roots > 0) & (roots < tmax[None, :, None]) & (disc > 0)[None]
    per_prim = inside.sum(0)  # (n, N)
    mat = np.asarray(scene.spheres.material)
    counts = np.stack([per_prim[:, mat == m].sum(1) for m in range(scene.materials.color.shape[0])], 1)
    near = (np.abs(roots) < 1e-3) | (np.abs(roots - tmax[None, :, None]) < 1e-3)
    clear = ~np.any(near & (disc > 0)[None], (0, 2)) & ~np.any(np.abs(disc) < 1e-3, 1)
    return counts, clear


@jax.jit
def _queries(scene, o, d, tmax):
    kinds = I.prepare(scene)
    return I.occluded(kinds, o, d, tmax), I.occluder_counts(kinds, o, d, tmax, scene.materials.color.shape[0])


@pytest.mark.parametrize("n", [I.UNROLL_SHADOW - 4, 60, I.BLOCK + 72])
def test_shadow_queries_match_numpy_crossings(n):
    scene, centres, radii = _spheres(n, seed=n)
    rng = np.random.default_rng(1)
    m = 512
    o = rng.uniform(-2.5, 2.5, size=(3, m))
    d = rng.normal(size=(3, m))
    d /= np.linalg.norm(d, axis=0)
    tmax = rng.uniform(0.2, 5.0, size=m)
    counts, clear = _reference(o, d, tmax, centres, radii, scene)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    blocked, got = _queries(scene, f32(o), f32(d), f32(tmax))
    blocked, got = np.asarray(blocked), np.asarray(got)
    assert clear.mean() > 0.9
    assert 0.1 < (counts.sum(1) > 0).mean() < 0.9  # some rays blocked, some not
    np.testing.assert_array_equal(got[clear], counts[clear])
    np.testing.assert_array_equal(blocked[clear], counts[clear].sum(1) > 0)
