"""Recover the positions of two point lights from one image.

The target is rendered from known light positions; the fit starts with both
lights moved by about 3 units and recovers them with Levenberg-Marquardt on the
residual image (or ``--solver bfgs``). With physical shading the irradiance
``I cos / r^2`` makes every lit pixel a smooth function of the light position,
which is what makes positions recoverable (shadow edges carry no gradient).

    python examples/fit_light_positions.py                  # 96 x 72, about a minute
    python examples/fit_light_positions.py --solver bfgs --out /tmp/lights

Prints the distance of each light from the truth at every step, and saves
``fit_light_positions.png`` (target / start / fit / |fit - target|) and
``fit_light_positions_loss.png`` (loss and errors per step) in ``--out``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

# The solver's own arithmetic in float64 (the scene stays float32): quasi-Newton
# updates (BFGS) stall in float32 near the optimum.
jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402

TRUE_LIGHTS = [(-2.5, 4.0, 2.0), (2.5, 3.0, -1.0)]
START_OFFSETS = [(2.0, -1.5, 1.5), (-2.0, 1.5, -1.5)]  # 2.9 units each
SCENE_SIZE = 10.0  # the floor the camera sees is about 10 units across
NAMES = ["light[0].position", "light[1].position"]


def make_scene(width=96, height=72, lights=TRUE_LIGHTS):
    """A floor, a back wall and two spheres lit by a warm and a cool light."""
    b = rt.SceneBuilder("physical", width=width, height=height, spp=1, max_depth=1, background=(0.05, 0.05, 0.05))
    b.camera(position=(0, 3, 9), look_at=(0, 0.8, 0), fov=45)
    b.light(lights[0], intensity=(30, 22, 14))
    b.light(lights[1], intensity=(10, 16, 30))
    b.material("floor", color=(0.8, 0.8, 0.8))
    b.material("red", color=(0.8, 0.3, 0.2))
    b.material("green", color=(0.3, 0.7, 0.35))
    b.plane((0, 0, 0), (0, 1, 0), "floor")
    b.plane((0, 0, -4), (0, 0, 1), "floor")
    b.sphere((-0.6, 1, 0), 1.0, "red")
    b.sphere((1.6, 0.6, 1.2), 0.6, "green")
    return b.build()


def start_positions():
    return {n: np.asarray(p, float) + np.asarray(o, float) for n, p, o in zip(NAMES, TRUE_LIGHTS, START_OFFSETS)}


def errors(values):
    return [
        float(np.linalg.norm(np.asarray(values[n], float) - np.asarray(p, float))) for n, p in zip(NAMES, TRUE_LIGHTS)
    ]


def run(width=96, height=72, steps=100, solver="levenberg_marquardt", out=None, verbose=True):
    """Render the target, fit, optionally save the pictures; returns the
    :class:`raytrax.FitResult` and the final errors (world units)."""
    scene = make_scene(width, height)
    target = rt.render(scene)
    start = make_scene(width, height, lights=list(start_positions().values()))

    def report(step, loss, values):
        if verbose:
            e = errors(values)
            print(
                f"step {step:3d}  loss {loss:.3e}  |light0 - truth| {e[0]:.5f}  |light1 - truth| {e[1]:.5f}", flush=True
            )

    res = rt.fit(start, target, NAMES, solver=solver, max_steps=steps, progress=False, callback=report)
    err = errors(res.params)
    if verbose:
        print(f"{res.message}; {res.steps} steps in {res.seconds:.1f} s (compilation included)")
        for n, p in zip(NAMES, TRUE_LIGHTS):
            print(f"  {n}: fitted {np.round(res.params[n], 4).tolist()}  true {list(p)}")
        print(
            f"  final errors: {err[0]:.2e}, {err[1]:.2e} world units "
            f"({100 * max(err) / SCENE_SIZE:.2g}% of the scene's size)"
        )
    if out:
        save_figures(out, target, rt.render(start), rt.render(res.scene), res, verbose)
    return res, err


def save_figures(out, target, start_img, fit_img, res, verbose=True):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # examples/_figures.py
    from _figures import image_grid, pyplot, save

    plt = pyplot()

    diff = np.abs(np.asarray(fit_img) - np.asarray(target))
    panels = [
        ("target", target),
        ("start", start_img),
        ("fit", fit_img),
        (f"|fit - target| x 10 (max {diff.max():.1e})", diff * 10),
    ]
    p1 = image_grid(os.path.join(out, "fit_light_positions.png"), panels)

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].semilogy(np.maximum(res.loss_history, 1e-30), marker=".")
    ax[0].set_xlabel("step")
    ax[0].set_ylabel("loss (MSE)")
    ax[0].set_title("loss")
    errs = np.array([errors(v) for v in res.param_history])
    for k in range(2):
        ax[1].semilogy(np.maximum(errs[:, k], 1e-12), marker=".", label=f"light {k}")
    ax[1].axhline(0.01 * SCENE_SIZE, color="grey", ls="--", label="1% of the scene")
    ax[1].set_xlabel("step")
    ax[1].set_ylabel("|position - truth|")
    ax[1].set_title("light position error")
    ax[1].legend()
    p2 = save(fig, os.path.join(out, "fit_light_positions_loss.png"))
    if verbose:
        print(f"saved {p1} and {p2}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=72)
    ap.add_argument("--steps", type=int, default=100, help="maximum solver steps")
    ap.add_argument(
        "--solver",
        default="levenberg_marquardt",
        help="levenberg_marquardt, gauss_newton, dogleg, bfgs, gradient_descent, nonlinear_cg",
    )
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "out"))
    a = ap.parse_args(argv)
    t = time.perf_counter()
    run(a.width, a.height, a.steps, a.solver, a.out)
    print(f"total {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
