"""The compiled pieces of a fit: the start check and the solver's ``init`` and ``step``.

They live at module level so that their caches outlive one fit.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..compile_options import filter_jit
from ._problem import _Problem
from ._uncertainty import _jacobian

_TAGS = frozenset()
_JACFWD_MAX = 32  # fitted numbers up to which the start check resolves single components


def _effect(problem: _Problem, z, probe):
    """For each fitted name, the sum over the (weighted) image of
    ``|d image / d z|``: per component (forward-mode Jacobian, the compiled
    function the standard errors use too) when there are few, else along one
    random direction per name. Zero means no effect."""
    w = problem.weights
    size = sum(int(np.prod(v.shape)) for v in z.values())
    if size <= _JACFWD_MAX:
        _, J = _jacobian(problem, z)
        return {n: jnp.sum(jnp.abs(j) * w.reshape(w.shape + (1,) * (j.ndim - 3)), axis=(0, 1, 2)) for n, j in J.items()}
    return _effect_along(problem, z, probe)


@filter_jit
def _effect_along(problem: _Problem, z, probe):
    """:func:`_effect` for many fitted numbers: along one random direction per name."""
    w = problem.weights
    names = list(z)

    def along(i):
        t = {n: jnp.where(k == i, probe[n], jnp.zeros_like(probe[n])) for k, n in enumerate(names)}
        return jnp.sum(jnp.abs(jax.jvp(problem.image, (z,), (t,))[1]) * w)

    per = jax.vmap(along)(jnp.arange(len(names)))
    return {n: per[k] for k, n in enumerate(names)}


def _fn(problem, least_squares):
    """The function optimistix solves: the residual image or the scalar loss."""
    return problem.residual if least_squares else problem.objective


def _solver_init(problem, solver, z, least_squares):
    """The solver's state at ``z`` (uncompiled; :func:`_init` and :func:`_step` call it)."""
    fn = _fn(problem, least_squares)
    f_struct, aux_struct = jax.eval_shape(fn, z, None)
    return solver.init(fn, z, None, {}, f_struct, aux_struct, _TAGS)


@filter_jit
def _init(problem, solver, z, least_squares):
    """The array part of the solver's initial state (compiled)."""
    return eqx.filter(_solver_init(problem, solver, z, least_squares), eqx.is_array)


@filter_jit
def _step(problem, solver, z, dyn_state, least_squares):
    """One solver step (compiled): -> (new z, new state's arrays, done, result,
    loss at the new point, whether it is finite, the parameter values there)."""
    fn = _fn(problem, least_squares)
    # The state's static part (jaxprs inside linear operators, compared by
    # identity) is rebuilt here from `init`, as optimistix's own loop keeps the
    # one from `init`; only arrays cross the jit boundary.
    static = eqx.filter(_solver_init(problem, solver, z, least_squares), eqx.is_array, inverse=True)
    state = eqx.combine(dyn_state, static)
    z_new, state, _ = solver.step(fn, z, None, {}, state, _TAGS)
    done, result = solver.terminate(fn, z, None, {}, state, _TAGS)
    f_info = getattr(state, "f_info", None)
    if f_info is not None and hasattr(f_info, "residual") and least_squares:
        obj = jnp.sum(f_info.residual**2)
    elif f_info is not None and hasattr(f_info, "f") and not least_squares:
        obj = f_info.f
    else:
        obj = fn(z_new, None)[0]
        obj = jnp.sum(obj**2) if least_squares else obj
    finite = jnp.isfinite(obj) & jnp.all(
        jnp.stack([jnp.all(jnp.isfinite(v)) for v in jax.tree_util.tree_leaves(z_new)])
    )
    return (
        z_new,
        eqx.filter(state, eqx.is_array),
        done,
        result,
        obj / problem.scale,
        finite,
        problem.scene_values(z_new),
    )
