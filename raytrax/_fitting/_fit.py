""":func:`fit`: inverse rendering with optimistix, in named steps.

:func:`fit` checks its arguments, chooses the solver, builds the
:class:`~._problem._Problem` (what is fitted, its bounds, the target and the
weights), checks the start, runs the solver one compiled step at a time and
assembles the :class:`FitResult`; each step is a function below.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..scene import Scene
from ..shapes import KINDS
from ._compiled import _effect, _init, _step
from ._problem import _Frozen, _is_float_array, _Problem
from ._report import _fmt, _Reporter
from ._result import FitResult
from ._robust import _blurred, _resolve_search, _start_points
from ._setup import _render_opts, _resolve_bounds, _resolve_params, _target_and_weights, _to_unconstrained
from ._solvers import _make_solver
from ._uncertainty import _uncertainty
from ._views import _resolve_views, _stack_views


def fit(
    scene: Scene,
    target,
    params: str | Sequence[str] | dict | Callable,
    *,
    solver: str | Any = "levenberg_marquardt",
    bounds: dict | None = None,
    default_bounds: bool = True,
    loss: str | Callable = "mse",
    weights=None,
    regularizer: Callable | None = None,
    max_steps: int = 100,
    rtol: float | None = None,
    atol: float | None = None,
    learning_rate: float | None = None,
    render_kwargs: dict | None = None,
    patience: int = 10,
    progress: bool | str = True,
    callback: Callable | None = None,
    check: bool = True,
    throw: bool = True,
    starts: int | None = None,
    levels: Sequence[float] | None = None,
    start_steps: int | None = None,
    noise: float | None = None,
    uncertainty: bool = True,
    cameras: Sequence | None = None,
) -> FitResult:
    """Fit parameters of ``scene`` so that its render matches ``target``.

    **Arguments**

    - ``scene``: the start (a :class:`~raytrax.Scene`).
    - ``target``: an ``(H, W, 3)`` linear image the size of the render; or, to fit
      several views of the scene at once, a list of such images (or a
      ``(V, H, W, 3)`` array), one per entry of ``cameras``.
    - ``cameras``: one camera per target: a :class:`raytrax.Camera`, a dict of
      some of its fields (``position``, ``look_at``, ``up``, ``fov``; the
      others are the scene's camera's) or ``None`` (the scene's camera).
      Without ``cameras`` a list of targets is several images of the scene's
      own view. The residuals of all views form one least-squares problem
      (every pixel of every view weighted alike unless ``weights`` say
      otherwise); the standard errors come from all views together. Every view
      is rendered at the same size (``render_kwargs``). The scene's camera
      cannot be fitted together with ``cameras``.
    - ``params``: what to fit: names of :func:`raytrax.parameters` (a string or a
      list, e.g. ``["light[0].position", "material.glass.ior"]``), a dict
      ``{name: start value}`` (``None`` keeps the scene's value), or a selector
      returning leaves of the scene pytree (``lambda s: s.lights.position`` or a
      tuple of leaves; these are then named by their path, ``"lights.position"``).
    - ``solver``: ``"levenberg_marquardt"`` (default), ``"gauss_newton"``,
      ``"dogleg"`` (least squares on the residual image), ``"bfgs"``, ``"lbfgs"``,
      ``"gradient_descent"`` (step ``learning_rate``, default 0.1 on the loss
      normalised to 1 at the start), ``"nonlinear_cg"`` (minimisers), or an
      optimistix solver instance.
    - ``bounds``: ``{name: (lo, hi)}``, ``None`` for a side without bound or for no
      bounds at all; merged over :data:`DEFAULT_BOUNDS` unless
      ``default_bounds=False``.
    - ``loss``: ``"mse"`` (weighted mean squared error), or a function
      ``loss(image, target) -> scalar`` (minimisers only).
    - ``weights``: per-pixel weights or a boolean mask, ``(H, W)``, ``(H, W, 1)``
      or ``(H, W, 3)``; with several targets, one for every view or a list of
      one per view (``None`` entries weigh a view's pixels 1).
    - ``regularizer``: ``regularizer(values) -> scalar`` added to the loss
      (``values``: the fitted parameters by name, in their bounded form), e.g. a
      smoothness prior on a texture; minimisers only. The loss history then
      holds the loss plus the regulariser.
    - ``max_steps``, ``rtol``, ``atol``: solver budget and the solver's own
      tolerances (defaults ``1e-5`` for float32 scenes, ``1e-8`` for float64;
      ``atol`` is in units of the start: parameters are the solver's
      unconstrained ones, residuals are normalised to an RMS of 1 at the start,
      the minimisers' loss to 1).
    - ``patience``: also stop (as converged, "stalled") when the loss has
      improved by less than 0.1% over this many steps: a float32 render has a
      noise floor below which no step is accepted.
    - ``render_kwargs``: options for :func:`raytrax.render` (``width``,
      ``height``, ``spp``, ``max_depth``, ``key``...).
    - ``progress``: ``True`` prints a line per step (step, loss, parameter
      values), ``"bar"`` shows a tqdm bar, ``False`` is silent.
    - ``callback``: ``callback(step, loss, values)`` called after every step.
    - ``check``: before fitting, check that every fitted number has an effect
      on the image (a non-zero derivative); raise naming those that do not
      (costs one forward-mode derivative of the render, compiled once per
      scene structure and parameter set).
    - ``throw``: raise on a non-finite loss (otherwise stop and report it in
      the result).

    Returns a :class:`FitResult`. A fit that runs out of steps warns
    (``RuntimeWarning``) and returns ``converged=False``.
    """
    t_start = time.perf_counter()
    rtol, atol = _check_arguments(scene, max_steps, progress, patience, rtol, atol)
    opt, least_squares = _make_solver(solver, rtol, atol, learning_rate)
    loss_fn = _check_loss(loss, regularizer, least_squares)
    fitted = _resolve_fitted(scene, params, bounds, default_bounds)
    n_starts, levels = _resolve_search(fitted, bounds, starts, levels)
    start_steps = _check_start_steps(start_steps, max_steps)
    if noise is not None and not (math.isfinite(float(noise)) and float(noise) > 0):
        raise ValueError(f"noise: expected a positive standard deviation, got {noise!r}")
    problem, z0 = _build_problem(scene, target, weights, render_kwargs, fitted, loss_fn, regularizer, cameras)
    if progress:
        note = _gradient_note(problem.names, render_kwargs)
        if note:
            print(note)

    # -- start: loss, finiteness, effect of each parameter ----------------
    loss0 = _start_loss(problem, z0)
    if check:
        _check_effect(problem, z0, weighted=weights is not None)
    start_values = _values_at(problem, z0)
    search = None
    if n_starts > 1 or len(levels) > 1:
        # -- the robust search: starts on the first level, the best refined on the next
        search = _search(problem, fitted, z0, opt, least_squares, n_starts, levels, start_steps, patience, progress)
        z0 = search.z
        loss0 = _start_loss(problem, z0)
    log = _Log(_Reporter(progress, max_steps, problem.names), callback)
    values0 = _values_at(problem, z0)
    log.record(0, loss0, values0)
    if loss0 == 0.0:
        msg = "the start already reproduces the target exactly (loss 0)"
        if search is not None:
            msg = f"{search.summary}; then {msg}"
        log.reporter.close(msg)
        return _assemble_result(
            problem, z0, values0, start_values, log, 0, True, optx.RESULTS.successful, msg, opt, t_start,
            search=search, extra=_extra(problem, z0, uncertainty, noise),
        )  # fmt: skip
    problem_n = _normalise(problem, loss0, least_squares)

    # -- iterate ------------------------------------------------------------
    run = _run_solver(problem_n, opt, z0, least_squares, loss0, values0, log, max_steps, patience)
    msg, result = _ending(run, max_steps, patience, log.values[-1])
    if run.nonfinite and throw:
        log.reporter.close("stopped: non-finite values")
        raise FloatingPointError(msg)
    if search is not None:
        msg = f"{search.summary}; then {msg}"
    _report_end(log.reporter, run, msg, loss0)
    return _assemble_result(
        problem, run.best_z, run.best_values, start_values, log, run.steps, run.converged, result, msg, opt, t_start,
        search=search, extra=_extra(problem, run.best_z, uncertainty, noise),
    )  # fmt: skip


# ---------------------------------------------------------------------------
# The steps of fit, in order
# ---------------------------------------------------------------------------
# Parameters whose change moves an edge in the image (a silhouette, a shadow
# boundary, what is seen through glass): geometry, the camera, light positions
# and directions, refractive indices; by name (``object[0].center``) or by
# selector path (``spheres.center``). Colours and intensities do not.
_MOVES_EDGES = re.compile(
    r"^(camera\.|object\[|\w*lights?(\[\d+\])?\.(position|direction)$|material\.[^.]+\.ior$|materials\.ior$)"
)


def _moves_edges(name: str) -> bool:
    return bool(_MOVES_EDGES.match(name)) or name.split(".")[0] in {k.field for k in KINDS}


def _gradient_note(names, render_kwargs) -> str | None:
    """One line on which gradient the fit uses when fitted parameters move edges
    and the caller did not choose (``render_kwargs["edge_gradients"]``)."""
    if render_kwargs and "edge_gradients" in render_kwargs:
        return None
    moving = [nm for nm in names if _moves_edges(nm)]
    if not moving:
        return None
    return (
        f"rt.fit: plain AD gradients; the edges that {', '.join(moving)} move are not in the derivative "
        "(the default search compares losses, so it still finds the basin). "
        "render_kwargs=dict(edge_gradients=True) adds them at several times the cost (docs/gradients.md)."
    )


def _check_arguments(scene, max_steps, progress, patience, rtol, atol):
    """Check the scene and the plain options; -> the solver's ``(rtol, atol)``
    (defaults ``1e-5`` for a float32 scene, ``1e-8`` for float64)."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a raytrax.Scene, got {type(scene).__name__}")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps: expected a positive integer, got {max_steps!r}")
    if progress not in (True, False, "bar", "lines", None):
        raise ValueError(f"progress: expected True, False or 'bar', got {progress!r}")
    f64 = jnp.dtype(scene.dtype) == jnp.dtype(jnp.float64)
    rtol = (1e-8 if f64 else 1e-5) if rtol is None else float(rtol)
    atol = (1e-8 if f64 else 1e-5) if atol is None else float(atol)
    if not isinstance(patience, int) or patience < 1:
        raise ValueError(f"patience: expected a positive integer, got {patience!r}")
    return rtol, atol


def _check_loss(loss, regularizer, least_squares):
    """Check ``loss`` and ``regularizer`` against the kind of solver; -> the custom
    loss function, or ``None`` for the weighted MSE."""
    if loss == "mse":
        loss_fn = None
    elif callable(loss):
        if least_squares:
            raise ValueError(
                "loss: a custom loss function needs a minimiser (solver='bfgs', "
                "'gradient_descent' or 'nonlinear_cg'); least squares fit the residual image "
                "(loss='mse' with weights)"
            )
        loss_fn = loss
    else:
        raise ValueError(f"loss: expected 'mse' or a function loss(image, target) -> scalar, got {loss!r}")
    if regularizer is not None:
        if not callable(regularizer):
            raise TypeError(f"regularizer: expected a function values -> scalar, got {regularizer!r}")
        if least_squares:
            raise ValueError(
                "regularizer: a regularised loss needs a minimiser (solver='bfgs', 'lbfgs', "
                "'gradient_descent' or 'nonlinear_cg')"
            )
    return loss_fn


class _Fitted(NamedTuple):
    """What is fitted: names, start values (name -> array) and bounds."""

    names: tuple
    starts: dict
    by_path: bool  # names are pytree paths (a selector), not raytrax.parameters names
    lo: dict
    hi: dict
    maps: tuple  # per name: "none" | "lower" | "upper" | "both"


def _resolve_fitted(scene, params, bounds, default_bounds):
    """Resolve ``params`` (names, a dict of start values or a selector) and the bounds
    (``bounds`` over :data:`DEFAULT_BOUNDS`) into a :class:`_Fitted`."""
    names, starts, by_path = _resolve_params(scene, params)
    lo, hi, maps = _resolve_bounds(names, starts, bounds, default_bounds)
    return _Fitted(names, starts, by_path, lo, hi, maps)


def _build_problem(scene, target, weights, render_kwargs, fitted, loss_fn, regularizer, cameras=None):
    """Gather the scene, the checked target(s), weights and cameras, the render options
    and the fitted parameters into a :class:`_Problem` (loss scale 1 for now); ->
    (problem, the solver's unconstrained start point ``z0``)."""
    dtype = scene.dtype
    names = fitted.names
    targets, cams, ws = _resolve_views(scene, target, cameras, weights, names)
    render_opts, key, shape = _render_opts(scene, render_kwargs)
    if cams is None:
        target_a, weights_a = _target_and_weights(targets[0], ws[0], shape, dtype)
    else:
        t, w = _stack_views(targets, ws, shape)
        target_a, weights_a = jnp.asarray(t, dtype), jnp.asarray(w, dtype)
    # The solver works in float64 when JAX allows it (x64 on), whatever the
    # scene's dtype: quasi-Newton updates in float32 stall near the optimum.
    sdt = jnp.dtype(jnp.float64) if jax.config.read("jax_enable_x64") else jnp.dtype(dtype)
    z0 = {
        n: jnp.asarray(_to_unconstrained(fitted.starts[n], fitted.lo[n], fitted.hi[n], k), sdt)
        for n, k in zip(names, fitted.maps)
    }
    floats, ints = eqx.partition(scene, _is_float_array)
    problem = _Problem(
        floats=floats,
        ints=_Frozen(ints),
        target=target_a,
        weights=weights_a,
        scale=jnp.asarray(1.0, sdt),
        lo={n: v.astype(sdt) for n, v in fitted.lo.items()},
        hi={n: v.astype(sdt) for n, v in fitted.hi.items()},
        key=key,
        names=names,
        dtypes=tuple(str(fitted.starts[n].dtype) for n in names),
        maps=fitted.maps,
        by_path=fitted.by_path,
        render_opts=render_opts,
        loss_fn=loss_fn,
        reg_fn=regularizer,
        cameras=None if cams is None else tuple(cams),
    )
    return problem, z0


def _start_loss(problem, z0):
    """The loss at the start; raise if the start's render or loss is not finite."""
    # The start's image outside jit: the render is compiled once per scene
    # structure, so this reuses the compilation that rendered the target.
    img0 = problem.image(z0)
    loss0 = float(problem.total_loss(img0, z0))
    if not bool(np.isfinite(np.asarray(img0)).all()):
        raise FloatingPointError(
            "the render at the start contains non-finite values (nan or inf); check the start parameters"
        )
    if not math.isfinite(loss0):
        raise FloatingPointError(f"the loss at the start is not finite ({loss0})")
    return loss0


def _check_effect(problem, z0, weighted):
    """Check that every fitted number has an effect on the image at the start:
    raise naming the parameters with none, warn about single components with none."""
    rng = np.random.default_rng(0)
    probe = {n: jnp.asarray(rng.uniform(0.5, 1.5, z0[n].shape), problem.scale.dtype) for n in problem.names}
    g = _effect(problem, z0, probe)
    dead, part = [], []
    for n in problem.names:
        gz = np.asarray(g[n])
        zero = gz == 0
        if zero.all():
            dead.append(n)
        elif zero.any():
            part.extend(f"{n}[{', '.join(map(str, i))}]" for i in zip(*np.nonzero(zero)))
    if dead:
        raise ValueError(
            f"parameter(s) {', '.join(dead)} have no effect on the rendered image at the start "
            f"(their derivative is zero at every{' weighted' if weighted else ''} pixel), "
            "so they cannot be fitted: e.g. a light that lights nothing the camera sees, a material "
            "no visible object uses, or an effect only through hard edges (silhouettes, shadow "
            "boundaries carry no gradient). Move the start, or leave them out of params."
        )
    if part:
        warnings.warn(
            f"fit: component(s) {', '.join(part)} have no effect on the image at the start "
            "(zero derivative); they will stay where they are",
            RuntimeWarning,
            stacklevel=3,  # fit's caller
        )


def _values_at(problem, z):
    """The fitted parameters' values at ``z``, by name, as NumPy arrays in the scene's dtype."""
    v = problem.scene_values(z)
    return {n: np.asarray(v[n]) for n in problem.names}


@dataclasses.dataclass
class _Log:
    """The loss and parameter histories (``[start, after step 1, ...]``), reported
    and passed to the user's callback as they grow."""

    reporter: _Reporter
    callback: Callable | None
    losses: list = dataclasses.field(default_factory=list)
    values: list = dataclasses.field(default_factory=list)

    def record(self, step, loss, values):
        self.losses.append(loss)
        self.values.append(values)
        self.reporter(step, loss, values)
        if self.callback is not None:
            self.callback(step, loss, values)


def _normalise(problem, loss0, least_squares):
    """Scale the solver's function to size 1 at the start, so that its tolerances are
    relative: least squares get residuals of RMS 1, minimisers a loss of 1."""
    n_eff = float(np.count_nonzero(np.asarray(problem.weights))) if least_squares else 1.0
    return eqx.tree_at(lambda p: p.scale, problem, jnp.asarray(n_eff / loss0, problem.scale.dtype))


@dataclasses.dataclass
class _Run:
    """How the solver loop went: steps taken, how it stopped, the best point."""

    steps: int
    converged: bool
    interrupted: bool
    nonfinite: bool
    stalled: bool
    result: Any  # the optimistix result of the last step
    best_loss: float
    best_z: dict
    best_values: dict


def _run_solver(problem, opt, z0, least_squares, loss0, start_values, log, max_steps, patience):
    """Run the solver from ``z0`` one compiled step at a time, recording every step in
    ``log`` and keeping the best point; stop when the solver terminates or fails, when
    the loss stalls (``patience``), goes non-finite, or on Ctrl-C."""
    run = _Run(
        steps=0,
        converged=False,
        interrupted=False,
        nonfinite=False,
        stalled=False,
        result=optx.RESULTS.successful,
        best_loss=loss0,
        best_z=z0,
        best_values=start_values,
    )
    z = z0
    dyn = _init(problem, opt, z, least_squares)
    best_at = [loss0]  # best loss after each step
    try:
        for steps in range(1, max_steps + 1):
            run.steps = steps
            z_new, dyn, done, result, cur, finite, vals = _step(problem, opt, z, dyn, least_squares)
            run.result = result
            cur = float(cur)
            if not bool(finite):
                run.nonfinite = True
                break
            z = z_new
            vals = {n: np.asarray(vals[n]) for n in problem.names}
            if cur <= run.best_loss:
                run.best_loss, run.best_z, run.best_values = cur, z, vals
            log.record(steps, cur, vals)
            best_at.append(run.best_loss)
            if bool(done) or result != optx.RESULTS.successful:
                run.converged = bool(done) and result == optx.RESULTS.successful
                break
            if steps >= patience and best_at[-1] > (1.0 - 1e-3) * best_at[-1 - patience]:
                run.stalled = run.converged = True
                break
    except KeyboardInterrupt:
        run.interrupted = True
    return run


def _ending(run, max_steps, patience, last_values):
    """-> (the sentence saying how the fit ended, the optimistix result to report)."""
    steps, result = run.steps, run.result
    if run.nonfinite:
        msg = (
            f"the loss or the parameters became non-finite (nan or inf) at step {steps}; last finite "
            f"values: "
            + ", ".join(f"{n}={_fmt(v)}" for n, v in last_values.items())
            + ". Try bounds, a closer start or another solver"
        )
        return msg, optx.RESULTS.nonfinite
    if run.interrupted:
        return f"interrupted after {steps - 1} steps; returning the best point so far", result
    if run.stalled:
        return (
            f"converged in {steps} steps (stalled: the loss improved by less than 0.1% in the last {patience} steps)",
            result,
        )
    if run.converged:
        return f"converged in {steps} steps", result
    if result != optx.RESULTS.successful:
        return f"the solver stopped at step {steps}: {optx.RESULTS[result]}", result
    return f"did not converge within max_steps={max_steps} steps", optx.RESULTS.nonlinear_max_steps_reached


def _report_end(reporter, run, msg, loss0):
    """Close the progress report; warn (``RuntimeWarning``) if the fit did not converge
    and was not interrupted."""
    reporter.close(f"{msg}; loss {loss0:.4g} -> {run.best_loss:.4g}")
    if not run.converged and not run.interrupted:
        warnings.warn(
            f"fit: {msg} (loss {loss0:.4g} -> {run.best_loss:.4g}); the result may be inaccurate: "
            "raise max_steps, loosen rtol/atol, or check the problem",
            RuntimeWarning,
            stacklevel=3,  # fit's caller
        )


def _assemble_result(
    problem, z, values, start_values, log, steps, converged, result, msg, opt, t_start, search=None, extra=None
):
    """The :class:`FitResult` for the point ``z`` (its parameter ``values``)."""
    unc = extra
    return FitResult(
        scene=problem.scene_at(z),
        params=values,
        initial_params=start_values,
        loss_history=np.asarray(log.losses),
        param_history=log.values,
        steps=steps,
        converged=converged,
        result=result,
        message=msg,
        solver=opt,
        seconds=time.perf_counter() - t_start,
        stderr=None if unc is None else unc.stderr,
        covariance=None if unc is None else unc.covariance,
        covariance_labels=() if unc is None else unc.labels,
        noise=None if unc is None else unc.noise,
        undetermined=[] if unc is None else unc.undetermined,
        starts=[] if search is None else search.starts,
        levels=[] if search is None else search.levels,
    )


# ---------------------------------------------------------------------------
# The robust search and the uncertainty
# ---------------------------------------------------------------------------
def _check_start_steps(start_steps, max_steps):
    """-> the budget of each start's local fit (default ``min(max_steps, 15)``)."""
    if start_steps is None:
        return min(max_steps, 15)
    if isinstance(start_steps, bool) or not isinstance(start_steps, int) or start_steps < 1:
        raise ValueError(f"start_steps: expected a positive integer, got {start_steps!r}")
    return start_steps


@dataclasses.dataclass
class _Search:
    """What the robust search found: the point the final fit starts from, and records."""

    z: dict
    starts: list  # per start: dict(start=, params=, loss=, steps=, converged=)
    levels: list  # per level before the last: dict(level=, start=, params=, loss=, steps=)
    summary: str


def _local(problem, z, opt, least_squares, max_steps, patience):
    """A quiet local fit of ``problem`` from ``z``: -> (run, loss at the start) or
    ``(None, inf)`` when the start's loss is not finite. Losses are ``problem``'s own
    (blurred on a blurred level)."""
    try:
        loss0 = _start_loss(problem, z)
    except FloatingPointError:
        return None, math.inf
    log = _Log(_Reporter(False, max_steps, problem.names), None)
    values0 = _values_at(problem, z)
    log.record(0, loss0, values0)
    if loss0 == 0.0:
        return _Run(0, True, False, False, False, optx.RESULTS.successful, 0.0, z, values0), loss0
    run = _run_solver(
        _normalise(problem, loss0, least_squares), opt, z, least_squares, loss0, values0, log, max_steps, patience
    )
    return run, loss0


def _search(problem, fitted, z_given, opt, least_squares, n_starts, levels, start_steps, patience, progress):
    """Local fits of ``start_steps`` steps from ``n_starts`` points (the given start and
    points spread over the bounds) on the first blur level; the lowest loss is kept
    and refined on each later level but the last (which :func:`fit` runs)."""
    say = print if progress else (lambda *a, **k: None)
    sdt = z_given[problem.names[0]].dtype
    points = _start_points(fitted, n_starts)
    zs = [z_given] + [
        {
            n: jnp.asarray(_to_unconstrained(pt[n], fitted.lo[n], fitted.hi[n], k), sdt)
            for n, k in zip(problem.names, fitted.maps)
        }
        for pt in points[1:]
    ]
    first = _blurred(problem, levels[0])
    records, ends = [], []
    for i, z in enumerate(zs):
        run, l0 = _local(first, z, opt, least_squares, start_steps, patience)
        start = _values_at(problem, z)
        if run is None:
            records.append(dict(start=start, params=start, loss=math.inf, steps=0, converged=False))
            ends.append(z)
        else:
            records.append(
                dict(start=start, params=run.best_values, loss=run.best_loss, steps=run.steps, converged=run.converged)
            )
            ends.append(run.best_z)
        r = records[-1]
        vals = "  ".join(f"{n}={_fmt(r['start'][n])}->{_fmt(r['params'][n])}" for n in problem.names)
        say(f"start {i:2d}  level {levels[0]:g}  {r['steps']:3d} steps  loss {r['loss']:.4g}  {vals}", flush=True)
    best = int(np.argmin([r["loss"] for r in records]))
    z = ends[best]
    level_records = []
    for lv in levels[1:-1]:  # the last level is fit's final run
        run, l0 = _local(_blurred(problem, lv), z, opt, least_squares, start_steps, patience)
        if run is None:
            break
        level_records.append(
            dict(level=lv, start=_values_at(problem, z), params=run.best_values, loss=run.best_loss, steps=run.steps)
        )
        say(f"level {lv:g}  {run.steps:3d} steps  loss {l0:.4g} -> {run.best_loss:.4g}", flush=True)
        z = run.best_z
    summary = f"best of {n_starts} start{'s' if n_starts > 1 else ''} (start {best}"
    summary += f", on images blurred by {levels[0]:g} x width)" if levels[0] > 0 else ")"
    return _Search(z, records, level_records, summary)


def _extra(problem, z, uncertainty, noise):
    """The standard errors at ``z`` (``None`` when not asked for, for a custom loss or
    a regulariser, or too many fitted numbers); warns about undetermined directions."""
    if not uncertainty or problem.loss_fn is not None or problem.reg_fn is not None:
        return None
    unc = _uncertainty(problem, z, noise)
    if unc is not None and unc.undetermined:
        groups = "; ".join(" and ".join(g) for g in unc.undetermined)
        warnings.warn(
            f"fit: the image does not determine every direction of the parameters (J^T J is near-singular): "
            f"{groups} trade off against each other (or have no effect), so their standard errors are inf; "
            "fix one of them, or add a view that separates them",
            RuntimeWarning,
            stacklevel=3,  # fit's caller
        )
    return unc
