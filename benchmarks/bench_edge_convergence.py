"""Convergence of an edge gradient with the sample count, where spp 256 is far off.

    python benchmarks/bench_edge_convergence.py                 # ~8 min on 2 cores
    python benchmarks/bench_edge_convergence.py --keys 64 --ref-spp 9216

Scene: ``scenes/edge_occluders.toml`` (the FD test's scene), float64, the loss
``mean(R * image)`` of ``tests/test_edges.py``. Differentiated with respect to one
component of the sphere's centre (``--component``, default 0: x, the component that
test lists as a known miss at spp 256: 3 % of the centre gradient, on a ball 3
pixels across whose silhouette is crossed by two terminators and a shadow edge).

The reference is a central difference of jittered renders (the same key on both
sides) averaged over ``--keys`` keys, with its standard error. The edge gradient
is computed on the regular grids of spp 256, 1024, 2304 and 4096 (sample spacing
``h = 1/sqrt(spp)`` pixel); the script prints each one's error against the
reference, the least-squares order ``p`` of ``|error| ~ h^p`` and the Richardson
extrapolation of the two finest grids with that order.
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

SCENE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "edge_occluders.toml")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--component", type=int, choices=(0, 1, 2), default=0, help="centre component: 0 x, 1 y, 2 z")
    ap.add_argument("--keys", type=int, default=128, help="jitter keys averaged by the reference")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--step", type=float, default=0.03, help="FD step, world units (~0.1 pixel)")
    ap.add_argument(
        "--spp", type=spp_list, default=[256, 1024, 2304, 4096], help="edge-gradient sample counts (square numbers)"
    )
    a = ap.parse_args()

    s0 = rt.load_scene(SCENE, dtype=jnp.float64)
    R = jnp.asarray(smooth_weights(s0.settings.height, s0.settings.width))
    c0 = rt.parameters(s0)["object[1].center"]
    e = jnp.zeros(3, jnp.float64).at[a.component].set(1.0)

    def loss(t, **kw):
        return jnp.mean(R * rt.render(rt.with_parameters(s0, {"object[1].center": c0 + t * e}), **kw))

    t0 = time.time()
    f = jax.jit(lambda t, key: loss(t, spp=a.ref_spp, key=key))
    fd = np.array(
        [float((f(a.step, k) - f(-a.step, k)) / (2 * a.step)) for k in (jax.random.key(i) for i in range(a.keys))]
    )
    ref, se = fd.mean(), fd.std(ddof=1) / np.sqrt(a.keys)
    print(
        f"sphere centre[{a.component}]: reference {ref:+.6f} +- {se:.6f} (jittered central differences, "
        f"spp {a.ref_spp}, step {a.step}, {a.keys} keys, {time.time() - t0:.0f} s)",
        flush=True,
    )
    print(f"{'spp':>5}  {'h (pixel)':>9}  {'edge gradient':>13}  {'error':>9}  {'relative':>8}")
    hs, errs = [], []
    zero = jnp.asarray(0.0, jnp.float64)
    for spp in a.spp:
        g = float(jax.grad(lambda t: loss(t, spp=spp, edge_gradients=True))(zero))
        h = 1.0 / np.sqrt(spp)
        hs.append(h)
        errs.append(g - ref)
        print(f"{spp:>5}  {h:>9.4f}  {g:>+13.6f}  {g - ref:>+9.6f}  {(g - ref) / abs(ref):>+8.1%}", flush=True)
    if len(hs) >= 2 and all(abs(v) > 2 * se for v in errs):
        p = np.polyfit(np.log(hs), np.log(np.abs(errs)), 1)[0]
        print(f"order of convergence (least squares, |error| ~ h^p): p = {p:.2f}")
        # Richardson extrapolation from the two finest grids with that order.
        r = (hs[-2] / hs[-1]) ** p
        g1, g2 = errs[-2] + ref, errs[-1] + ref
        print(
            f"extrapolated to h = 0 from spp {a.spp[-2]} and {a.spp[-1]}: "
            f"{(r * g2 - g1) / (r - 1):+.6f} (reference {ref:+.6f} +- {se:.6f})"
        )
    else:
        print("order of convergence: not fitted (an error is within two standard errors of the reference)")


if __name__ == "__main__":
    main()
