"""Recover a texture (1728 texel values) from one noisy image.

A poster with an image texture hangs in front of a wall, lit by a point light,
so the image is the texture times a shading that falls off across the poster.
The target is rendered with the true 24 x 24 texture (a downsampled
scikit-image astronaut) and Gaussian noise is added (``--noise``, standard
deviation in linear units). The fit starts from a uniform grey texture and
minimises the mean squared error with L-BFGS, which needs one reverse-mode
gradient per step whatever the number of parameters (a least-squares solver
would need one forward pass per texel). ``--smooth W`` adds a smoothness prior
(``W`` times the mean squared difference of neighbouring texels) through the
``regularizer`` argument of :func:`raytrax.fit`; on this detailed texture it
trades noise for blur and does not lower the error.

    python examples/fit_texture.py                        # 128 x 96, under a minute
    python examples/fit_texture.py --noise 0.03 --smooth 0.003

Prints the loss and the texture's RMS error (over all texels; the camera sees all)
per step, and saves ``fit_texture.png`` (target / start / fit renders and the
true / start / fitted textures) and ``fit_texture_loss.png`` in ``--out``.
The fitted texture undoes the shading: it is the albedo, not the image.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)  # the solver in float64; the scene stays float32

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402

NAME = "material.poster.texture.image"
TEX = 24


def true_texture(n=TEX):
    img = rt.builtin_image("astronaut")  # (512, 512, 3) linear RGB
    k = img.shape[0] // n
    return img[: n * k, : n * k].reshape(n, k, n, k, 3).mean((1, 3)).astype(np.float32)


def make_scene(width=96, height=72, texture=None):
    tex = true_texture() if texture is None else np.asarray(texture, np.float32)
    b = rt.SceneBuilder("physical", width=width, height=height, spp=1, max_depth=1, background=(0.0, 0.0, 0.0))
    b.camera(position=(1.0, 0.3, 6.0), look_at=(0, 0, 0), fov=40)
    b.light((-1.5, 1.5, 4.5), intensity=(40, 40, 40))
    b.material("poster", color=(1, 1, 1), texture=rt.ImageTexture(tex))
    b.material("wall", color=(0.5, 0.5, 0.5))
    b.plane((0, 0, -0.5), (0, 0, 1), "wall")
    b.quad([(-1.6, -1.6, 0), (1.6, -1.6, 0), (1.6, 1.6, 0), (-1.6, 1.6, 0)], "poster")
    return b.build()


def smoothness(weight):
    """``weight`` times the mean squared difference of neighbouring texels."""

    def reg(values):
        t = values[NAME]
        return weight * (jnp.mean((t[1:] - t[:-1]) ** 2) + jnp.mean((t[:, 1:] - t[:, :-1]) ** 2))

    return reg


def run(width=128, height=96, steps=300, solver="lbfgs", noise=0.01, smooth=0.0, out=None, verbose=True, seed=0):
    scene = make_scene(width, height)
    clean = np.asarray(rt.render(scene))
    rng = np.random.default_rng(seed)
    target = (clean + noise * rng.standard_normal(clean.shape)).astype(np.float32)
    start = make_scene(width, height, texture=np.full((TEX, TEX, 3), 0.3, np.float32))
    truth = true_texture()

    def tex_rmse(tex):
        return float(np.sqrt(np.mean((np.asarray(tex) - truth) ** 2)))

    def report(step, loss, values):
        if verbose and (step % 10 == 0 or step < 5):
            print(f"step {step:4d}  loss {loss:.4e}  texture RMS error {tex_rmse(values[NAME]):.4f}", flush=True)

    res = rt.fit(
        start,
        target,
        [NAME],
        solver=solver,
        max_steps=steps,
        progress=False,
        callback=report,
        regularizer=smoothness(smooth) if smooth > 0 else None,
    )
    err = tex_rmse(res.params[NAME])
    if verbose:
        print(f"{res.message}; {res.steps} steps in {res.seconds:.1f} s (compilation included)")
        print(
            f"  texture RMS error: start {tex_rmse(res.initial_params[NAME]):.4f} -> fit {err:.4f} "
            f"(noise std in the image {noise}); loss {res.loss_history[0]:.3e} -> {res.loss:.3e} "
            f"(noise variance {noise**2:.1e})"
        )
    if out:
        save_figures(out, target, rt.render(start), rt.render(res.scene), truth, res, noise, verbose)
    return res, err


def save_figures(out, target, start_img, fit_img, truth, res, noise=0.0, verbose=True):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # examples/_figures.py
    from _figures import image_grid, pyplot, save

    plt = pyplot()

    row0 = [("noisy target", target), ("start render", start_img), ("fit render", fit_img)]
    row1 = [("true texture", truth), ("start texture", res.initial_params[NAME]), ("fitted texture", res.params[NAME])]
    p1 = image_grid(os.path.join(out, "fit_texture.png"), row0 + row1, rows=2)

    fig, ax = plt.subplots(figsize=(5, 3.6))
    ax.semilogy(res.loss_history, marker=".", label="loss")
    if noise > 0:
        ax.axhline(noise**2, color="grey", ls="--", label="noise variance")
    ax.legend()
    ax.set_xlabel("step")
    ax.set_ylabel("loss (MSE)")
    ax.set_title("texture fit")
    p2 = save(fig, os.path.join(out, "fit_texture_loss.png"))
    if verbose:
        print(f"saved {p1} and {p2}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--steps", type=int, default=300, help="maximum solver steps")
    ap.add_argument("--noise", type=float, default=0.01, help="std of the Gaussian noise added to the target")
    ap.add_argument("--smooth", type=float, default=0.0, help="weight of the smoothness prior (0: none)")
    ap.add_argument("--solver", default="lbfgs", help="lbfgs, bfgs, gradient_descent, nonlinear_cg")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "out"))
    a = ap.parse_args(argv)
    t = time.perf_counter()
    run(a.width, a.height, a.steps, a.solver, a.noise, a.smooth, a.out)
    print(f"total {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
