"""Fits that converge from far away: several starts spread over the bounds, and
coarse-to-fine levels (render and target blurred alike).

A loss dominated by edges (silhouettes, a checker seen through glass, shadow
boundaries) is not convex in the parameters and plain automatic differentiation
does not see edges move, so a local solver from a far start stops in the wrong
valley. Two remedies, used together by default when every fitted parameter has
finite lower and upper bounds given in ``bounds``:

* **starts**: local fits from the given start and from points spread over the
  bounds (a Halton sequence: deterministic and low-discrepancy), each with a
  short budget; the one with the lowest loss is kept. The loss *values* pick
  the basin, whatever the gradients say.
* **levels**: the loss compares ``blur(render)`` with ``blur(target)`` (a
  Gaussian of standard deviation ``level * width`` pixels); the starts are run
  on the first (most blurred) level and the best one is refined on the next
  levels, the last one unblurred. Blurring turns edge jumps into ramps that
  overlap over a wider range of the parameters, so basins widen.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._problem import _Problem

#: Defaults of the robust search (see :func:`raytrax.fit`): the number of starts
#: and the blur levels (Gaussian standard deviation as a fraction of the image width).
DEFAULT_STARTS = 8
DEFAULT_LEVELS = (0.05, 0.0)
#: fitted numbers up to which the robust search is the default when bounds are given
ROBUST_MAX_NUMBERS = 8


class _BlurredProblem(_Problem):
    """A :class:`_Problem` whose loss compares the blurred render with the blurred
    target: ``blur(x) = Bh @ x @ Bw^T`` per channel (separable Gaussian matrices,
    rows renormalised at the image border). The matrices are traced arrays, so
    every blur level of one image size shares one compiled step."""

    bh: jax.Array | None = None  # (H, H); block-diagonal over views
    bw: jax.Array | None = None  # (W, W)

    def blur(self, img):
        assert self.bh is not None and self.bw is not None
        hp = jax.lax.Precision.HIGHEST
        out = jnp.einsum("ij,jkc->ikc", self.bh.astype(img.dtype), img, precision=hp)
        return jnp.einsum("lk,ikc->ilc", self.bw.astype(img.dtype), out, precision=hp)

    def raw_loss(self, img):
        if self.loss_fn is not None:
            return self.loss_fn(self.blur(img), self.blur(self.target))
        d = self.blur(img - self.target)
        return jnp.sum(self.weights * d * d)

    def residual(self, z, args):
        d = self.blur(self.image(z) - self.target)
        r = (jnp.sqrt(self.weights) * d).reshape(-1).astype(self.scale.dtype)
        return jnp.sqrt(self.scale) * r, None


def _gauss_matrix(n, sigma):
    """The ``(n, n)`` matrix of a 1-D Gaussian blur of standard deviation ``sigma``
    pixels, each row renormalised to sum 1 (no darkening at the border)."""
    i = np.arange(n)
    k = np.exp(-0.5 * ((i[:, None] - i[None, :]) / sigma) ** 2)
    return k / k.sum(axis=1, keepdims=True)


def _blurred(problem: _Problem, level: float) -> _Problem:
    """``problem`` with its loss on images blurred by a Gaussian of standard deviation
    ``level * width`` pixels (``problem`` itself for level 0)."""
    if level <= 0:
        return problem
    h, w = problem.target.shape[:2]
    sigma = level * w
    fields = {f: getattr(problem, f) for f in problem.__dataclass_fields__ if f not in ("bh", "bw")}
    # several views stacked along the height: block-diagonal, each view blurred on its own
    bh = np.kron(np.eye(problem.views), _gauss_matrix(h // problem.views, sigma))
    return _BlurredProblem(
        **fields,
        bh=jnp.asarray(bh, problem.target.dtype),
        bw=jnp.asarray(_gauss_matrix(w, sigma), problem.target.dtype),
    )


def _halton(k, base):
    """The ``k``-th (from 1) element of the van der Corput sequence in ``base``."""
    f, r = 1.0, 0.0
    while k > 0:
        f /= base
        r += f * (k % base)
        k //= base
    return r


_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71, 73, 79, 83, 89, 97)


def _spread(n, dims):
    """``n`` points of the Halton sequence in ``[0, 1]^dims`` (points 1..n; for one
    dimension 1/2, 1/4, 3/4, 1/8, ...). Beyond 25 dimensions the bases repeat
    with a shift (still deterministic, less uniform)."""
    pts = np.empty((n, dims))
    for d in range(dims):
        base = _PRIMES[d % len(_PRIMES)]
        shift = (d // len(_PRIMES)) * 0.5 / base
        pts[:, d] = [(_halton(k, base) + shift) % 1.0 for k in range(1, n + 1)]
    return pts


def _start_points(fitted, n):
    """``n`` start values (dicts name -> array): the given start, then ``n - 1``
    points spread over the bounds of every component that has finite lower and
    upper bounds (the others keep their given start)."""
    names = fitted.names
    spread = [
        (nm, i)
        for nm, kind in zip(names, fitted.maps)
        if kind == "both"
        for i in np.ndindex(*np.shape(fitted.starts[nm]))
    ]
    if n > 1 and not spread:
        raise ValueError(
            "starts: several starts are spread over the bounds, but no fitted parameter has both a "
            "lower and an upper bound; pass bounds={name: (lo, hi)}"
        )
    given = {nm: np.asarray(fitted.starts[nm], np.float64) for nm in names}
    out = [given]
    for u in _spread(n - 1, len(spread)):
        pt = {nm: v.copy() for nm, v in given.items()}
        for (nm, i), t in zip(spread, u):
            lo = float(np.asarray(fitted.lo[nm])[i])
            hi = float(np.asarray(fitted.hi[nm])[i])
            pt[nm][i] = lo + t * (hi - lo)
        out.append(pt)
    return out


def _resolve_search(fitted, bounds, starts, levels):
    """-> (number of starts, blur levels) from the ``starts`` and ``levels`` arguments
    (``None``: the robust defaults when every fitted parameter has finite lower and
    upper bounds in ``bounds`` and there are at most :data:`ROBUST_MAX_NUMBERS`
    fitted numbers, else one start and no blur)."""
    size = sum(int(np.prod(np.shape(fitted.starts[n]))) for n in fitted.names)
    user = dict(bounds or {})
    robust = (
        all(n in user and kind == "both" for n, kind in zip(fitted.names, fitted.maps)) and size <= ROBUST_MAX_NUMBERS
    )
    if starts is None:
        starts = DEFAULT_STARTS if robust else 1
    if isinstance(starts, bool) or not isinstance(starts, int) or starts < 1:
        raise ValueError(f"starts: expected a positive integer, got {starts!r}")
    if starts > 1 and "both" not in fitted.maps:
        raise ValueError(
            "starts: several starts are spread over the bounds, but no fitted parameter has both a "
            "lower and an upper bound; pass bounds={name: (lo, hi)}"
        )
    if levels is None:
        levels = DEFAULT_LEVELS if robust else (0.0,)
    try:
        levels = tuple(float(v) for v in levels)
    except TypeError:
        raise ValueError(
            f"levels: expected a sequence of blur levels (fractions of the image width), got {levels!r}"
        ) from None
    if not levels or any(not np.isfinite(v) or v < 0 for v in levels):
        raise ValueError(f"levels: expected non-negative finite blur levels, got {levels!r}")
    if levels[-1] != 0.0:
        levels = levels + (0.0,)  # the last level is always the unblurred loss
    return starts, levels
