"""Inverse rendering: fit scene parameters to a target image with optimistix.

:func:`fit` renders the scene with the parameters being fitted replaced by the
solver's current guess and compares the image with a target:

* least squares (``"levenberg_marquardt"``, ``"gauss_newton"``, ``"dogleg"``, or
  any :class:`optimistix.AbstractLeastSquaresSolver`) work on the residual image
  ``sqrt(w) * (render - target)`` with forward-mode Jacobians (one JVP per fitted
  number, so they suit a handful of parameters);
* scalar minimisers (``"bfgs"``, ``"gradient_descent"``, ``"nonlinear_cg"``, or
  any :class:`optimistix.AbstractMinimiser`) minimise the loss with reverse-mode
  gradients (one VJP whatever the number of parameters, e.g. a whole texture).

The loss is the weighted mean squared error on linear images,
``sum(w * (render - target)^2) / sum(w)`` (``w = 1`` by default, or per-pixel
weights / a boolean mask). Internally it is divided by its value at the start,
so the solver's tolerances are relative and a minimiser's first step has a
sensible size; the reported losses are the true ones.

The solver is run one step at a time from Python (its ``init`` / ``step`` /
``terminate`` methods, each step one compiled call), so every step is reported
(a line per step or a progress bar) and recorded in the loss history, and a fit
can be interrupted with Ctrl-C (the best point so far is returned). Compiled
steps are cached: fitting the same parameters of scenes of the same structure
again (new values, new target) does not recompile.

Bounds are handled by reparameterisation: a parameter with a lower bound is
``lo + softplus(z)``, with an upper bound ``hi - softplus(z)``, with both
``lo + (hi - lo) sigmoid(z)``; the solver works on the unconstrained ``z``. By
default the refractive index is kept ``>= 1``, intensities, radii, sizes and
shininess ``>= 0``, transparency in ``[0, 1]`` and the field of view in
``(0, 180)``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .integrator import render
from .scene import Scene

__all__ = ["fit", "FitResult", "SOLVERS", "DEFAULT_BOUNDS"]

LEAST_SQUARES = ("levenberg_marquardt", "gauss_newton", "dogleg")
MINIMISERS = ("bfgs", "lbfgs", "gradient_descent", "nonlinear_cg")
SOLVERS = LEAST_SQUARES + MINIMISERS

#: Bounds applied by default, by the last component of a parameter's name.
DEFAULT_BOUNDS = {
    "ior": (1.0, None),
    "intensity": (0.0, None),
    "transparency": (0.0, 1.0),
    "radius": (0.0, None),
    "size": (0.0, None),
    "shininess": (0.0, None),
    "fov": (0.0, 180.0),
}

_RENDER_KEYS = (
    "width",
    "height",
    "spp",
    "max_depth",
    "filter_textures",
    "branches",
    "tile_rays",
    "devices",
    "key",
    "edge_gradients",
    "edge_budget",
)
_TAGS = frozenset()
_JACFWD_MAX = 32  # fitted numbers up to which the start check resolves single components


# ---------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------
@dataclasses.dataclass
class FitResult:
    """What :func:`fit` returns.

    - ``scene``: the scene with the fitted values put in.
    - ``params``: fitted values by name (numpy arrays); ``initial_params``: the start.
    - ``loss_history``: the loss (weighted MSE) at the solver's current point,
      ``[start, after step 1, after step 2, ...]``; ``param_history``: the
      parameter values at the same points.
    - ``steps``: solver steps taken; ``converged``: whether the solver's own
      termination test was met; ``result``: the :class:`optimistix.RESULTS`
      item; ``message``: a sentence saying how the fit ended.
    - ``solver``: the optimistix solver used; ``seconds``: wall time of the fit
      (compilation included).
    """

    scene: Scene
    params: dict
    initial_params: dict
    loss_history: np.ndarray
    param_history: list
    steps: int
    converged: bool
    result: Any
    message: str
    solver: Any
    seconds: float

    @property
    def loss(self) -> float:
        """The final loss."""
        return float(self.loss_history[-1])

    def __str__(self):
        vals = "\n".join(f"  {n} = {_fmt(v)}" for n, v in self.params.items())
        return (
            f"FitResult({self.message}; {self.steps} steps, loss {self.loss_history[0]:.4g} -> "
            f"{self.loss:.4g}, {self.seconds:.1f} s)\n{vals}"
        )


class _Frozen:
    """A hashable pytree of (integer) NumPy arrays, kept static under ``jit``.

    The scene's integer leaves (material ids, texture kinds) are passed this
    way so that they stay concrete inside compiled steps (the renderer and
    :func:`raytrax.with_parameters` read them) while the float leaves are
    traced; equal contents hit the same compiled step.
    """

    def __init__(self, tree):
        self.tree = jax.tree_util.tree_map(np.asarray, tree)
        leaves, treedef = jax.tree_util.tree_flatten(self.tree)
        self._key = (treedef, tuple((a.shape, a.dtype.str, a.tobytes()) for a in leaves))
        self._hash = hash(self._key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, _Frozen) and self._hash == other._hash and self._key == other._key


def _is_float_array(x):
    return eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.inexact)


# ---------------------------------------------------------------------------
# The problem: a pytree (arrays are traced, the rest is static), so compiled
# steps are reused across fits of the same structure.
# ---------------------------------------------------------------------------
class _Problem(eqx.Module):
    floats: Scene  # the scene's float leaves (None elsewhere)
    ints: _Frozen = eqx.field(static=True)  # and the rest
    target: jax.Array  # (H, W, 3)
    weights: jax.Array  # (H, W, 3), sums to 1
    scale: jax.Array  # () 1 / loss at the start
    lo: dict  # name -> array (finite where the parameter has a lower bound)
    hi: dict
    key: jax.Array | None
    names: tuple = eqx.field(static=True)
    dtypes: tuple = eqx.field(static=True)  # the scene's dtype of each fitted parameter
    maps: tuple = eqx.field(static=True)  # per name: "none" | "lower" | "upper" | "both"
    by_path: bool = eqx.field(static=True)  # names are pytree paths (selector), not raytrax.parameters names
    render_opts: tuple = eqx.field(static=True)
    loss_fn: Callable | None = eqx.field(static=True)
    reg_fn: Callable | None = eqx.field(static=True, default=None)

    # z (unconstrained) -> parameter values
    def values(self, z):
        out = {}
        for name, kind in zip(self.names, self.maps):
            x = z[name]
            if kind == "lower":
                x = self.lo[name] + jax.nn.softplus(x)
            elif kind == "upper":
                x = self.hi[name] - jax.nn.softplus(x)
            elif kind == "both":
                x = self.lo[name] + (self.hi[name] - self.lo[name]) * jax.nn.sigmoid(x)
            out[name] = x
        return out

    def scene_values(self, z):
        """The parameter values at ``z`` in the scene's dtype (what goes into the scene)."""
        v = self.values(z)
        return {n: v[n].astype(dt) for n, dt in zip(self.names, self.dtypes)}

    def scene_at(self, z):
        vals = self.scene_values(z)
        # Integer leaves as NumPy while the values are written (raytrax.with_parameters
        # reads the texture kinds), then as JAX arrays for the renderer.
        scene = _set_values(eqx.combine(self.floats, self.ints.tree), vals, self.by_path)
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x) if isinstance(x, np.ndarray) else x, scene)

    def image(self, z):
        kw = dict(self.render_opts)
        return render(self.scene_at(z), key=self.key, **kw)

    def raw_loss(self, img):
        if self.loss_fn is not None:
            return self.loss_fn(img, self.target)
        d = img - self.target
        return jnp.sum(self.weights * d * d)

    # optimistix-facing functions: fn(y, args) -> (out, aux)
    def residual(self, z, args):
        d = self.image(z) - self.target
        r = (jnp.sqrt(self.weights) * d).reshape(-1).astype(self.scale.dtype)
        return jnp.sqrt(self.scale) * r, None

    def total_loss(self, img, z):
        out = self.raw_loss(img).astype(self.scale.dtype)
        if self.reg_fn is not None:
            out = out + jnp.asarray(self.reg_fn(self.values(z))).astype(self.scale.dtype)
        return out

    def objective(self, z, args):
        return self.scale * self.total_loss(self.image(z), z), None


def _set_values(scene, values, by_path):
    if not by_path:
        from .params import with_parameters

        return with_parameters(scene, values)
    flat, treedef = jax.tree_util.tree_flatten_with_path(scene)
    leaves = []
    for path, leaf in flat:
        name = _path_name(path)
        leaves.append(values[name].astype(leaf.dtype) if name in values else leaf)
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _path_name(path):
    return jax.tree_util.keystr(path).lstrip(".")


# ---------------------------------------------------------------------------
# Compiled pieces (module level, so their caches outlive one fit)
# ---------------------------------------------------------------------------
@eqx.filter_jit
def _effect(problem: _Problem, z, probe):
    """For each fitted name, the sum over the (weighted) image of
    ``|d image / d z|``: per component (forward-mode Jacobian) when there are
    few, else along one random direction per name. Zero means no effect."""
    w = problem.weights
    size = sum(int(np.prod(v.shape)) for v in z.values())
    if size <= _JACFWD_MAX:
        J = jax.jacfwd(problem.image)(z)
        return {n: jnp.sum(jnp.abs(j) * w.reshape(w.shape + (1,) * (j.ndim - 3)), axis=(0, 1, 2)) for n, j in J.items()}
    names = list(z)

    def along(i):
        t = {n: jnp.where(k == i, probe[n], jnp.zeros_like(probe[n])) for k, n in enumerate(names)}
        return jnp.sum(jnp.abs(jax.jvp(problem.image, (z,), (t,))[1]) * w)

    per = jax.vmap(along)(jnp.arange(len(names)))
    return {n: per[k] for k, n in enumerate(names)}


def _fn(problem, least_squares):
    return problem.residual if least_squares else problem.objective


def _solver_init(problem, solver, z, least_squares):
    fn = _fn(problem, least_squares)
    f_struct, aux_struct = jax.eval_shape(fn, z, None)
    return solver.init(fn, z, None, {}, f_struct, aux_struct, _TAGS)


@eqx.filter_jit
def _init(problem, solver, z, least_squares):
    return eqx.filter(_solver_init(problem, solver, z, least_squares), eqx.is_array)


@eqx.filter_jit
def _step(problem, solver, z, dyn_state, least_squares):
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


# ---------------------------------------------------------------------------
# Setting up
# ---------------------------------------------------------------------------
def _make_solver(solver, rtol, atol, learning_rate):
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


def _resolve_params(scene, params):
    """-> (names, start values dict name -> array, by_path)."""
    starts_override = {}
    if isinstance(params, str):
        params = [params]
    if isinstance(params, dict):
        starts_override = dict(params)
        params = list(params)
    if callable(params) and not isinstance(params, (list, tuple)):
        return _resolve_selector(scene, params)
    params = list(params)
    if not params:
        raise ValueError("params: nothing to fit (empty list)")
    if not all(isinstance(p, str) for p in params):
        raise TypeError(
            f"params: expected parameter names (str), a dict of name -> start value, or a "
            f"selector function (lambda s: s.lights.position), got {params!r}"
        )
    if len(set(params)) != len(params):
        raise ValueError(f"params: a name is given twice in {params}")
    from .params import parameters

    available = parameters(scene)
    for p in params:
        if p not in available:
            near = difflib.get_close_matches(p, list(available), n=3)
            hint = f"; did you mean {' or '.join(repr(n) for n in near)}?" if near else ""
            raise ValueError(
                f"params: unknown parameter {p!r}{hint} (raytrax.parameters(scene) lists the "
                f"{len(available)} names this scene has)"
            )
    starts = {}
    for p in params:
        cur = jnp.asarray(available[p])
        if p in starts_override and starts_override[p] is not None:
            v = np.asarray(starts_override[p], dtype=np.float64)
            if v.shape != cur.shape and v.size != 1:
                raise ValueError(f"params[{p!r}]: start value of shape {v.shape}, expected {cur.shape}")
            cur = jnp.asarray(np.broadcast_to(v, cur.shape), cur.dtype)
        starts[p] = cur
    return tuple(params), starts, False


def _resolve_selector(scene, selector):
    try:
        sel = selector(scene)
    except Exception as e:  # noqa: BLE001
        raise ValueError(f"params: the selector raised {type(e).__name__}: {e}") from e
    items = list(sel) if isinstance(sel, (list, tuple)) else [sel]
    flat, _ = jax.tree_util.tree_flatten_with_path(scene)
    by_id = {id(leaf): _path_name(path) for path, leaf in flat}
    names, starts = [], {}
    for it in items:
        if id(it) not in by_id:
            raise ValueError(
                "params: a selector must return whole array leaves of the scene "
                "(e.g. lambda s: s.lights.position or (s.lights.position, s.materials.ior)); "
                "to fit one row use names such as 'light[0].position'"
            )
        name = by_id[id(it)]
        if not jnp.issubdtype(it.dtype, jnp.floating):
            raise ValueError(f"params: {name} is an integer leaf ({it.dtype}); only float leaves can be fitted")
        if name in starts:
            raise ValueError(f"params: {name} selected twice")
        names.append(name)
        starts[name] = it
    if not names:
        raise ValueError("params: the selector selected nothing")
    return tuple(names), starts, True


def _resolve_bounds(names, starts, bounds, default_bounds):
    bounds = dict(bounds or {})
    for b in bounds:
        if b not in names:
            raise ValueError(f"bounds: {b!r} is not one of the fitted parameters {list(names)}")
    lo, hi, maps = {}, {}, []
    for n in names:
        shape, dt = starts[n].shape, starts[n].dtype
        leaf = n.rsplit(".", 1)[-1]
        b = bounds[n] if n in bounds else (DEFAULT_BOUNDS.get(leaf) if default_bounds else None)
        if b is None:
            b = (None, None)
        if not (isinstance(b, (tuple, list)) and len(b) == 2):
            raise ValueError(f"bounds[{n!r}]: expected (lo, hi) with None for no bound, got {b!r}")
        l = np.broadcast_to(np.asarray(-np.inf if b[0] is None else b[0], np.float64), shape)
        h = np.broadcast_to(np.asarray(np.inf if b[1] is None else b[1], np.float64), shape)
        if np.any(h <= l):
            raise ValueError(f"bounds[{n!r}]: expected lo < hi, got {b!r}")
        fl, fh = np.isfinite(l), np.isfinite(h)
        if not (fl.all() or (~fl).all()) or not (fh.all() or (~fh).all()):
            raise ValueError(f"bounds[{n!r}]: give every component a bound or none (got {b!r})")
        kind = {(False, False): "none", (True, False): "lower", (False, True): "upper", (True, True): "both"}[
            (bool(fl.all()), bool(fh.all()))
        ]
        x0 = np.asarray(starts[n], np.float64)
        if np.any(x0 < l) or np.any(x0 > h):
            raise ValueError(
                f"params: the start value of {n} = {_fmt(x0)} is outside its bounds "
                f"[{_fmt(l)}, {_fmt(h)}]; pass a start inside them (params={{name: value}}) or "
                f"other bounds (bounds={{{n!r}: (lo, hi)}} or None)"
            )
        maps.append(kind)
        lo[n] = jnp.asarray(np.where(fl, l, 0.0), dt)
        hi[n] = jnp.asarray(np.where(fh, h, 0.0), dt)
    return lo, hi, tuple(maps)


def _to_unconstrained(x0, lo, hi, kind):
    x0 = np.asarray(x0, np.float64)
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    if kind == "none":
        return x0
    if kind == "both":
        w = hi - lo
        t = np.clip((x0 - lo) / w, 1e-4, 1 - 1e-4)  # a start on a bound is moved just inside
        return np.log(t) - np.log1p(-t)
    d = x0 - lo if kind == "lower" else hi - x0
    d = np.maximum(d, 1e-4 * np.maximum(1.0, np.abs(lo if kind == "lower" else hi)))
    return d + np.log(-np.expm1(-d))  # inverse softplus


def _fmt(v, n=6):
    a = np.asarray(v)
    if a.size > n:
        return f"<{a.shape} array, mean {a.mean():.4g}>"
    if a.ndim == 0:
        return f"{float(a):.5g}"
    return "[" + " ".join(f"{float(x):.4g}" for x in a.ravel()) + "]"


def _render_opts(scene, render_kwargs):
    kw = dict(render_kwargs or {})
    for k in kw:
        if k not in _RENDER_KEYS:
            raise TypeError(f"render_kwargs: unknown key {k!r}; expected some of {_RENDER_KEYS}")
    key = kw.pop("key", None)
    kw = {k: v for k, v in kw.items() if v is not None}
    h = kw.get("height", scene.settings.height)
    w = kw.get("width", scene.settings.width)
    return tuple(sorted(kw.items())), key, (h, w, 3)


def _target_and_weights(target, weights, shape, dtype):
    t = np.asarray(target)
    if t.shape != shape:
        hint = ""
        if t.ndim == 3 and t.shape[2] == 3:
            hint = (
                f"; render the target at the scene's size or pass "
                f"render_kwargs=dict(width={t.shape[1]}, height={t.shape[0]})"
            )
        raise ValueError(
            f"target: shape {t.shape} does not match the rendered image's shape {shape} (height, width, 3){hint}"
        )
    if not np.all(np.isfinite(t)):
        raise ValueError(f"target: contains {int(np.sum(~np.isfinite(t)))} non-finite values (nan or inf)")
    if weights is None:
        w = np.ones(shape, np.float64)
    else:
        w = np.asarray(weights)
        w = w.astype(np.float64)
        if w.shape == shape[:2]:
            w = w[:, :, None]
        try:
            w = np.broadcast_to(w, shape)
        except ValueError:
            raise ValueError(
                f"weights: shape {np.shape(weights)} does not fit the image's shape {shape}; "
                f"expected (H, W), (H, W, 1) or (H, W, 3)"
            ) from None
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError("weights: expected finite, non-negative weights")
        if not np.any(w > 0):
            raise ValueError("weights: every weight is zero (an empty mask): nothing to fit")
    w = w / w.sum()
    return jnp.asarray(t, dtype), jnp.asarray(w, dtype)


# ---------------------------------------------------------------------------
# Progress reporting
# ---------------------------------------------------------------------------
class _Reporter:
    def __init__(self, progress, max_steps, names, stream=None):
        self.mode = progress
        self.bar = None
        self.stream = stream or sys.stdout
        if progress == "bar":
            from tqdm.auto import tqdm

            self.bar = tqdm(total=max_steps, desc="fit", unit="step", leave=True)

    def __call__(self, step, loss, values, extra=""):
        if not self.mode:
            return
        if self.bar is not None:
            if step > 0:
                self.bar.update(1)
            self.bar.set_postfix_str(f"loss={loss:.4g}")
            return
        vals = "  ".join(f"{n}={_fmt(v)}" for n, v in values.items())
        print(f"step {step:4d}  loss {loss:.6g}  {vals}{extra}", file=self.stream, flush=True)

    def close(self, message):
        if self.bar is not None:
            self.bar.close()
        if self.mode:
            print(f"fit: {message}", file=self.stream, flush=True)


# ---------------------------------------------------------------------------
# fit
# ---------------------------------------------------------------------------
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
) -> FitResult:
    """Fit parameters of ``scene`` so that its render matches ``target``.

    **Arguments**

    - ``scene``: the start (a :class:`~raytrax.Scene`).
    - ``target``: an ``(H, W, 3)`` linear image the size of the render.
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
      or ``(H, W, 3)``.
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
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a raytrax.Scene, got {type(scene).__name__}")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps: expected a positive integer, got {max_steps!r}")
    if progress not in (True, False, "bar", "lines", None):
        raise ValueError(f"progress: expected True, False or 'bar', got {progress!r}")
    dtype = scene.dtype
    f64 = jnp.dtype(dtype) == jnp.dtype(jnp.float64)
    rtol = (1e-8 if f64 else 1e-5) if rtol is None else float(rtol)
    atol = (1e-8 if f64 else 1e-5) if atol is None else float(atol)
    if not isinstance(patience, int) or patience < 1:
        raise ValueError(f"patience: expected a positive integer, got {patience!r}")
    opt, least_squares = _make_solver(solver, rtol, atol, learning_rate)
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

    names, starts, by_path = _resolve_params(scene, params)
    lo, hi, maps = _resolve_bounds(names, starts, bounds, default_bounds)
    render_opts, key, shape = _render_opts(scene, render_kwargs)
    target_a, weights_a = _target_and_weights(target, weights, shape, dtype)
    # The solver works in float64 when JAX allows it (x64 on), whatever the
    # scene's dtype: quasi-Newton updates in float32 stall near the optimum.
    sdt = jnp.dtype(jnp.float64) if jax.config.jax_enable_x64 else jnp.dtype(dtype)
    z0 = {n: jnp.asarray(_to_unconstrained(starts[n], lo[n], hi[n], k), sdt) for n, k in zip(names, maps)}
    lo = {n: v.astype(sdt) for n, v in lo.items()}
    hi = {n: v.astype(sdt) for n, v in hi.items()}

    floats, ints = eqx.partition(scene, _is_float_array)
    problem = _Problem(
        floats=floats,
        ints=_Frozen(ints),
        target=target_a,
        weights=weights_a,
        scale=jnp.asarray(1.0, sdt),
        lo=lo,
        hi=hi,
        key=key,
        names=names,
        dtypes=tuple(str(starts[n].dtype) for n in names),
        maps=maps,
        by_path=by_path,
        render_opts=render_opts,
        loss_fn=loss_fn,
        reg_fn=regularizer,
    )

    # -- start: loss, finiteness, effect of each parameter ----------------
    rng = np.random.default_rng(0)
    probe = {n: jnp.asarray(rng.uniform(0.5, 1.5, z0[n].shape), sdt) for n in names}
    # The start's image outside jit: the render is compiled once per scene
    # structure, so this reuses the compilation that rendered the target.
    img0 = problem.image(z0)
    loss0 = float(problem.total_loss(img0, z0))
    if not bool(jnp.all(jnp.isfinite(img0))):
        raise FloatingPointError(
            "the render at the start contains non-finite values (nan or inf); check the start parameters"
        )
    if not math.isfinite(loss0):
        raise FloatingPointError(f"the loss at the start is not finite ({loss0})")
    if check:
        g = _effect(problem, z0, probe)
        dead, part = [], []
        for n in names:
            gz = np.asarray(g[n])
            zero = gz == 0
            if zero.all():
                dead.append(n)
            elif zero.any():
                part.extend(f"{n}[{', '.join(map(str, i))}]" for i in zip(*np.nonzero(zero)))
        if dead:
            raise ValueError(
                f"parameter(s) {', '.join(dead)} have no effect on the rendered image at the start "
                f"(their derivative is zero at every{' weighted' if weights is not None else ''} pixel), "
                "so they cannot be fitted: e.g. a light that lights nothing the camera sees, a material "
                "no visible object uses, or an effect only through hard edges (silhouettes, shadow "
                "boundaries carry no gradient). Move the start, or leave them out of params."
            )
        if part:
            warnings.warn(
                f"fit: component(s) {', '.join(part)} have no effect on the image at the start "
                "(zero derivative); they will stay where they are",
                RuntimeWarning,
                stacklevel=2,
            )
    v0 = problem.scene_values(z0)
    start_values = {n: np.asarray(v0[n]) for n in names}
    reporter = _Reporter(progress, max_steps, names)
    history = [loss0]
    p_history = [start_values]
    reporter(0, loss0, start_values)
    if callback is not None:
        callback(0, loss0, start_values)

    if loss0 == 0.0:
        msg = "the start already reproduces the target exactly (loss 0)"
        reporter.close(msg)
        return FitResult(
            scene=problem.scene_at(z0),
            params=start_values,
            initial_params=start_values,
            loss_history=np.asarray(history),
            param_history=p_history,
            steps=0,
            converged=True,
            result=optx.RESULTS.successful,
            message=msg,
            solver=opt,
            seconds=time.perf_counter() - t_start,
        )
    # Least squares: residuals of RMS 1 at the start; minimisers: loss 1 at the start.
    n_eff = float(np.count_nonzero(np.asarray(weights_a))) if least_squares else 1.0
    problem = eqx.tree_at(lambda p: p.scale, problem, jnp.asarray(n_eff / loss0, sdt))

    # -- iterate ------------------------------------------------------------
    z = z0
    best = (loss0, z0, start_values)
    dyn = _init(problem, opt, z, least_squares)
    steps, converged, interrupted, nonfinite, stalled = 0, False, False, False, False
    best_at = [loss0]  # best loss after each step
    result = optx.RESULTS.successful
    try:
        for steps in range(1, max_steps + 1):
            z_new, dyn, done, result, cur, finite, vals = _step(problem, opt, z, dyn, least_squares)
            cur = float(cur)
            if not bool(finite):
                nonfinite = True
                break
            z = z_new
            vals = {n: np.asarray(vals[n]) for n in names}
            history.append(cur)
            p_history.append(vals)
            if cur <= best[0]:
                best = (cur, z, vals)
            reporter(steps, cur, vals)
            if callback is not None:
                callback(steps, cur, vals)
            best_at.append(best[0])
            if bool(done) or result != optx.RESULTS.successful:
                converged = bool(done) and result == optx.RESULTS.successful
                break
            if steps >= patience and best_at[-1] > (1.0 - 1e-3) * best_at[-1 - patience]:
                stalled = converged = True
                break
    except KeyboardInterrupt:
        interrupted = True

    if nonfinite:
        msg = (
            f"the loss or the parameters became non-finite (nan or inf) at step {steps}; last finite "
            f"values: "
            + ", ".join(f"{n}={_fmt(v)}" for n, v in p_history[-1].items())
            + ". Try bounds, a closer start or another solver"
        )
        if throw:
            reporter.close("stopped: non-finite values")
            raise FloatingPointError(msg)
        result = optx.RESULTS.nonfinite
    elif interrupted:
        msg = f"interrupted after {steps - 1} steps; returning the best point so far"
    elif stalled:
        msg = f"converged in {steps} steps (stalled: the loss improved by less than 0.1% in the last {patience} steps)"
    elif converged:
        msg = f"converged in {steps} steps"
    elif result != optx.RESULTS.successful:
        msg = f"the solver stopped at step {steps}: {optx.RESULTS[result]}"
    else:
        result = optx.RESULTS.nonlinear_max_steps_reached
        msg = f"did not converge within max_steps={max_steps} steps"
    _, z_best, vals_best = best
    reporter.close(f"{msg}; loss {loss0:.4g} -> {best[0]:.4g}")
    if not converged and not interrupted:
        warnings.warn(
            f"fit: {msg} (loss {loss0:.4g} -> {best[0]:.4g}); the result may be inaccurate: "
            "raise max_steps, loosen rtol/atol, or check the problem",
            RuntimeWarning,
            stacklevel=2,
        )
    return FitResult(
        scene=problem.scene_at(z_best),
        params=vals_best,
        initial_params=start_values,
        loss_history=np.asarray(history),
        param_history=p_history,
        steps=steps,
        converged=converged,
        result=result,
        message=msg,
        solver=opt,
        seconds=time.perf_counter() - t_start,
    )
