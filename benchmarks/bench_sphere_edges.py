"""Edge gradients of a lone sphere against a reference with error bars.

    python benchmarks/bench_sphere_edges.py              # ~4 min on 2 cores
    python benchmarks/bench_sphere_edges.py --keys 64    # tighter reference

Scene: one Phong-shaded sphere over a flat background, one light, 8 x 6 pixels,
classic shading, float64. The scalar is ``L = mean(R * image)`` with ``R`` the
smooth weights of :func:`raytrax.testing.smooth_weights`. Differentiated with
respect to the sphere's centre.

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
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.testing import smooth_weights  # noqa: E402

W, H = 8, 6


def scene(light=(2.0, 3.0, 5.0)):
    b = rt.SceneBuilder("classic", width=W, height=H, spp=256, max_depth=0, background=(0.2, 0.2, 0.25))
    b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=30)
    b.light(light, intensity=(0.8, 0.8, 0.8))
    b.material("red", color=(0.8, 0.3, 0.2), specular=0.3, shininess=20)
    b.sphere((0.1, 0.05, 0), 0.8, "red")
    return b.build(dtype=jnp.float64)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keys", type=int, default=32, help="jitter keys averaged by the reference")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--step", type=float, default=0.01, help="FD step, world units (~0.02 pixel)")
    ap.add_argument("--spp", default="64,256,1024", help="edge-gradient sample counts")
    def xyz(text):
        try:
            v = tuple(float(c) for c in text.split(","))
        except ValueError:
            v = ()
        if len(v) != 3:
            raise argparse.ArgumentTypeError(f"expected three numbers x,y,z, got {text!r}")
        return v

    ap.add_argument("--light", type=xyz, default=(2.0, 3.0, 5.0),
                    help="light position x,y,z (0,0,5: at the camera, no terminator in view)")
    a = ap.parse_args()

    s0 = scene(a.light)
    R = jnp.asarray(smooth_weights(H, W))
    c0 = rt.parameters(s0)["object[0].center"]

    def loss(c, **kw):
        return jnp.mean(R * rt.render(rt.with_parameters(s0, {"object[0].center": c}), **kw))

    t0 = time.time()
    f = jax.jit(lambda c, key: loss(c, spp=a.ref_spp, key=key))
    fd = np.zeros((a.keys, 3))
    for k in range(a.keys):
        key = jax.random.key(k)
        for i in range(3):
            e = jnp.zeros(3).at[i].set(a.step)
            fd[k, i] = float((f(c0 + e, key) - f(c0 - e, key)) / (2 * a.step))
    ref, ref_se = fd.mean(0), fd.std(0, ddof=1) / np.sqrt(a.keys)
    gi = jax.jit(jax.grad(lambda c, key: loss(c, spp=256, key=key)))
    inner = np.array([np.asarray(gi(c0, jax.random.key(10_000 + k))) for k in range(16 * a.keys)])
    in_ref, in_se = inner.mean(0), inner.std(0, ddof=1) / np.sqrt(len(inner))
    print(f"reference: jittered central differences, spp {a.ref_spp}, step {a.step}, {a.keys} keys "
          f"({time.time() - t0:.0f} s)")
    print("  d L / d centre  =", "  ".join(f"{v:+.6f} +- {e:.6f}" for v, e in zip(ref, ref_se)))
    print("  interior part   =", "  ".join(f"{v:+.6f} +- {e:.6f}" for v, e in zip(in_ref, in_se)),
          f"(plain AD of jittered renders, spp 256, {len(inner)} keys)")
    print(f"{'spp':>5}  {'plain AD (grid)':>32}  {'edge gradients':>32}  relative error of edge (x, y, z)")
    for spp in (int(v) for v in a.spp.split(",")):
        gp = np.asarray(jax.grad(lambda c: loss(c, spp=spp))(c0))
        ge = np.asarray(jax.grad(lambda c: loss(c, spp=spp, edge_gradients=True))(c0))
        rel = (ge - ref) / np.abs(ref)
        print(f"{spp:>5}  {' '.join(f'{v:+.6f}' for v in gp):>32}  {' '.join(f'{v:+.6f}' for v in ge):>32}  "
              + "  ".join(f"{r:+.1%}" for r in rel), flush=True)


if __name__ == "__main__":
    main()
