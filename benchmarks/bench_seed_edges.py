"""Edge gradients on the seed scene (``scenes/cosc363.toml``), a scene not made for them.

    python benchmarks/bench_seed_edges.py [--size 64x48] [--spp 16,64,256] [--ref-spp 2304]
                                          [--floor plane|quad] [--filter both|on|off]

Differentiates ``L = mean(R * image)`` (``R``: :func:`raytrax.testing.smooth_weights`,
float64) with respect to the first light's position and the centre of the large
mirror sphere (``object[1]``: reflectivity 0.5, radius 15, resting on the
checkered floor), by plain AD and with ``edge_gradients=True`` at each ``--spp``,
against central differences of renders at ``--ref-spp`` with steps 0.3 and 0.15
world units (edges move 0.1-0.2 pixel at 64 x 48; the two steps agreeing shows
the reference has converged). It does so with the scene's filtered textures
(``filter_textures=True``, its default) and with hard ones.

``--floor quad`` replaces the infinite floor plane by a 1000 x 1000 quad with
the same 5-unit checker: the horizon of an infinite plane is an edge that edge
mode leaves out (docs/gradients.md), and the mirror shows it.
"""

from __future__ import annotations

import argparse
import os
import re
import tempfile
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.testing import smooth_weights  # noqa: E402

SEED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "cosc363.toml")
NAMES = ("light[0].position", "object[1].center")
STEPS = (0.3, 0.15)

_PLANE = re.compile(r'type = "plane"\nmaterial = "floor"\npoint = \[0.0, -15.0, 0.0\]\nnormal = \[0.0, 1.0, 0.0\]')
_QUAD = (
    'type = "quad"\nmaterial = "floor"\n'
    "corners = [[-500.0, -15.0, 500.0], [500.0, -15.0, 500.0], [500.0, -15.0, -500.0], [-500.0, -15.0, -500.0]]"
)


def seed_scene(width, height, floor="plane", filtered=True):
    """The seed scene in float64 at ``width x height``; ``floor="quad"``: the floor plane
    replaced by a 1000 x 1000 quad with the same checker (a quad's checker scale counts
    cells per side, a plane's cells per world unit)."""
    text = open(SEED).read()
    if floor == "quad":
        text, n = _PLANE.subn(_QUAD, text)
        text = text.replace("scale = 0.2 }", "scale = 200.0 }")
        assert n == 1, "the seed scene's floor plane was not found"
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "seed.toml")
        with open(path, "w") as f:
            f.write(text)
        s = rt.load_scene(path, dtype=jnp.float64)
    return s.replace_settings(width=width, height=height, filter_textures=filtered)


def comps(tree):
    return np.concatenate([np.ravel(np.asarray(tree[k])) for k in NAMES])


def measure(sc, spps, ref_spp):
    H, W = sc.settings.height, sc.settings.width
    R = jnp.asarray(smooth_weights(H, W), sc.dtype)
    p = rt.parameters(sc)
    q0 = {k: p[k] for k in NAMES}

    def loss(q, **kw):
        return jnp.mean(R * rt.render(rt.with_parameters(sc, q), **kw))

    rows = {}
    for spp in spps:
        for edge in (False, True):
            t = time.perf_counter()
            g = jax.jit(jax.grad(lambda q: loss(q, spp=spp, edge_gradients=edge)))(q0)
            rows[("edge" if edge else "plain", spp)] = (comps(g), time.perf_counter() - t)
    ref = jax.jit(lambda q: loss(q, spp=ref_spp))
    for h in STEPS:
        out = []
        for k in NAMES:
            v = np.asarray(q0[k])
            for c in range(v.size):
                e = jnp.asarray(np.eye(v.size)[c].reshape(v.shape) * h)
                out.append(float((ref(q0 | {k: q0[k] + e}) - ref(q0 | {k: q0[k] - e})) / (2 * h)))
        rows[("FD", h)] = (np.asarray(out), 0.0)
    return rows


def report(rows, title):
    labels = [f"{n.split('.')[0]} {c}" for n in NAMES for c in "xyz"]
    fd = rows[("FD", STEPS[0])][0]
    print(f"\n== {title} ==")
    print(f"{'':16s}" + "".join(f"{x:>12s}" for x in labels))
    for (what, arg), (g, dt) in rows.items():
        name = f"FD step {arg}" if what == "FD" else f"{what} spp {arg}"
        print(f"{name:16s}" + "".join(f"{x:+12.3e}" for x in g) + (f"   ({dt:.0f} s)" if dt else ""))
        if what != "FD":
            print(f"{'  rel. error':16s}" + "".join(f"{(x - r) / abs(r):+12.1%}" for x, r in zip(g, fd)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="64x48")
    ap.add_argument("--spp", default="16,64,256")
    ap.add_argument("--ref-spp", type=int, default=2304)
    ap.add_argument("--floor", choices=("plane", "quad"), default="plane")
    ap.add_argument("--filter", choices=("both", "on", "off"), default="both")
    a = ap.parse_args(argv)
    W, H = (int(x) for x in a.size.split("x"))
    spps = [int(x) for x in a.spp.split(",")]
    print(f"seed scene {W} x {H}, floor {a.floor}, float64; L = mean(R * image); jax {jax.__version__}")
    for filtered in {"both": (True, False), "on": (True,), "off": (False,)}[a.filter]:
        sc = seed_scene(W, H, a.floor, filtered)
        report(measure(sc, spps, a.ref_spp), f"filter_textures={filtered}")


if __name__ == "__main__":
    main()
