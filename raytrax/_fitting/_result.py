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
