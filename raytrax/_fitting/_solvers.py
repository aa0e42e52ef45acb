"""The solvers :func:`raytrax.fit` knows by name, and choosing one."""

from __future__ import annotations

import difflib

import optimistix as optx

LEAST_SQUARES = ("levenberg_marquardt", "gauss_newton", "dogleg")
MINIMISERS = ("bfgs", "lbfgs", "gradient_descent", "nonlinear_cg")
SOLVERS = LEAST_SQUARES + MINIMISERS


def _make_solver(solver, rtol, atol, learning_rate):
    """-> (the optimistix solver, whether it is a least-squares solver) for a name or an instance."""
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        return solver, True
    if isinstance(solver, optx.AbstractMinimiser):
        return solver, False
    if not isinstance(solver, str):
        raise TypeError(
            f"solver: expected one of {SOLVERS} or an optimistix least-squares solver or minimiser, got {solver!r}"
        )
    key = solver.lower().replace("-", "_").replace(" ", "_")
    aliases = {
        "lm": "levenberg_marquardt",
        "gn": "gauss_newton",
        "gd": "gradient_descent",
        "levenbergmarquardt": "levenberg_marquardt",
        "gaussnewton": "gauss_newton",
    }
    key = aliases.get(key, key)
    if key == "levenberg_marquardt":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol), True
    if key == "gauss_newton":
        return optx.GaussNewton(rtol=rtol, atol=atol), True
    if key == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol), True
    if key == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol), False
    if key == "lbfgs":
        return optx.LBFGS(rtol=rtol, atol=atol), False
    if key == "nonlinear_cg":
        return optx.NonlinearCG(rtol=rtol, atol=atol), False
    if key == "gradient_descent":
        lr = 0.1 if learning_rate is None else float(learning_rate)
        return optx.GradientDescent(learning_rate=lr, rtol=rtol, atol=atol), False
    near = difflib.get_close_matches(key, SOLVERS, n=1)
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    raise ValueError(
        f"solver: unknown solver {solver!r}{hint}; expected one of {SOLVERS} or an optimistix solver instance"
    )
