"""raytrax.branching: conditionals that skip work, under jit, vmap and reverse mode."""

import jax
import jax.numpy as jnp
import numpy as np

from raytrax.branching import any_in_batch, run_or_zeros


def _fn(x, k):
    return {"sum": jnp.sum(x * x) + k, "ids": jnp.arange(3, dtype=jnp.int32) + k.astype(jnp.int32)}


def test_run_or_zeros_gives_the_function_or_zeros_of_its_shapes():
    x, k = jnp.arange(4.0, dtype=jnp.float32), jnp.float32(2.0)
    on = jax.jit(lambda x, k: run_or_zeros(jnp.bool_(True), _fn, x, k))(x, k)
    off = jax.jit(lambda x, k: run_or_zeros(jnp.bool_(False), _fn, x, k))(x, k)
    assert float(on["sum"]) == 16.0 and on["ids"].tolist() == [2, 3, 4]
    assert float(off["sum"]) == 0.0 and off["ids"].tolist() == [0, 0, 0]
    assert off["sum"].dtype == jnp.float32 and off["ids"].dtype == jnp.int32


def test_run_or_zeros_traces_the_function_once():
    calls = []

    def fn(x):
        calls.append(1)
        return 2.0 * x

    out = jax.jit(lambda x: run_or_zeros(jnp.any(x > 0), fn, x))(jnp.ones(3))
    np.testing.assert_array_equal(np.asarray(out), [2.0, 2.0, 2.0])
    assert len(calls) == 1  # jax.eval_shape + lax.cond of a plain function trace it twice


def test_run_or_zeros_in_a_map_over_chunks_and_its_gradient():
    # Chunks whose predicate fails contribute zeros, in value and in gradient.
    def loss(w, xs):
        def chunk(x):
            return run_or_zeros(jnp.any(x > 0), lambda x: jnp.sum(jnp.sin(w * x)), x)

        return jnp.sum(jax.lax.map(chunk, xs))

    xs = jnp.asarray([[0.5, 1.0], [-1.0, -2.0], [0.0, 2.0]], jnp.float32)
    w = jnp.float32(0.7)
    live = np.asarray(xs)[[0, 2]]
    want = np.sum(np.sin(0.7 * live))
    want_grad = np.sum(live * np.cos(0.7 * live))
    v, g = jax.value_and_grad(loss)(w, xs)
    np.testing.assert_allclose(float(v), want, rtol=1e-6)
    np.testing.assert_allclose(float(g), want_grad, rtol=1e-6)


def test_any_in_batch_keeps_a_vmapped_branch_a_branch():
    # Under vmap the predicate is the whole batch's: every member runs the branch when
    # any needs it, so each member's value is its own function value.
    def f(x):
        return run_or_zeros(any_in_batch(x > 0), lambda x: x + 1.0, x)

    out = jax.vmap(f)(jnp.asarray([-3.0, 2.0], jnp.float32))
    np.testing.assert_array_equal(np.asarray(out), [-2.0, 3.0])  # -3 ran the branch too (not zero)
    none = jax.vmap(f)(jnp.asarray([-1.0, -2.0], jnp.float32))
    np.testing.assert_array_equal(np.asarray(none), [0.0, 0.0])
