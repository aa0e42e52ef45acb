"""Edge gradients of a sphere's centre and radius against a reference with error bars.

    python benchmarks/bench_sphere_edges.py                  # ~5 min on 2 cores
    python benchmarks/bench_sphere_edges.py --keys 256       # tighter reference
    python benchmarks/bench_sphere_edges.py --light 0,0,5    # light at the camera

Scene: ``scenes/edge_sphere.toml`` (the one ``tests/test_edges.py`` checks): a
Phong sphere in front of a hard-edged checkered wall, one light, 8 x 6 pixels,
classic shading, float64. The scalar is ``L = mean(R * image)`` with ``R`` the
smooth weights of :func:`raytrax.testing.smooth_weights`. Differentiated with
respect to the sphere's centre and radius.

The reference is a central difference of *jittered* renders (``key=``), the same
key on both sides, averaged over ``--keys`` keys: each term is an unbiased
estimate of the difference quotient of the pixel-integrated image, so the mean
has an honest standard error (printed). The grid renders' own difference
quotients are not used: on a regular grid a sphere's silhouette is sampled at
phases that change slowly along it, and their error does not average out.

It also prints the *interior* part alone (plain AD of jittered renders,
averaged; unbiased for the integral of the samples' derivative) beside plain
AD on the grid: the difference is the grid's error on the integrable
singularity of a sphere's hit at its silhouette, which
``edge_gradients=True`` corrects (see ``raytrax/edges.py``, step 6).
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.testing import smooth_weights  # noqa: E402
from scenes import spp_list  # noqa: E402

SCENE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "edge_sphere.toml")
NAMES = ("x", "y", "z", "radius")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keys", type=int, default=64, help="jitter keys averaged by the reference")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--step", type=float, default=0.02, help="FD step, world units (~0.045 pixel)")
    ap.add_argument("--spp", type=spp_list, default=[64, 256, 1024], help="edge-gradient sample counts")

    def xyz(text):
        try:
            v = tuple(float(c) for c in text.split(","))
        except ValueError:
            v = ()
        if len(v) != 3:
            raise argparse.ArgumentTypeError(f"expected three numbers x,y,z, got {text!r}")
        return v

    ap.add_argument(
        "--light",
        type=xyz,
        default=None,
        help="light position x,y,z instead of the scene's (2,3,5); 0,0,5: at the camera, "
        "no terminator or shadow in view",
    )
    a = ap.parse_args()

    s0 = rt.load_scene(SCENE, dtype=jnp.float64)
    if a.light is not None:
        s0 = rt.with_parameters(s0, {"light[0].position": jnp.asarray(a.light, jnp.float64)})
    R = jnp.asarray(smooth_weights(s0.settings.height, s0.settings.width))
    p0 = rt.parameters(s0)
    q0 = jnp.concatenate([p0["object[1].center"], p0["object[1].radius"][None]])

    def loss(q, **kw):
        s = rt.with_parameters(s0, {"object[1].center": q[:3], "object[1].radius": q[3]})
        return jnp.mean(R * rt.render(s, **kw))

    t0 = time.time()
    f = jax.jit(lambda q, key: loss(q, spp=a.ref_spp, key=key))
    fd = np.zeros((a.keys, 4))
    for k in range(a.keys):
        key = jax.random.key(k)
        for i in range(4):
            e = jnp.zeros(4).at[i].set(a.step)
            fd[k, i] = float((f(q0 + e, key) - f(q0 - e, key)) / (2 * a.step))
    ref, ref_se = fd.mean(0), fd.std(0, ddof=1) / np.sqrt(a.keys)
    gi = jax.jit(jax.grad(lambda q, key: loss(q, spp=256, key=key)))
    inner = np.array([np.asarray(gi(q0, jax.random.key(10_000 + k))) for k in range(4 * a.keys)])
    in_ref, in_se = inner.mean(0), inner.std(0, ddof=1) / np.sqrt(len(inner))
    print(
        f"reference: jittered central differences, spp {a.ref_spp}, step {a.step}, {a.keys} keys "
        f"({time.time() - t0:.0f} s)"
    )
    print("  components      =", "  ".join(f"{n:>20}" for n in NAMES))
    print("  d L / d q       =", "  ".join(f"{v:+.6f} +- {e:.6f}" for v, e in zip(ref, ref_se)))
    print(
        "  interior part   =",
        "  ".join(f"{v:+.6f} +- {e:.6f}" for v, e in zip(in_ref, in_se)),
        f"(plain AD of jittered renders, spp 256, {len(inner)} keys)",
    )
    print(f"{'spp':>5}  {'plain AD (grid)':>42}  {'edge gradients':>42}  relative error of edge (x, y, z, radius)")
    for spp in a.spp:
        gp = np.asarray(jax.grad(lambda q: loss(q, spp=spp))(q0))
        ge = np.asarray(jax.grad(lambda q: loss(q, spp=spp, edge_gradients=True))(q0))
        rel = (ge - ref) / np.abs(ref)
        print(
            f"{spp:>5}  {' '.join(f'{v:+.6f}' for v in gp):>42}  {' '.join(f'{v:+.6f}' for v in ge):>42}  "
            + "  ".join(f"{r:+.1%}" for r in rel),
            flush=True,
        )


if __name__ == "__main__":
    main()
