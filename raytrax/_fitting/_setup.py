"""Setting a fit up: what is fitted (names, start values, bounds), the render
options, the target and the weights, all checked with clear messages."""

from __future__ import annotations

import difflib

import jax
import jax.numpy as jnp
import numpy as np

from ._problem import _path_name
from ._report import _fmt

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
    from ..params import parameters

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
    """:func:`_resolve_params` for a selector (``lambda s: s.lights.position``): names are pytree paths."""
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
    """-> (lo, hi, maps): per name the bounds (0 where there is none) and the
    reparameterisation, ``"none"``, ``"lower"``, ``"upper"`` or ``"both"``."""
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
    """The solver's unconstrained value for the start ``x0`` (inverse of :meth:`_Problem.values`)."""
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


def _render_opts(scene, render_kwargs):
    """-> (render options as a sorted tuple, the render key, the image shape (H, W, 3))."""
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
    """The target and the per-pixel weights (normalised to sum to 1) as ``(H, W, 3)`` arrays, checked."""
    t, w = _check_target_and_weights(target, weights, shape)
    return jnp.asarray(t, dtype), jnp.asarray(w / w.sum(), dtype)


def _check_target_and_weights(target, weights, shape, view=""):
    """One target and its weights, checked against the render's ``shape``: -> NumPy
    ``(H, W, 3)`` target and (unnormalised) weights. ``view`` (``"[i]"``) names the
    view in messages (``target[1]: ...``)."""
    t = np.asarray(target)
    if t.shape != shape:
        hint = ""
        if t.ndim == 3 and t.shape[2] == 3:
            every = " (every view is rendered at this size)" if view else ""
            hint = (
                f"; render the target at the scene's size or pass "
                f"render_kwargs=dict(width={t.shape[1]}, height={t.shape[0]}){every}"
            )
        raise ValueError(
            f"target{view}: shape {t.shape} does not match the rendered image's shape {shape} (height, width, 3){hint}"
        )
    if not np.all(np.isfinite(t)):
        raise ValueError(f"target{view}: contains {int(np.sum(~np.isfinite(t)))} non-finite values (nan or inf)")
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
                f"weights{view}: shape {np.shape(weights)} does not fit the image's shape {shape}; "
                f"expected (H, W), (H, W, 1) or (H, W, 3)"
            ) from None
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"weights{view}: expected finite, non-negative weights")
        if not np.any(w > 0):
            raise ValueError(f"weights{view}: every weight is zero (an empty mask): nothing to fit")
    return t, w
