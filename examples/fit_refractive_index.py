"""Recover the refractive index of a glass sphere from one image.

A glass ball stands in front of a box-filtered checkerboard wall; the target
is rendered at ior 1.5 and the fit starts at 1.2 (``--start``). What is seen
through the ball (an inverted, shrunken view of the wall) moves smoothly with
the ior because the filtered checker has smooth edges, so the index is
recovered by least squares on the image (Levenberg-Marquardt; or
``--solver bfgs``). The ior is fitted with its default bound ``ior >= 1``
(``ior = 1 + softplus(z)``).

    python examples/fit_refractive_index.py                 # 96 x 72, about a minute
    python examples/fit_refractive_index.py --start 1.8 --solver bfgs

Prints the ior and its error at every step, and saves
``fit_refractive_index.png`` (target / start / fit / |fit - target|) and
``fit_refractive_index_loss.png`` in ``--out``.

Why the wall is far behind the ball and the checker coarse: a ball lens of
radius R has its focus ``n R / (2 (n - 1))`` from its centre; a wall that
the focus sweeps across while n goes from the start to the truth flips the
image through infinite magnification and gives the loss a barrier. With the
wall beyond the focus for every n in [1.2, 1.9] the loss is one smooth valley.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)  # the solver in float64; the scene stays float32

import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402

TRUE_IOR = 1.5
START_IOR = 1.2
NAME = "material.glass.ior"


def make_scene(width=96, height=72, ior=TRUE_IOR):
    b = rt.SceneBuilder("physical", width=width, height=height, spp=1, max_depth=3, background=(0.0, 0.0, 0.0))
    b.camera(position=(0, 0.5, 7), look_at=(0, 0, 0), fov=32)
    b.light((4.0, 5.0, -5.0), intensity=(120, 120, 120))  # beside the ball: its shadow misses the wall
    b.material("wall", color=(0.9, 0.9, 0.85), texture=rt.Checker(color2=(0.1, 0.15, 0.4), scale=0.2))
    b.material("glass", color=(0, 0, 0), transparency=1.0, ior=ior)
    b.plane((0, 0, -9), (0, 0, 1), "wall")
    b.sphere((0, 0, 0), 1.3, "glass")
    return b.build()


def run(width=96, height=72, steps=100, solver="levenberg_marquardt", start_ior=START_IOR, out=None, verbose=True):
    """Render the target, fit, optionally save the pictures; returns the
    :class:`raytrax.FitResult` and the final ior error."""
    scene = make_scene(width, height)
    target = rt.render(scene)
    start = make_scene(width, height, ior=start_ior)

    def report(step, loss, values):
        if verbose:
            v = float(values[NAME])
            print(f"step {step:3d}  loss {loss:.3e}  ior {v:.7f}  error {abs(v - TRUE_IOR):.2e}", flush=True)

    res = rt.fit(start, target, [NAME], solver=solver, max_steps=steps, progress=False, callback=report)
    err = abs(float(res.params[NAME]) - TRUE_IOR)
    if verbose:
        print(f"{res.message}; {res.steps} steps in {res.seconds:.1f} s (compilation included)")
        print(f"  ior: fitted {float(res.params[NAME]):.7f}  true {TRUE_IOR}  error {err:.2e}")
    if out:
        save_figures(out, target, rt.render(start), rt.render(res.scene), res, verbose)
    return res, err


def save_figures(out, target, start_img, fit_img, res, verbose=True):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # examples/_figures.py
    from _figures import image_grid, pyplot, save

    plt = pyplot()

    diff = np.abs(np.asarray(fit_img) - np.asarray(target))
    ior0 = float(res.initial_params[NAME])
    ior1 = float(res.params[NAME])
    panels = [
        (f"target (ior {TRUE_IOR})", target),
        (f"start (ior {ior0:.2f})", start_img),
        (f"fit (ior {ior1:.5f})", fit_img),
        (f"|fit - target| x 10 (max {diff.max():.1e})", diff * 10),
    ]
    p1 = image_grid(os.path.join(out, "fit_refractive_index.png"), panels)

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].semilogy(np.maximum(res.loss_history, 1e-30), marker=".")
    ax[0].set_xlabel("step")
    ax[0].set_ylabel("loss (MSE)")
    ax[0].set_title("loss")
    iors = [float(v[NAME]) for v in res.param_history]
    ax[1].plot(iors, marker=".")
    ax[1].axhline(TRUE_IOR, color="grey", ls="--", label="truth")
    ax[1].set_xlabel("step")
    ax[1].set_ylabel("ior")
    ax[1].set_title("refractive index")
    ax[1].legend()
    p2 = save(fig, os.path.join(out, "fit_refractive_index_loss.png"))
    if verbose:
        print(f"saved {p1} and {p2}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=72)
    ap.add_argument("--steps", type=int, default=100, help="maximum solver steps")
    ap.add_argument("--start", type=float, default=START_IOR, help="starting ior")
    ap.add_argument(
        "--solver",
        default="levenberg_marquardt",
        help="levenberg_marquardt, gauss_newton, dogleg, bfgs, gradient_descent, nonlinear_cg",
    )
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "out"))
    a = ap.parse_args(argv)
    t = time.perf_counter()
    run(a.width, a.height, a.steps, a.solver, a.start, a.out)
    print(f"total {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
