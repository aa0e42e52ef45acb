"""What :func:`raytrax.fit` returns: :class:`FitResult`."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..scene import Scene
from ._report import _fmt


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
    - ``stderr``: one-sigma standard errors by name (arrays shaped like the
      parameters), from the Gauss-Newton approximation at the optimum,
      ``covariance = sigma^2 (J^T W J)^-1`` with ``J`` the Jacobian of the image
      with respect to the fitted values (natural units) and ``sigma`` the noise
      level per pixel and channel: ``fit(noise=...)``, or estimated from the
      residual as ``sqrt(RSS / (n - p))`` (``noise`` holds the value used).
      ``inf`` for components in a direction the image does not determine (listed
      in ``undetermined``, one list of component labels per direction, and
      warned about). ``None`` when not computed (``uncertainty=False``, a custom
      loss or regulariser, more than 64 fitted numbers).
    - ``covariance``: the ``(p, p)`` covariance of the flattened fitted numbers,
      in the order of ``covariance_labels`` (``"name"`` or ``"name[i]"``).
    - ``starts``: for a fit from several starts (``fit(starts=N)``, or the
      default with bounds), one dict per start: ``start`` and ``params`` (values
      by name before / after its short local fit), ``loss`` (on the first blur
      level), ``steps``, ``converged``; the lowest loss was kept. ``levels``: the
      intermediate blur levels' refinements (``level``, ``start``, ``params``,
      ``loss``, ``steps``). ``loss_history``, ``param_history`` and ``steps``
      are those of the final, unblurred run from the search's best point.
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
    stderr: dict | None = None
    covariance: np.ndarray | None = None
    covariance_labels: tuple = ()
    noise: float | None = None
    undetermined: list = dataclasses.field(default_factory=list)
    starts: list = dataclasses.field(default_factory=list)
    levels: list = dataclasses.field(default_factory=list)

    @property
    def loss(self) -> float:
        """The final loss."""
        return float(self.loss_history[-1])

    def __str__(self):
        def line(n, v):
            se = "" if self.stderr is None else f" +- {_fmt(self.stderr[n])}"
            return f"  {n} = {_fmt(v)}{se}"

        vals = "\n".join(line(n, v) for n, v in self.params.items())
        return (
            f"FitResult({self.message}; {self.steps} steps, loss {self.loss_history[0]:.4g} -> "
            f"{self.loss:.4g}, {self.seconds:.1f} s)\n{vals}"
        )
