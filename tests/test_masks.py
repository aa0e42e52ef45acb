"""raytrax.masks: boolean reductions equal jnp's and compile without XLA:CPU's slow windows."""

import jax
import jax.numpy as jnp
import numpy as np

from raytrax.masks import SMALL_MAX, all_true, any_true, count_true, pack_map, prefix_count, true_indices


def test_any_true_and_all_true_equal_jnp_any_and_all():
    rng = np.random.default_rng(0)
    shapes = [((7,), None), ((5000,), None), ((3, 40), 1), ((3, 40), 0), ((2, 3, 4), (0, 2)), ((0,), None)]
    # Flat sizes on either side of the rows-of-32 path (33 to SMALL_MAX) and of its padding.
    shapes += [((n,), None) for n in (33, 64, 100, SMALL_MAX, SMALL_MAX + 1)] + [((4, 25), None)]
    for shape, axis in shapes:
        for p in (0.0, 0.01, 0.5, 1.0):
            x = rng.random(shape) < p
            assert np.array_equal(np.asarray(any_true(x, axis)), np.any(x, axis)), (shape, axis, p)
            assert np.array_equal(np.asarray(all_true(x, axis)), np.all(x, axis)), (shape, axis, p)
    assert any_true(jnp.ones(3, bool)).dtype == jnp.bool_


def test_count_true_equals_the_sum():
    rng = np.random.default_rng(1)
    for n in (0, 5, 33, 64, 100, SMALL_MAX, SMALL_MAX + 1, 1000, 4096, 70000):
        for p in (0.0, 0.3, 1.0):
            x = rng.random(n) < p
            c = count_true(jnp.asarray(x))
            assert int(c) == int(x.sum()) and c.dtype == jnp.sum(jnp.asarray(x)).dtype, (n, p)
    assert count_true(jnp.ones((3, 50), bool), jnp.int32).dtype == jnp.int32


def test_any_true_compiles_without_boolean_reduce_windows():
    # jnp.any over a few thousand rays compiles to 32-wide reduce-windows of i1 vectors on
    # XLA:CPU, several times the compile time of the byte reduction any_true uses.
    x = jnp.zeros(4096, jnp.float32)
    hlo = jax.jit(lambda v: any_true(v > 0)).lower(x).compile().as_text() or ""
    assert "pred[128]{0} reduce-window" not in hlo
    # Small masks (reduced in rows of 32 bytes or integers): no window of booleans.
    small = jnp.zeros(300, jnp.float32)
    for fn in (any_true, count_true):
        text = jax.jit(lambda v: fn(v > 0)).lower(small).compile().as_text() or ""
        assert not [ln for ln in text.splitlines() if "reduce-window(" in ln and "= pred[" in ln], text
    ref = jax.jit(lambda v: jnp.any(v > 0)).lower(x).compile().as_text() or ""
    if jax.default_backend() == "cpu" and "reduce-window" in ref:  # the pattern any_true avoids is still XLA's
        assert hlo.count("reduce-window") < ref.count("reduce-window")


def test_true_indices_equal_jnp_nonzero():
    rng = np.random.default_rng(2)
    for n, size in ((1, 1), (10, 4), (100, 100), (5000, 3000), (5000, 6000)):
        for p in (0.0, 0.1, 0.9, 1.0):
            m = jnp.asarray(rng.random(n) < p)
            for fill in (0, n):
                got = true_indices(m, size, fill)
                (want,) = jnp.nonzero(m, size=size, fill_value=fill)
                assert got.dtype == want.dtype
                np.testing.assert_array_equal(np.asarray(got), np.asarray(want), err_msg=f"{n} {size} {p} {fill}")


def test_prefix_count_equals_cumsum():
    rng = np.random.default_rng(3)
    for n in (1, 7, 127, 128, 1000, 2048, 4096, 16384, 16447, 70000, 300000):
        for p in (0.0, 0.2, 1.0):
            m = rng.random(n) < p
            got = jax.jit(prefix_count)(jnp.asarray(m))
            assert got.dtype == jnp.int32
            np.testing.assert_array_equal(np.asarray(got), np.cumsum(m), err_msg=f"{n} {p}")


def test_pack_map_sends_each_true_entry_to_its_rank():
    rng = np.random.default_rng(4)
    for k, size in ((5, 5), (300, 200), (4096, 4096)):
        m = rng.random(k) < 0.4
        src, dst, c = pack_map(jnp.asarray(m), size, k, jnp.int32)
        idx = np.nonzero(m)[0]
        assert int(c) == len(idx) and c.dtype == jnp.int32 and src.dtype == jnp.int32
        want_dst = np.full(k, size)
        want_dst[idx] = np.arange(len(idx))
        want_dst[want_dst >= size] = size  # entries past the last slot have none
        np.testing.assert_array_equal(np.where(np.asarray(dst) >= size, size, np.asarray(dst)), want_dst)
        want_src = np.full(size, k)
        want_src[: min(size, len(idx))] = idx[:size]
        np.testing.assert_array_equal(np.asarray(src), want_src)
