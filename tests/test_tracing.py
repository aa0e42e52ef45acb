"""raytrax.tracing.tangent_seed: zero in value and derivative, a live tangent under AD,
unbatched under vmap; a scan carry started from it is differentiated exactly."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from raytrax.tracing import tangent_seed


def test_value_and_derivatives_are_zero():
    tree = {"a": jnp.array([1.0, jnp.inf], jnp.float32), "n": jnp.arange(3, dtype=jnp.int32)}
    assert float(tangent_seed(tree, jnp.float32)) == 0.0
    out, tan = jax.jvp(
        lambda a: tangent_seed({"a": a}, jnp.float32), (tree["a"],), (jnp.array([jnp.inf, 1.0], jnp.float32),)
    )
    assert float(out) == 0.0 and float(tan) == 0.0  # no NaN from an infinite tangent
    g = jax.grad(lambda a: jnp.sum(a) * 2.0 + tangent_seed(a, jnp.float32))(jnp.array([0.5, 1.5], jnp.float32))
    np.testing.assert_array_equal(np.asarray(g), [2.0, 2.0])


def test_its_tangent_is_live_only_where_an_input_has_one():
    seen = []

    @jax.custom_jvp
    def probe(s):
        return s

    def rule(primals, tangents):
        seen.append(not isinstance(tangents[0], SymbolicZero))
        return primals[0], tangents[0]

    probe.defjvp(rule, symbolic_zeros=True)
    x = jnp.float32(1.0)
    jax.jvp(lambda x, y: probe(tangent_seed(x, jnp.float32)) + y, (x, x), (x, x))
    assert seen == [True]
    seen.clear()
    jax.grad(lambda x, y: probe(tangent_seed(x, jnp.float32)) + y, argnums=1)(x, x)
    assert seen == []  # x has no tangent: the seed is a constant, the rule is not called


def test_unbatched_under_vmap():
    out = jax.vmap(lambda a: tangent_seed(a, jnp.float64))(jnp.ones((4, 2)))
    assert out.shape == (4,) and np.all(np.asarray(out) == 0.0)


def test_scan_from_a_seeded_zero_carry_differentiates_exactly():
    def f(x):
        def body(c, _):
            return c * 0.5 + x, None

        c, _ = jax.lax.scan(body, jnp.zeros((3,), x.dtype) + tangent_seed(x, x.dtype), None, length=4)
        return jnp.sum(c)

    x = jnp.float64(0.7)
    # c_4 = x (1 + 1/2 + 1/4 + 1/8) per entry: d/dx sum = 3 * 1.875
    assert float(jax.grad(f)(x)) == 3 * 1.875
    assert float(jax.jvp(f, (x,), (jnp.float64(1.0),))[1]) == 3 * 1.875
