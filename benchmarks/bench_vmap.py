"""``jax.vmap`` of a render over one scene parameter against a Python loop of renders.

For each kind of parameter (an IOR, a colour, a sphere radius, the camera
position, a light position) a batch of ``--batch`` values of the *physical*
scene (mirror and glass, two lights) is rendered once with ``jax.vmap`` and once
as a loop of single renders (both jitted and warmed up first), and the script
prints the time per image of each and their ratio, with process CPU time beside
wall time (the CPU time is the steadier figure on a shared machine).

With ``--grad`` the same is done for the gradient of the image's mean with
respect to the parameter (``jax.vmap(jax.grad(...))`` against a loop of
``jax.grad``).

    python benchmarks/bench_vmap.py [--size 160x120] [--spp 4] [--batch 8] [--repeat 3] [--grad]
"""

from __future__ import annotations

import argparse
import resource
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import raytrax as rt
from scenes import physical_scene


def _cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _time(fn, repeat):
    jax.block_until_ready(fn())
    best = (float("inf"), float("inf"))
    for _ in range(repeat):
        c0, t0 = _cpu(), time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, (time.perf_counter() - t0, _cpu() - c0))
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--depth", type=int, default=6)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--grad", action="store_true", help="time gradients of the image mean instead of renders")
    a = ap.parse_args(argv)
    W, H = (int(x) for x in a.size.split("x"))
    s = physical_scene(W, H, a.spp, a.depth)
    N = a.batch
    u = jnp.linspace(0.0, 1.0, N, dtype=jnp.float32)
    cases = {
        "ior": (lambda x: eqx.tree_at(lambda s: s.materials.ior, s, s.materials.ior.at[5].set(x)), 1.2 + 0.6 * u),
        "colour": (
            lambda x: eqx.tree_at(lambda s: s.materials.color, s, s.materials.color.at[1].set(x)),
            jnp.stack([u, 1.0 - u, 0.5 + 0.0 * u], 1),
        ),
        "radius": (lambda x: eqx.tree_at(lambda s: s.spheres.radius, s, s.spheres.radius.at[2].set(x)), 0.4 + 0.4 * u),
        "camera": (
            lambda x: eqx.tree_at(lambda s: s.camera.position, s, x),
            s.camera.position[None] + jnp.stack([u - 0.5, 0.0 * u, 0.0 * u], 1),
        ),
        "light": (
            lambda x: eqx.tree_at(lambda s: s.lights.position, s, s.lights.position.at[0].set(x)),
            s.lights.position[0][None] + jnp.stack([2.0 * u - 1.0, 0.0 * u, 0.0 * u], 1),
        ),
    }
    what = "gradient of the image mean" if a.grad else "render"
    print(f"raytrax {rt.__version__}, jax {jax.__version__}, {W}x{H} spp {a.spp} depth {a.depth}, batch {N}: {what}")
    print(f"{'parameter':10s} {'loop s/img':>11s} {'vmap s/img':>11s} {'vmap/loop':>10s}   (wall; CPU in brackets)")
    for name, (make, xs) in cases.items():
        if a.grad:
            one = jax.jit(jax.grad(lambda x, make=make: jnp.sum(rt.render(make(x))) / (W * H * 3)))
        else:
            one = jax.jit(lambda x, make=make: rt.render(make(x)))
        many = jax.jit(jax.vmap(one))
        diff = float(np.abs(np.stack([np.asarray(one(x)) for x in xs]) - np.asarray(many(xs))).max())
        tl = _time(lambda: [one(x) for x in xs], a.repeat)
        tv = _time(lambda: many(xs), a.repeat)
        print(
            f"{name:10s} {tl[0] / N:11.4f} {tv[0] / N:11.4f} {tv[0] / tl[0]:10.2f}   "
            f"({tl[1] / N:.4f} {tv[1] / N:.4f} {tv[1] / tl[1]:.2f})  max |vmap - loop| {diff:.1e}",
            flush=True,
        )


if __name__ == "__main__":
    main()
