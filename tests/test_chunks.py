"""raytrax.chunks: equal chunks of a batch axis, mapped and joined back, on one device
and split over four (conftest.py gives the suite four CPU devices)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from raytrax.chunks import equal_chunks, join, map_chunks, map_leading, map_worklist, split


@pytest.mark.parametrize("m,most,multiple", [(1, 4, 1), (10, 4, 1), (12, 4, 1), (13, 512, 4), (307200, 1 << 18, 1)])
def test_equal_chunks_hold_everything_with_little_padding(m, most, multiple):
    n, size = equal_chunks(m, most, multiple)
    assert n % multiple == 0 and size <= most and n * size >= m
    assert n * size - m < n  # padding: less than one entry per chunk
    assert n == multiple * -(-m // (most * multiple))  # the fewest such chunks


def test_split_pads_with_the_last_entry_or_a_fill_and_join_undoes_it():
    x = jnp.arange(2 * 10, dtype=jnp.int32).reshape(2, 10)
    c = split(x, 3, 4)
    assert c.shape == (3, 2, 4)
    np.testing.assert_array_equal(np.asarray(c[1]), np.asarray(x[:, 4:8]))
    np.testing.assert_array_equal(np.asarray(c[2]), [[8, 9, 9, 9], [18, 19, 19, 19]])
    np.testing.assert_array_equal(np.asarray(split(x, 3, 4, fill=-1)[2]), [[8, 9, -1, -1], [18, 19, -1, -1]])
    np.testing.assert_array_equal(np.asarray(join(c, 10)), np.asarray(x))
    w = jnp.arange(10 * 3, dtype=jnp.int32).reshape(10, 3)  # the batch on axis 0
    np.testing.assert_array_equal(np.asarray(join(split(w, 5, 2, axis=0), 10, axis=0)), np.asarray(w))
    with pytest.raises(ValueError, match="do not fit"):
        split(x, 2, 4)


def _fn(c, k=None):
    # Outputs with the batch last and with it first; an optional constant.
    x, y = c
    off = 0.0 if k is None else k
    return {"a": x * 2.0 + off, "b": jnp.stack([y, y + 1.0], -1)}


@pytest.mark.parametrize("devices,deal", [(1, False), (4, False), (4, True)])
def test_map_chunks_equals_the_function_on_everything(devices, deal):
    m = 37
    x = jnp.linspace(0.0, 1.0, 3 * m, dtype=jnp.float32).reshape(3, m)
    y = jnp.arange(m, dtype=jnp.float32)
    n, size = equal_chunks(m, 5, devices)
    k = jnp.float32(0.5)

    @jax.jit
    def run(x, y, k):
        # out_axis -1 for "a" (3, size) and 0 for "b" (size, 2) cannot mix in one call: two calls
        a = map_chunks(lambda c, kk: _fn(c, kk)["a"], (x, y), m, n, size, devices=devices, deal=deal, const=k)
        b = map_chunks(lambda c: _fn(c)["b"], (x, y), m, n, size, out_axis=0, devices=devices, deal=deal)
        return a, b

    a, b = run(x, y, k)
    want = _fn((x, y), k)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(want["a"]))
    np.testing.assert_array_equal(np.asarray(b), np.asarray(_fn((x, y))["b"]))


def test_map_chunks_is_differentiable_over_devices():
    m = 20
    x = jnp.linspace(0.5, 1.5, m, dtype=jnp.float32)

    def loss(s, devices):
        n, size = equal_chunks(m, 3, devices)
        out = map_chunks(lambda c: jnp.sin(s * c), x, m, n, size, devices=devices, deal=True)
        return jnp.sum(out**2)

    g1 = jax.grad(loss)(jnp.float32(0.7), 1)
    g4 = jax.grad(loss)(jnp.float32(0.7), 4)
    want = jnp.sum(2 * jnp.sin(0.7 * x) * jnp.cos(0.7 * x) * x)
    np.testing.assert_allclose(float(g1), float(want), rtol=1e-5)
    np.testing.assert_allclose(float(g4), float(want), rtol=1e-5)


def test_map_leading_one_entry_equals_the_loop_in_value_and_gradient():
    def loss(s, n, remat):
        xs = {"a": jnp.linspace(0.5, 1.5, 3 * n, dtype=jnp.float32).reshape(n, 3)}
        out = map_leading(lambda x: jnp.sin(s * x["a"]) ** 2, xs, remat=remat)
        assert out.shape == (n, 3)
        return jnp.sum(out)

    for n, remat in ((1, True), (1, False), (2, True), (2, False)):
        s = jnp.float32(0.7)
        g = float(jax.grad(loss)(s, n, remat))
        xn = jnp.linspace(0.5, 1.5, 3 * n, dtype=jnp.float32)
        want = float(jnp.sum(2 * jnp.sin(0.7 * xn) * jnp.cos(0.7 * xn) * xn))
        np.testing.assert_allclose(g, want, rtol=1e-5)
        np.testing.assert_allclose(float(loss(s, n, remat)), float(jnp.sum(jnp.sin(0.7 * xn) ** 2)), rtol=1e-6)


def _halving(devices, n, size, start):
    """A work list where each live entry ``v > 1`` adds the entry ``v // 2``."""
    v = jnp.zeros(n * size, jnp.int32).at[: len(start)].set(jnp.asarray(start, jnp.int32))
    live = jnp.arange(n * size) < len(start)

    def fn(c, const):  # kept: the value seen; passed to spawn only: its half
        return {"seen": jnp.where(c["live"], c["v"] + const, 0)}, {"half": c["v"] // 2}

    def spawn(c, aux):
        new = c["live"] & (aux["half"] > 0)
        return new, {"v": aux["half"], "live": new}

    outs, final, lost = map_worklist(fn, spawn, {"v": v, "live": live}, len(start), n, size, devices, const=100)
    seen = np.asarray(outs["seen"])
    return sorted(int(x) - 100 for x in seen[seen > 0]), np.asarray(final["live"]), int(lost)


@pytest.mark.parametrize("devices", [1, 2])
def test_a_work_list_runs_the_entries_it_adds_in_later_chunks(devices):
    seen, live, lost = _halving(devices, 8, 4, [8, 3, 5])
    assert seen == sorted([8, 4, 2, 1, 3, 1, 5, 2, 1])  # every added entry ran once
    assert lost == 0 and live.sum() == 9
    # Too little room: what does not fit is dropped and counted, what fits runs.
    seen, live, lost = _halving(devices, 2, 2, [64, 64])
    assert lost > 0 and len(seen) == live.sum() and len(seen) + lost <= 14
