"""Recover where an unseen object is from its shadow alone: plain AD fails, edge gradients succeed.

A ball hangs above a floor, outside the camera's view: the image shows only the
floor and the ball's hard shadow. The fit starts with the ball moved sideways
and looks for its (x, z) position that reproduces the target image.

With plain automatic differentiation the floor's shading does not depend on the
ball at all (visibility is piecewise constant), so the gradient is exactly zero
and no solver can move. With ``render(..., edge_gradients=True)`` the gradient
includes the shadow boundary moving over the floor (``raytrax.edges``), and
the fit recovers the position.

    python examples/fit_occluder_from_shadow.py          # 48 x 36, spp 16, a few minutes on 2 cores
    python examples/fit_occluder_from_shadow.py --out /tmp/shadow

Prints both runs step by step and saves ``fit_occluder_from_shadow.png``
(target / start / plain-AD result / edge-gradient result) and
``fit_occluder_from_shadow_loss.png`` in ``--out``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)  # the solver's arithmetic; the scene stays float32

import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402

TRUE = (0.3, 2.6, -0.2)
START = (0.9, 2.4, 0.3)  # 0.8 units away
NAME = "object[1].center"


def make_scene(width=48, height=36, spp=16, center=TRUE):
    """A floor seen from above; a ball above it, out of view (39 degrees off the
    camera's axis, the view's half-angles are 20 and 26 degrees); one light above."""
    b = rt.SceneBuilder("physical", width=width, height=height, spp=spp, max_depth=1, background=(0.0, 0.0, 0.0))
    b.camera(position=(0.0, 2.0, 3.5), look_at=(0.0, 0.0, 0.0), fov=40)
    b.light((0.5, 6.0, 0.0), intensity=(60.0, 56.0, 50.0))
    b.material("floor", color=(0.8, 0.8, 0.8))
    b.material("ball", color=(0.7, 0.2, 0.2))
    b.plane((0, 0, 0), (0, 1, 0), "floor")
    b.sphere(center, 0.5, "ball")
    return b.build()


def error(values):
    return float(np.linalg.norm(np.asarray(values[NAME], float) - np.asarray(TRUE, float)))


def run(width=48, height=36, spp=16, steps=30, out=None, verbose=True):
    target = rt.render(make_scene(width, height, spp))
    start = make_scene(width, height, spp, START)
    results = {}
    for label, kw in (("plain AD", {}), ("edge gradients", {"edge_gradients": True})):

        def report(step, loss, values, label=label):
            if verbose:
                c = np.round(np.asarray(values[NAME], float), 4).tolist()
                print(f"[{label}] step {step:3d}  loss {loss:.3e}  centre {c}  error {error(values):.4f}", flush=True)

        res = rt.fit(
            start,
            target,
            [NAME],
            solver="levenberg_marquardt",
            max_steps=steps,
            progress=False,
            callback=report,
            render_kwargs=kw,
            check=False,
            throw=False,
        )
        err = error(res.params)
        results[label] = (res, err)
        if verbose:
            c = np.round(np.asarray(res.params[NAME], float), 4).tolist()
            print(
                f"[{label}] {res.message}; {res.steps} steps, {res.seconds:.1f} s; "
                f"final centre {c}, truth {list(TRUE)}, error {err:.2e}"
            )
    if out:
        save_figures(out, target, rt.render(start), results, verbose)
    return results


def save_figures(out, target, start_img, results, verbose=True):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # examples/_figures.py
    from _figures import image_grid, pyplot, save

    plt = pyplot()

    panels = [("target", target), ("start", start_img)]
    for label, (res, err) in results.items():
        panels.append((f"{label} (error {err:.2g})", rt.render(res.scene)))
    p1 = image_grid(os.path.join(out, "fit_occluder_from_shadow.png"), panels)
    fig, ax = plt.subplots(figsize=(5, 3.6))
    for label, (res, _) in results.items():
        ax.semilogy(np.maximum(res.loss_history, 1e-30), marker=".", label=label)
    ax.set_xlabel("step")
    ax.set_ylabel("loss (MSE)")
    ax.legend()
    p2 = save(fig, os.path.join(out, "fit_occluder_from_shadow_loss.png"))
    if verbose:
        print(f"saved {p1} and {p2}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=48)
    ap.add_argument("--height", type=int, default=36)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--steps", type=int, default=30, help="maximum solver steps")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "out"))
    a = ap.parse_args(argv)
    t = time.perf_counter()
    run(a.width, a.height, a.spp, a.steps, a.out)
    print(f"total {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
