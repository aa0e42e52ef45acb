"""Gradient checks for your own unit tests.

:func:`check_gradients` compares the reverse-mode (``jax.grad``) and
forward-mode (``jax.jvp``) derivatives of a scalar function of named scene
parameters with central finite differences, in float64, and fails with a
readable per-component table. :func:`render64` renders a scene in float64 and
:func:`image_loss` builds the usual "mean squared error of a render against a
target" function of the parameters.

Example (a pytest test; x64 must be enabled before any array is made)::

    import jax
    jax.config.update("jax_enable_x64", True)

    import raytrax as rt
    from raytrax.testing import check_gradients, image_loss, render64

    def test_my_scene_gradients():
        b = rt.SceneBuilder("classic", width=8, height=6, max_depth=1)
        b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=30)
        b.light((2, 3, 5))
        b.material("red", color=(0.8, 0.2, 0.2), specular=0.5, shininess=20)
        b.sphere((0, 0, 0), 1.0, "red")
        scene = b.build()
        target = render64(rt.with_parameters(scene, {"light[0].position": [1.0, 3.0, 5.0]}))
        loss = image_loss(scene, target)          # loss(params) -> float64 scalar
        report = check_gradients(loss, rt.parameters(scene),
                                 names=["light[0].position", "material.red.color"])
        print(report)                             # the table, also shown on failure

A component passes when ``|AD - FD| <= atol + rtol * |FD|`` for reverse mode
and (with ``forward_mode=True``) forward mode. Finite differences only measure
the derivative the renderer computes where the function is smooth within the
step: with the default tiny steps that is almost everywhere, but a silhouette,
shadow edge or unfiltered texture edge that crosses a sample ray within the
step makes finite differences jump (see docs/gradients.md); pass
``fd_consistency=True`` to have such components flagged.

Edge gradients (``edge_gradients=True``) are the derivative of the anti-aliased
image instead: :func:`jittered_central_differences` is their reference.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "check_gradients",
    "gradient_report",
    "GradientReport",
    "render64",
    "image_loss",
    "smooth_weights",
    "jittered_central_differences",
]

_EPS64 = float(np.finfo(np.float64).eps)


def _require_x64(what: str):
    if not jax.config.read("jax_enable_x64"):
        raise RuntimeError(
            f"{what} needs float64: call jax.config.update('jax_enable_x64', True) at the start of "
            "the program (or set JAX_ENABLE_X64=1), before any array is created"
        )


def render64(scene, **render_kwargs) -> jax.Array:
    """Render ``scene`` with every float leaf cast to float64 (needs x64 enabled).

    Keywords are those of :func:`raytrax.render`. Returns an ``(H, W, 3)``
    float64 image; differentiable like ``render``.
    """
    from .renderer import render

    _require_x64("raytrax.testing.render64")
    return render(scene.astype(jnp.float64), **render_kwargs)


def smooth_weights(height: int, width: int) -> np.ndarray:
    """``(height, width, 3)`` loss weights between 0.1 and 0.9 that vary slowly over the
    image (a different low-frequency wave per channel).

    For checking edge gradients (``render(..., edge_gradients=True)``) against finite
    differences: with a weight that jumps from pixel to pixel, ``sum(w * image)`` has a
    kink whenever an edge crosses a pixel boundary, so no finite step converges to its
    derivative; with these weights the kinks are small and a step that moves edges by a
    tenth of a pixel does converge."""
    yy, xx = np.meshgrid((np.arange(height) + 0.5) / height, (np.arange(width) + 0.5) / width, indexing="ij")
    return np.stack(
        [
            0.5 + 0.4 * np.sin(2 * np.pi * (0.7 * xx + 0.3 * yy) + 0.3),
            0.5 + 0.4 * np.sin(2 * np.pi * (-0.4 * xx + 0.8 * yy) + 1.1),
            0.5 + 0.4 * np.cos(2 * np.pi * (0.5 * xx - 0.6 * yy) + 2.0),
        ],
        -1,
    )


def image_loss(scene, target, *, weights=None, **render_kwargs) -> Callable[[Mapping[str, Any]], jax.Array]:
    """``loss(params) = mean(weights * (render64(with_parameters(scene, params)) - target)^2)``.

    ``target`` is an ``(H, W, 3)`` image; ``weights`` (optional) broadcasts
    against it, e.g. an ``(H, W, 1)`` mask of the pixels that count (the mean is
    then over the weighted pixels: ``sum(w e^2) / sum(w)`` per channel).
    The returned function takes a dict of named parameters (all of them, or a
    subset) and returns a float64 scalar.
    """
    from .params import with_parameters
    from .renderer import render

    _require_x64("raytrax.testing.image_loss")
    scene64 = scene.astype(jnp.float64)
    target = jnp.asarray(target, jnp.float64)
    w = None if weights is None else jnp.broadcast_to(jnp.asarray(weights, jnp.float64), target.shape)

    def loss(params):
        img = render(with_parameters(scene64, params), **render_kwargs)
        if img.shape != target.shape:
            raise ValueError(f"image_loss: render has shape {img.shape}, target {target.shape}")
        e2 = (img - target) ** 2
        if w is None:
            return jnp.mean(e2)
        return jnp.sum(w * e2) / jnp.maximum(jnp.sum(w), 1e-300)

    return loss


@dataclasses.dataclass
class GradientRow:
    """One checked component: ``name[index]`` (``index`` is a flat index into the parameter)."""

    name: str
    index: int
    shape: tuple
    value: float
    step: float
    fd: float
    rev: float
    fwd: float | None
    tol: float
    fd_half: float | None = None

    @property
    def err(self) -> float:
        e = abs(self.rev - self.fd)
        if self.fwd is not None:
            e = max(e, abs(self.fwd - self.fd))
        return e

    @property
    def rel_err(self) -> float:
        return self.err / max(abs(self.fd), 1e-300)

    @property
    def fd_unstable(self) -> bool:
        return self.fd_half is not None and abs(self.fd_half - self.fd) > self.tol

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.rev) and (self.fwd is None or np.isfinite(self.fwd)) and self.err <= self.tol)

    @property
    def label(self) -> str:
        if self.shape == ():
            return self.name
        idx = np.unravel_index(self.index, self.shape)
        return f"{self.name}[{','.join(str(int(i)) for i in idx)}]"


@dataclasses.dataclass
class GradientReport:
    """The outcome of :func:`gradient_report`: one :class:`GradientRow` per component."""

    rows: list
    value: float
    rtol: float
    atol: float

    @property
    def ok(self) -> bool:
        return all(r.ok for r in self.rows)

    @property
    def failures(self) -> list:
        return [r for r in self.rows if not r.ok]

    @property
    def max_rel_err(self) -> float:
        """Largest relative error over components whose finite difference is not
        negligible (``|FD| > atol``)."""
        errs = [r.rel_err for r in self.rows if abs(r.fd) > self.atol]
        return max(errs, default=0.0)

    def table(self, rows=None) -> str:
        rows = self.rows if rows is None else rows
        has_fwd = any(r.fwd is not None for r in rows)
        has_half = any(r.fd_half is not None for r in rows)
        head = ["parameter", "value", "step", "finite diff", "reverse (grad)"]
        if has_fwd:
            head.append("forward (jvp)")
        head += ["rel err", ""]
        lines = []
        for r in rows:
            cells = [r.label, f"{r.value:.6g}", f"{r.step:.2g}", f"{r.fd:.9g}", f"{r.rev:.9g}"]
            if has_fwd:
                cells.append("-" if r.fwd is None else f"{r.fwd:.9g}")
            cells.append(f"{r.rel_err:.2e}")
            flag = "ok" if r.ok else "FAIL"
            if has_half and r.fd_unstable:
                flag += " (FD not smooth within the step)"
            cells.append(flag)
            lines.append(cells)
        widths = [max(len(h), *(len(c[i]) for c in lines)) if lines else len(h) for i, h in enumerate(head)]
        fmt = lambda cells: "  ".join(
            c.rjust(w) if 0 < i < len(cells) - 1 else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths))
        ).rstrip()
        return "\n".join([fmt(head), fmt(["-" * w for w in widths])] + [fmt(c) for c in lines])

    def __str__(self) -> str:
        n, bad = len(self.rows), len(self.failures)
        head = (
            f"gradient check: {n - bad}/{n} components pass (|AD - FD| <= atol + rtol |FD|, "
            f"rtol={self.rtol:.1e}, atol={self.atol:.2e}; f = {self.value:.9g}); "
            f"max relative error {self.max_rel_err:.2e}"
        )
        return head + "\n" + self.table()


def jittered_central_differences(loss: Callable, q0, step: float, spp: int, keys: int):
    """The reference for edge gradients: central differences of ``loss(q, spp=spp,
    key=key)`` (a scalar of jittered renders) at ``q0 (P,)``, one component at a time
    with a ``step`` that moves edges by a fraction of a pixel, both sides of each
    difference rendered with the same key, averaged over ``keys`` keys (``0 ..
    keys - 1``). The anti-aliased image is smooth in the parameters, and each key's
    difference is an unbiased estimate of its difference quotient. Returns the mean
    ``(P,)`` and its standard error ``(P,)`` (NumPy). ``loss`` is compiled once
    (``jax.jit``) for the ``2 P keys`` renders; give it a float64 scene where the step
    is small."""
    f = jax.jit(lambda q, key: loss(q, spp=spp, key=key))
    q0 = jnp.asarray(q0)
    if q0.ndim != 1:
        raise ValueError(f"jittered_central_differences: q0 must be a vector (P,), got shape {q0.shape}")
    if keys < 2:
        raise ValueError(f"jittered_central_differences: keys must be at least 2 (for a standard error), got {keys}")
    eye = step * jnp.eye(q0.shape[0], dtype=q0.dtype)
    fd = np.array(
        [
            [float((f(q0 + e, k) - f(q0 - e, k)) / (2 * step)) for e in eye]
            for k in (jax.random.key(i) for i in range(keys))
        ]
    )
    return fd.mean(0), fd.std(0, ddof=1) / np.sqrt(keys)


def _select(params, names) -> list[tuple[str, int]]:
    if names is None:
        names = list(params)
    comps = []
    if isinstance(names, Mapping):
        items = names.items()
    else:
        if isinstance(names, str):
            names = [names]
        items = [(n, None) for n in names]
    for name, idx in items:
        if name not in params:
            import difflib

            near = difflib.get_close_matches(str(name), [str(k) for k in params], n=3)
            hint = f"; did you mean {', '.join(map(repr, near))}?" if near else ""
            raise ValueError(f"check_gradients: {name!r} is not a key of params{hint}")
        size = int(np.size(params[name]))
        if idx is None:
            idx = range(size)
        elif isinstance(idx, (int, np.integer)):
            idx = [int(idx)]
        for i in idx:
            if not 0 <= int(i) < size:
                raise ValueError(f"check_gradients: component {i} of {name!r} out of range (size {size})")
            comps.append((name, int(i)))
    return comps


def _steps(step, rel_step, comps, params) -> list[float]:
    out = []
    for name, i in comps:
        x = float(np.asarray(params[name]).reshape(-1)[i])
        if step is None:
            h = rel_step * max(1.0, abs(x))
        elif isinstance(step, Mapping):
            h = float(step[name]) if name in step else rel_step * max(1.0, abs(x))
        else:
            h = float(step)
        # A step that is exactly representable around x.
        h = float(np.float64(x + h) - np.float64(x))
        if not h > 0:
            raise ValueError(f"check_gradients: the step for {name!r} at {x!r} is not positive (got {h!r})")
        out.append(h)
    return out


def gradient_report(
    fn: Callable,
    params: Mapping[str, Any],
    *,
    names=None,
    rtol: float = 1e-4,
    atol: float | None = None,
    step=None,
    rel_step: float = _EPS64 ** (1.0 / 3.0),
    forward_mode: bool = True,
    fd_consistency: bool = False,
) -> GradientReport:
    """Like :func:`check_gradients` but returns the :class:`GradientReport` without
    raising."""
    _require_x64("raytrax.testing.check_gradients")
    p = {k: jnp.asarray(np.asarray(v, dtype=np.float64)) for k, v in params.items()}
    comps = _select(p, names)
    if not comps:
        raise ValueError("check_gradients: nothing to check (no names / empty parameters)")

    def f(q):
        out = fn(q)
        out = jnp.asarray(out)
        if out.shape != ():
            raise ValueError(f"check_gradients: fn must return a scalar, got shape {out.shape}")
        return out

    f0 = f(p)
    if f0.dtype != jnp.float64:
        raise ValueError(
            f"check_gradients: fn returned {f0.dtype}; the function must compute in float64 "
            "(render with raytrax.testing.render64, or scene.astype(jnp.float64))"
        )
    f0 = float(f0)

    # Reverse mode: one gradient of the whole dict (so every call of the same fn shares
    # one compiled program whatever is checked).
    g = jax.grad(f)(p)
    rev = [float(np.asarray(g[n]).reshape(-1)[i]) for n, i in comps]

    # Forward mode: linearize once, then one jvp per checked direction (the linear
    # program is compiled once and reused for every direction).
    fwd: list = [None] * len(comps)
    if forward_mode:
        _, f_jvp = jax.linearize(f, p)
        zeros = {k: np.zeros(v.shape, np.float64) for k, v in p.items()}
        for j, (n, i) in enumerate(comps):
            e = zeros[n].copy()
            e.reshape(-1)[i] = 1.0
            fwd[j] = float(f_jvp({**zeros, n: e}))

    # Central finite differences.
    hs = _steps(step, rel_step, comps, p)
    host = {k: np.asarray(v) for k, v in p.items()}

    def shifted(name, i, delta):
        a = host[name].copy()
        a.reshape(-1)[i] += delta
        return float(f({**p, name: jnp.asarray(a)}))

    fd, fd_half = [], []
    for (n, i), h in zip(comps, hs):
        fd.append((shifted(n, i, h) - shifted(n, i, -h)) / (2.0 * h))
        if fd_consistency:
            hh = h * 0.5
            fd_half.append((shifted(n, i, hh) - shifted(n, i, -hh)) / (2.0 * hh))
        else:
            fd_half.append(None)

    gmax = max((abs(x) for x in fd), default=0.0)
    atol_auto = atol is None
    if atol_auto:
        atol = rtol * 1e-3 * gmax
    rows = []
    for (n, i), h, d, dh, r, fw in zip(comps, hs, fd, fd_half, rev, fwd):
        tol = atol + rtol * abs(d)
        if atol_auto:  # the rounding error of the difference quotient itself
            tol += 16.0 * _EPS64 * max(abs(f0), 1e-300) / h
        rows.append(GradientRow(n, i, tuple(np.shape(host[n])), float(host[n].reshape(-1)[i]), h, d, r, fw, tol, dh))
    return GradientReport(rows, f0, rtol, atol)


def check_gradients(
    fn: Callable,
    params: Mapping[str, Any],
    *,
    names=None,
    rtol: float = 1e-4,
    atol: float | None = None,
    step=None,
    rel_step: float = _EPS64 ** (1.0 / 3.0),
    forward_mode: bool = True,
    fd_consistency: bool = False,
) -> GradientReport:
    """Check the derivatives of ``fn(params) -> scalar`` against central finite differences.

    - ``fn``: a function of a dict of float64 arrays (e.g. from
      :func:`image_loss`, or your own ``lambda p: loss(render64(with_parameters(scene, p)))``)
      returning a float64 scalar.
    - ``params``: the point to check at, ``{name: array}`` (e.g.
      :func:`raytrax.parameters`); values are converted to float64. Gradients
      are always taken with respect to the whole dict.
    - ``names``: which to check; a list of keys (every component), or a dict
      ``{name: [flat component indices]}``. Default: everything.
    - ``rtol``, ``atol``: a component passes when ``|AD - FD| <= atol + rtol |FD|``.
      Default ``atol``: ``1e-3 * rtol`` times the largest ``|FD|`` checked, plus the
      rounding error of the difference quotient (``16 eps |f| / h``).
    - ``step``: finite-difference step, a number, a ``{name: step}`` dict, or
      ``None`` for ``rel_step * max(1, |x|)``; ``rel_step`` defaults to
      ``eps^(1/3)`` (about ``6e-6``), which balances truncation and rounding
      error for smooth functions. A smaller ``rel_step`` (e.g. ``1e-7``) makes
      it less likely that a kink of the render (a box-filtered texture ramp's
      end, ``max(n.l, 0)``) lies within the step.
    - ``forward_mode``: also check forward mode (``jax.linearize``, i.e. ``jax.jvp``)
      along each checked unit direction.
    - ``fd_consistency``: also difference with half the step and flag components
      where the two disagree (the function is not smooth within the step).

    Returns the :class:`GradientReport` when every component passes; otherwise
    raises ``AssertionError`` whose message is the report's table.
    """
    rep = gradient_report(
        fn,
        params,
        names=names,
        rtol=rtol,
        atol=atol,
        step=step,
        rel_step=rel_step,
        forward_mode=forward_mode,
        fd_consistency=fd_consistency,
    )
    if not rep.ok:
        bad = rep.failures
        raise AssertionError(
            f"{len(bad)} of {len(rep.rows)} gradient components disagree with finite differences "
            f"(|AD - FD| > atol + rtol |FD|, rtol={rep.rtol:.1e}, atol={rep.atol:.2e}, f = {rep.value:.9g})\n"
            + rep.table(bad)
            + ("\n\nall components:\n" + rep.table() if len(bad) < len(rep.rows) <= 60 else "")
        )
    return rep
