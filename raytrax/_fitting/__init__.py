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

Several views of one scene are fitted at once with a list of targets and one
camera per target (``fit(scene, [image_1, image_2], params, cameras=[cam_1,
cam_2])``): one least-squares problem over all views' pixels, standard errors
from all of them.

Bounds are handled by reparameterisation: a parameter with a lower bound is
``lo + softplus(z)``, with an upper bound ``hi - softplus(z)``, with both
``lo + (hi - lo) sigmoid(z)``; the solver works on the unconstrained ``z``. By
default the refractive index is kept ``>= 1``, intensities, radii, sizes and
shininess ``>= 0``, transparency in ``[0, 1]`` and the field of view in
``(0, 180)``.
"""

from ._fit import fit
from ._result import FitResult
from ._setup import DEFAULT_BOUNDS
from ._solvers import SOLVERS

__all__ = ["fit", "FitResult", "SOLVERS", "DEFAULT_BOUNDS"]
