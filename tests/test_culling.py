"""The culled search (raytrax.intersect: kinds of more than CULL_MIN spheres, boxes,
quads or disks searched in spatial groups, a group skipped by a batch of rays that
misses its box) gives exactly the answers of the brute-force search."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt
from raytrax import intersect as I
from raytrax.edges.prims import build_prims
from raytrax.edges.records import records


def _scene(n=90, seed=0, width=12, height=9):
    """More than CULL_MIN of every bounded kind, in random order: spheres, rotated boxes,
    a 10 x 9 checker of boxes sharing faces (ties between neighbours), quads and disks."""
    rng = np.random.default_rng(seed)
    b = rt.SceneBuilder("physical", width=width, height=height, spp=1, max_depth=1)
    b.camera(position=(0.5, 3.0, 6.0), look_at=(0, 0, 0), fov=50)
    b.light((2.0, 5.0, 3.0), intensity=(30.0, 30.0, 30.0))
    b.material("a", color=(0.8, 0.5, 0.2))
    b.material("b", color=(0.2, 0.5, 0.8))
    b.material("mirror", color=(0.1, 0.1, 0.1), reflectivity=0.8)
    b.plane((0, -1.0, 0), (0, 1, 0), "a")
    for c in rng.uniform(-2, 2, size=(n, 3)):
        b.sphere(c, rng.uniform(0.05, 0.3), "ab"[rng.integers(2)])
    for c in rng.uniform(-2, 2, size=(n // 3, 3)):
        h = rng.uniform(0.05, 0.25, 3)
        b.box(c - h, c + h, "b", rotation=rng.uniform(-40, 40, 3))
    cells = [(i, j) for i in range(10) for j in range(9)]
    for k in rng.permutation(len(cells)):
        i, j = cells[k]
        lo = np.array([-2.5 + 0.5 * i, -1.0, -2.5 + 0.5 * j])
        b.box(lo, lo + np.array([0.5, 0.08, 0.5]), "ab"[(i + j) % 2])
    for c in rng.uniform(-2, 2, size=(n, 3)):
        u, v = rng.normal(size=(2, 3)) * 0.2
        b.quad([c, c + u, c + u + v, c + v], "mirror")
    for c in rng.uniform(-2, 2, size=(n, 3)):
        b.disk(c, rng.normal(size=3), rng.uniform(0.05, 0.3), "b")
    return b.build()


def _rays(n=2000, seed=1):
    """Random rays, and axis-parallel ones (direction components exactly 0) starting on
    the checker's face planes."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3.0, 3.0, size=(n, 3))
    d = rng.normal(size=(n, 3))
    k = n // 4
    d[:k] = 0.0
    d[np.arange(k), rng.integers(0, 3, k)] = rng.choice([-1.0, 1.0], k)
    o[: k // 2, 1] = rng.choice([-1.0, -0.92], k // 2)
    o[: k // 2, 0] = -2.5 + 0.5 * rng.integers(0, 11, k // 2)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return jnp.asarray(o.T, jnp.float32), jnp.asarray(d.T, jnp.float32)


def _search_fn(scene, o, d, tmax):
    culled, brute = I.prepare(scene), I.prepare(scene, cull=False)
    ray = (o[0], o[1], o[2], d[0], d[1], d[2])
    nm = scene.materials.color.shape[0]
    return (
        [I.closest_kind(k, ray, 0.0) for k in culled],
        [I.closest_kind(k, ray, 0.0) for k in brute],
        I.occluder_counts(culled, o, d, tmax, nm),
        I.occluder_counts(brute, o, d, tmax, nm),
        [k.groups is not None for k in culled],
    )


_search = jax.jit(_search_fn)


def _check_against_brute_force(search):
    s = _scene()
    o, d = _rays()
    tmax = jnp.asarray(np.random.default_rng(2).uniform(0.1, 5.0, o.shape[1]), o.dtype)
    got, want, c, cb, culled = search(s, o, d, tmax)
    names = [k.name for k in I.prepare(s)]
    assert dict(zip(names, culled)) == {"sphere": True, "box": True, "plane": False, "quad": True, "disk": True}
    for name, (t, i), (tb, ib) in zip(names, got, want):
        t, i, tb, ib = map(np.asarray, (t, i, tb, ib))
        hit = np.isfinite(tb)
        assert 0.05 * hit.size < hit.sum() < hit.size, name  # hits and misses
        np.testing.assert_array_equal(np.isfinite(t), hit, err_msg=name)
        # The same kernel on the same numbers, fused differently: XLA may contract other
        # products into FMAs, and the sphere's quadratic cancels (measured: 9e-6 at most).
        np.testing.assert_allclose(t[hit], tb[hit], rtol=5e-5, err_msg=name)
        np.testing.assert_array_equal(i[hit], ib[hit], err_msg=name)  # ties: the lower index
    np.testing.assert_array_equal(np.asarray(c), np.asarray(cb))
    assert np.asarray(cb).sum() > 0


def test_every_bounded_kind_is_culled_and_matches_brute_force():
    _check_against_brute_force(_search)


def test_two_levels_of_groups_match_brute_force(monkeypatch):
    """Runs of groups culled first (every kind here has 6 to 8 groups: runs of 4,
    the last one padded with empty groups)."""
    monkeypatch.setattr(I, "SUPER_MIN", 2)
    monkeypatch.setattr(I, "SUPER", 4)
    s = _scene()
    assert all(k.groups.top is not None for k in I.prepare(s) if k.groups is not None)
    _check_against_brute_force(jax.jit(_search_fn))


def test_below_the_threshold_nothing_is_culled():
    b = rt.SceneBuilder("physical", width=4, height=3)
    b.material("a", color=(0.5, 0.5, 0.5))
    for k in range(I.CULL_MIN):
        b.sphere((0.1 * k, 0, -3), 0.05, "a")
    assert all(k.groups is None for k in I.prepare(b.build()))


def test_groups_are_compact_in_space():
    """Morton order: each group's box is much smaller than the whole set's."""
    rng = np.random.default_rng(0)
    c = rng.uniform(-1, 1, size=(1000, 3))
    bounds = jnp.asarray(np.stack([(c - 0.01).T, (c + 0.01).T]))
    order = np.asarray(I._spatial_order(bounds))
    np.testing.assert_array_equal(np.sort(order), np.arange(1000))
    groups = order[: 1000 // I.GROUP * I.GROUP].reshape(-1, I.GROUP)
    assert all(np.all(np.diff(g) > 0) for g in groups)  # by index within a group
    ext = np.ptp(c[groups], axis=1).prod(-1)
    assert np.median(ext) < 0.05 * np.ptp(c, axis=0).prod()


def test_render_and_gradient_equal_the_brute_force_ones(monkeypatch):
    s = _scene(width=8, height=6)
    name = "light[0].position"
    p = rt.parameters(s)[name]

    def loss(x):
        return jnp.mean(rt.render(rt.with_parameters(s, {name: x})) ** 2)

    got = jax.value_and_grad(loss)(p)
    monkeypatch.setattr(I, "CULL_MIN", 10**9)
    assert all(k.groups is None for k in I.prepare(s))
    want = jax.value_and_grad(loss)(p)
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(want[1]))
    assert np.all(np.isfinite(np.asarray(got[1]))) and np.any(np.asarray(got[1]) != 0)


def test_vmap_over_lights_equals_a_loop():
    """Under ``jax.vmap`` over light positions the shadow rays are batched; a group is
    still skipped only when no ray of any batch member meets its box."""
    s = _scene(width=8, height=6)
    name = "light[0].position"
    p = rt.parameters(s)[name]
    ps = p[None] + jnp.asarray([[0.0, 0.0, 0.0], [-2.0, 1.0, 0.5], [1.5, -0.5, 2.0]], p.dtype)

    def render(x):
        return rt.render(rt.with_parameters(s, {name: x}))

    batch = np.asarray(jax.vmap(render)(ps))
    for b, x in zip(batch, ps):
        np.testing.assert_allclose(b, np.asarray(render(x)), rtol=1e-6, atol=1e-7)
    assert np.ptp(batch, axis=0).max() > 1e-3  # the lights' moves change the image


def test_edge_records_equal_the_brute_force_ones():
    """The edge finder's records (closest hit, first and last occluder towards each light,
    level by level of the specular chain) use the culled search too: the same records."""
    s = _scene(width=16, height=12)
    jj, ii = np.meshgrid(np.arange(48) + 0.5, np.arange(36) + 0.5)  # 3 x 3 positions per pixel
    xy = jnp.asarray(np.stack([jj.ravel(), ii.ravel()]) / 3.0, jnp.float32)

    def rec(cull):
        kinds = I.prepare(s, cull=cull)
        assert any(k.groups is not None for k in kinds) == cull
        P, off = build_prims(s)
        return records(s, kinds, off, P, xy, 16, 12, 2)

    got, want = jax.jit(rec, static_argnums=0)(True), jax.jit(rec, static_argnums=0)(False)
    for name, a, b in zip(got._fields, got, want):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
    assert np.any(np.asarray(got.hit) >= 0) and np.any(np.asarray(got.first) >= 0)
    assert np.any(np.asarray(got.hit[1]) >= 0)  # the mirrors' reflections reach a second level
