"""How sure a fit is: Gauss-Newton standard errors and covariance at the optimum.

With the residual ``r = image(x) - target`` (per pixel and channel, weighted as
the loss weights it) and its Jacobian ``J = d image / d x`` with respect to the
fitted parameters in their natural (bounded) units, the covariance of the
least-squares estimate under independent Gaussian noise of standard deviation
``sigma`` on the target is ``sigma^2 (J^T W J)^-1``. ``sigma`` is the user's
``noise`` or estimated from the residual, ``sigma^2 = RSS / (n - p)`` (``n``
weighted values, ``p`` fitted numbers). Directions of the parameters that the
image does not determine (eigenvalues of the column-normalised ``J^T W J``
below ``rcond`` times the largest: e.g. a light's intensity against an albedo)
are left out of the pseudo-inverse, reported, and give the components involved
an infinite standard error.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from ..compile_options import filter_jit
from ._problem import _Problem

#: fitted numbers up to which standard errors are computed (one forward-mode column each)
UNCERTAINTY_MAX_NUMBERS = 64
#: relative eigenvalue below which a direction counts as undetermined
RCOND = 1e-10


@filter_jit
def _jacobian(problem: _Problem, z):
    """The render at ``z`` and its forward-mode Jacobian with respect to ``z``
    (dict name -> ``(H, W, 3, *shape)``); compiled once per problem structure."""
    return problem.image(z), jax.jacfwd(problem.image)(z)


def _dx_dz(problem, z):
    """Per name, the derivative of the bounded value with respect to the solver's ``z``."""
    out = {}
    for n, kind in zip(problem.names, problem.maps):
        zz = np.asarray(z[n], np.float64)
        s = 1.0 / (1.0 + np.exp(-zz))
        if kind == "none":
            out[n] = np.ones_like(zz)
        elif kind == "lower":
            out[n] = s
        elif kind == "upper":
            out[n] = -s
        else:
            out[n] = (np.asarray(problem.hi[n], np.float64) - np.asarray(problem.lo[n], np.float64)) * s * (1 - s)
    return out


def _labels(problem, z):
    """Names of the fitted numbers in covariance order: ``name`` or ``name[i]``."""
    out = []
    for n in problem.names:
        shape = np.shape(z[n])
        if shape == ():
            out.append(n)
        else:
            out.extend(f"{n}[{', '.join(map(str, i))}]" for i in np.ndindex(*shape))
    return tuple(out)


@dataclasses.dataclass
class _Uncertainty:
    stderr: dict
    covariance: np.ndarray
    labels: tuple
    noise: float
    noise_estimated: bool
    undetermined: list  # one entry per undetermined direction: the labels involved


def _uncertainty(problem, z, noise=None, rcond=RCOND, image_and_jacobian=None):
    """Standard errors at ``z`` of the unblurred ``problem``; ``None`` if too many numbers are fitted."""
    labels = _labels(problem, z)
    p = len(labels)
    if p > UNCERTAINTY_MAX_NUMBERS:
        return None
    img, jz = image_and_jacobian if image_and_jacobian is not None else _jacobian(problem, z)
    dxdz = _dx_dz(problem, z)
    cols = []
    for n in problem.names:
        j = np.asarray(jz[n], np.float64)
        j = j.reshape(j.shape[:3] + (-1,)) / dxdz[n].reshape(-1)
        cols.append(j.reshape(-1, j.shape[-1]))
    J = np.concatenate(cols, axis=1)  # (H*W*3, p), d image / d x
    w = np.asarray(problem.weights, np.float64).reshape(-1)
    n_eff = int(np.count_nonzero(w))
    w = w * n_eff  # relative inverse variances, 1 for an unweighted fit
    d = (np.asarray(img, np.float64) - np.asarray(problem.target, np.float64)).reshape(-1)
    if noise is None:
        dof = max(n_eff - p, 1)
        sigma2 = float(np.sum(w * d * d)) / dof
        estimated = True
    else:
        sigma2 = float(noise) ** 2
        estimated = False
    A = J.T @ (w[:, None] * J)
    diag = np.diag(A).copy()
    dead = ~(diag > 0)
    scale = np.where(dead, 1.0, np.sqrt(np.where(dead, 1.0, diag)))
    C = A / np.outer(scale, scale)
    C[dead, :] = 0.0
    C[:, dead] = 0.0
    lam, V = np.linalg.eigh(C)
    top = max(float(lam.max()), 0.0)
    keep = lam > rcond * top if top > 0 else np.zeros_like(lam, bool)
    inv = (V[:, keep] / lam[keep]) @ V[:, keep].T
    cov = sigma2 * inv / np.outer(scale, scale)
    var = np.diag(cov).copy()
    undetermined, involved = [], np.zeros(p, bool)
    for k in np.nonzero(~keep)[0]:
        v = np.abs(V[:, k])
        big = v > 0.1 * v.max()
        involved |= big
        undetermined.append([labels[i] for i in np.nonzero(big)[0]])
    var[involved | dead] = np.inf
    se = np.sqrt(np.maximum(var, 0.0))
    stderr, k = {}, 0
    for n in problem.names:
        shape = np.shape(z[n])
        m = int(np.prod(shape))
        stderr[n] = se[k : k + m].reshape(shape)
        k += m
    return _Uncertainty(stderr, cov, labels, float(np.sqrt(sigma2)), estimated, undetermined)
