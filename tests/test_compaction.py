"""raytrax.renderer.compaction: the Whitted integrator's ray queue. Packing keeps the
live samples in order, its derivatives (forward mode and reverse mode, which are
written by hand so that both are gathers) match central differences, and a queue
written block by block reads back what was appended, masked past the live count."""

import jax
import jax.numpy as jnp
import numpy as np

from raytrax.renderer import compaction as C

ALIVE = np.array([True, False, True, True, False, False, True])


def test_packed_keeps_live_samples_in_order_and_zeroes_the_tail():
    k, width = ALIVE.size, 9
    rows = jnp.arange(2 * 3 * k, dtype=jnp.float32).reshape(2, 3, k) + 1.0
    ids = jnp.arange(k, dtype=jnp.int32) + 10
    block, bid, c = C.packed(jnp.asarray(ALIVE), rows, ids, width)
    live = np.flatnonzero(ALIVE)
    assert int(c) == live.size
    np.testing.assert_array_equal(np.asarray(block[..., : live.size]), np.asarray(rows)[..., live])
    np.testing.assert_array_equal(np.asarray(block[..., live.size :]), 0.0)
    np.testing.assert_array_equal(np.asarray(bid[: live.size]), live + 10)


def test_packed_derivatives_match_central_differences():
    k, width = ALIVE.size, 9
    alive = jnp.asarray(ALIVE)
    rows0 = jax.random.normal(jax.random.key(0), (2, 3, k), jnp.float64)
    tangent = jax.random.normal(jax.random.key(1), (2, 3, k), jnp.float64)
    weights = jax.random.normal(jax.random.key(2), (2, 3, width), jnp.float64)

    def loss(rows):  # a nonlinear function of the packed block
        block = C.packed(alive, rows, jnp.arange(k, dtype=jnp.int32), width)[0]
        return jnp.sum(weights * jnp.sin(block) * block)

    h = 1e-6
    fd = (loss(rows0 + h * tangent) - loss(rows0 - h * tangent)) / (2 * h)
    jvp = jax.jvp(loss, (rows0,), (tangent,))[1]
    vjp = jnp.sum(jax.grad(loss)(rows0) * tangent)
    np.testing.assert_allclose(float(jvp), float(fd), rtol=1e-7)
    np.testing.assert_allclose(float(vjp), float(fd), rtol=1e-7)
    # dead samples get no cotangent
    g = np.asarray(jax.grad(loss)(rows0))
    np.testing.assert_array_equal(g[..., ~ALIVE], 0.0)


def test_append_then_read_returns_the_live_columns_and_masks_the_rest():
    r, B, ns, cap, n = 2, 2, 3, 12, 100
    queue = (jnp.full((2, r, B, cap), 7.0, jnp.float32), jnp.full((2, B, cap), 5, jnp.int32))
    cnt = jnp.zeros((), jnp.int32)
    written = []
    for start in (0, 4):  # two sub-tiles' blocks, each of width ns + 1
        k = ns + 1
        rows = jnp.arange(r * B * k, dtype=jnp.float32).reshape(r, B, k) + 100.0 * (start + 1)
        alive = jnp.asarray([True, start == 0, False, True])
        block, bid, c = C.packed(alive, rows, jnp.arange(k, dtype=jnp.int32) + start, k)
        queue = C.append(queue, jnp.int32(1), cnt, block, bid)
        written.append((np.asarray(rows)[..., np.asarray(alive)], np.flatnonzero(np.asarray(alive)) + start))
        cnt = cnt + c
    rays_all = np.concatenate([w[0] for w in written], -1)  # (r, B, cnt)
    ids_all = np.concatenate([w[1] for w in written])
    assert int(cnt) == ids_all.size == 5
    for j in range(2):  # sub-tiles of ns columns; the second is cut by the live count
        rays, sid = C.read(queue, jnp.int32(1), jnp.int32(j), ns, cnt, n)
        cols = np.arange(j * ns, (j + 1) * ns)
        ok = cols < int(cnt)
        want = np.where(ok, rays_all[..., np.minimum(cols, int(cnt) - 1)], 0.0).reshape(r, B * ns)
        np.testing.assert_array_equal(np.asarray(rays), want)
        np.testing.assert_array_equal(np.asarray(sid), np.tile(np.where(ok, ids_all[np.minimum(cols, 4)], n), B))


def test_queue_over_depths_derivative_matches_central_differences():
    # The queue used as the integrator uses it: four depths of two sub-tiles, blocks
    # that overlap past their live count, masked reads, each half written twice;
    # reverse mode, forward mode and vmap.
    r, B, ns, n, S = 2, 1, 3, 50, 2
    cap = S * ns + ns
    x0 = jax.random.normal(jax.random.key(3), (r, B, S * ns), jnp.float64)
    tangent = jax.random.normal(jax.random.key(4), x0.shape, jnp.float64)
    alive = [jnp.asarray(a) for a in ([True, False, True], [True, True, False], [False, True, True])]

    def loss(x):
        queue = (jnp.zeros((2, r, B, cap), x.dtype), jnp.full((2, B, cap), n, jnp.int32))
        cols, total = jnp.zeros((), jnp.int32), 0.0
        for depth in range(4):
            half = jnp.int32(depth % 2)
            cnt = jnp.zeros((), jnp.int32)
            for j in range(S):
                if depth == 0:
                    rays = x[..., j * ns : (j + 1) * ns].reshape(r, B * ns)
                    sid = jnp.arange(ns, dtype=jnp.int32) + j * ns
                else:
                    rays, sid = C.read(queue, half, jnp.int32(j), ns, cols, n)
                total = total + jnp.sum(jnp.sin(rays) * (depth + 1.0))
                kids = (1.3 * jnp.sin(rays) + 0.2 * rays**2).reshape(r, B, ns)
                block, bid, c = C.packed(alive[(depth + j) % 3] & (sid < n), kids, sid, ns)
                queue = C.append(queue, 1 - half, cnt, block, bid)
                cnt = cnt + c
            cols = cnt
        return total

    h = 1e-6
    fd = (loss(x0 + h * tangent) - loss(x0 - h * tangent)) / (2 * h)
    grad = jax.jit(jax.grad(loss))
    np.testing.assert_allclose(float(jnp.sum(grad(x0) * tangent)), float(fd), rtol=1e-7)
    np.testing.assert_allclose(float(jax.jvp(loss, (x0,), (tangent,))[1]), float(fd), rtol=1e-7)
    # under vmap: each example's gradient
    xs = jnp.stack([x0, 0.5 * x0 + 0.1])
    np.testing.assert_allclose(np.asarray(jax.vmap(grad)(xs)[1]), np.asarray(grad(xs[1])), rtol=1e-12)


def test_packed_in_chunks_matches_one_gather_and_zeroes_skipped_chunks():
    # A block wider than one chunk (compaction.PACK_CHUNK): the chunks past the live
    # count are skipped when nothing is differentiated; the block must be the same.
    width = 4 * C.PACK_CHUNK
    for frac in (0.0, 0.3, 1.0):  # no live sample, live ones in the first chunks, all live
        k = width - 5
        alive = np.asarray(jax.random.uniform(jax.random.key(3), (k,)) < frac)
        rows = jax.random.normal(jax.random.key(4), (2, 2, k), jnp.float32)
        block, bid, c = C.packed(jnp.asarray(alive), rows, jnp.arange(k, dtype=jnp.int32), width)
        live = np.flatnonzero(alive)
        assert int(c) == live.size
        expected = np.zeros((2, 2, width), np.float32)
        expected[..., : live.size] = np.asarray(rows)[..., live]
        np.testing.assert_array_equal(np.asarray(block), expected)
        np.testing.assert_array_equal(np.asarray(bid[: live.size]), live)
