"""Edge gradients (``render(..., edge_gradients=True)``): accuracy and cost against plain AD.

    python benchmarks/bench_edges.py                      # accuracy (16 x 12) and cost (64 x 48), ~10 min
    python benchmarks/bench_edges.py --no-accuracy --cost-size 128x96
    python benchmarks/bench_edges.py --no-accuracy --no-cost --calls glass,edge_occluders,edge_sphere --calls-size 64x48

Scene: a checkered floor under two lights with a sphere, a lifted rotated box and
a tetrahedron (classic shading, depth 1, float64). The scalar differentiated is
``L = mean(R * image)`` with ``R`` a fixed random image (what one step of any image
loss sees).

* accuracy: ``jax.grad`` of ``L`` with respect to both light positions, the
  sphere's centre and radius and a translation of the box, by plain AD and with
  edge gradients at spp 16 / 64 / 256, against central differences of renders
  at spp ``--ref-spp`` (default 9216, a 96 x 96 grid per pixel) with step
  ``--step`` (0.015 world units: edges move 5-10 of the reference's sample rows),
  and at half the step and at spp 16384 to show the reference has converged.
  The weights ``R`` are smooth over the image: a per-pixel random weight makes
  the loss kink wherever an edge crosses a pixel boundary, and then no finite
  step converges;
* calls: ``value_and_grad`` of an image loss, plain AD against
  ``edge_gradients=True``, each in a fresh process: the first call (compilation
  included), the median of 3 further calls and the process's peak resident memory;
  on ``glass`` (a glass ball, ior 1.5, over a 10 x 10 checker of thin boxes with
  five small balls behind it, one point light, depth 6: the loss is the MSE against
  the image at ior 1.5, differentiated with respect to the ior at 1.30) and on the
  scenes ``edge_occluders`` and ``edge_sphere`` (the loss above); ``--calls-devices N``
  renders on ``N`` devices instead of ``render``'s default;
* cost: compile time, steady time (median of 3) and XLA's temporary memory
  (``compiled.memory_analysis()``) of ``value_and_grad`` with and without edge
  gradients at the same spp, and of the forward render. Ratios are what to
  compare: the machine is shared.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.testing import smooth_weights  # noqa: E402


def scene(width, height, spp, dtype=jnp.float64):
    """``scenes/edge_occluders.toml`` (the scene of tests/test_edges.py) at another size."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "edge_occluders.toml")
    return rt.load_scene(path, dtype=dtype).replace_settings(width=width, height=height, spp=spp)


def make_loss(sc):
    p = rt.parameters(sc)
    H, W = sc.settings.height, sc.settings.width
    R = jnp.asarray(smooth_weights(H, W), sc.dtype)
    q0 = {
        "light0": p["light[0].position"],
        "light1": p["light[1].position"],
        "center": p["object[1].center"],
        "radius": p["object[1].radius"],
        "box": jnp.zeros(3, sc.dtype),
    }

    def loss(q, **kw):
        s = rt.with_parameters(
            sc,
            {
                "light[0].position": q["light0"],
                "light[1].position": q["light1"],
                "object[1].center": q["center"],
                "object[1].radius": q["radius"],
                "object[2].min": p["object[2].min"] + q["box"],
                "object[2].max": p["object[2].max"] + q["box"],
            },
        )
        return jnp.mean(R * rt.render(s, **kw))

    return loss, q0


def flat(g):
    return np.concatenate(
        [np.atleast_1d(np.asarray(g[k], float)) for k in ("light0", "light1", "center", "radius", "box")]
    )


LABELS = [
    f"{n}[{i}]" for n, k in (("light0", 3), ("light1", 3), ("center", 3), ("radius", 1), ("box", 3)) for i in range(k)
]


def fd(loss, q0, spp, step):
    f = jax.jit(lambda q: loss(q, spp=spp))
    out = []
    for name in ("light0", "light1", "center", "radius", "box"):
        v = jnp.atleast_1d(q0[name])
        for c in range(v.shape[0]):
            e = jnp.zeros_like(v).at[c].set(step).reshape(jnp.shape(q0[name]))
            out.append(float((f(q0 | {name: q0[name] + e}) - f(q0 | {name: q0[name] - e})) / (2 * step)))
    return np.array(out)


def accuracy(a):
    sc = scene(16, 12, 16)
    loss, q0 = make_loss(sc)
    cols = {}
    t = time.perf_counter()
    cols["plain AD (spp 64)"] = flat(jax.grad(lambda q: loss(q, spp=64))(q0))
    for spp in (16, 64, 256):
        cols[f"edge spp {spp}"] = flat(jax.grad(lambda q: loss(q, spp=spp, edge_gradients=True))(q0))
        print(f"  edge spp {spp} done ({time.perf_counter() - t:.0f} s)", flush=True)
    ref = fd(loss, q0, a.ref_spp, a.step)
    ref2 = fd(loss, q0, a.ref_spp, a.step / 2)
    ref3 = fd(loss, q0, 16384, a.step)
    print(
        f"\nAccuracy, 16 x 12, reference: central differences at spp {a.ref_spp}, step {a.step} "
        f"(and half the step, and spp 16384, to show convergence); relative error in brackets\n"
    )
    head = ["component", f"FD {a.step}", f"FD {a.step / 2}", "FD spp 16384"] + list(cols)
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    worst = {k: 0.0 for k in cols}
    for i, lab in enumerate(LABELS):
        cells = [
            lab,
            f"{ref[i]:+.5f}",
            f"{ref2[i]:+.5f} ({(ref2[i] - ref[i]) / ref[i]:+.1%})",
            f"{ref3[i]:+.5f} ({(ref3[i] - ref[i]) / ref[i]:+.1%})",
        ]
        for k, v in cols.items():
            e = (v[i] - ref[i]) / ref[i]
            worst[k] = max(worst[k], abs(e))
            cells.append(f"{v[i]:+.5f} ({e:+.1%})")
        print("| " + " | ".join(cells) + " |")
    print("\nlargest relative error per column: " + ", ".join(f"{k}: {v:.1%}" for k, v in worst.items()))


def _compiled(fn, q0):
    t = time.perf_counter()
    c = jax.jit(fn, compiler_options=rt.compiler_options()).lower(q0).compile()  # as raytrax's own jits
    ct = time.perf_counter() - t
    times = []
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(c(q0))
        times.append(time.perf_counter() - t)
    mem = c.memory_analysis()
    temp = getattr(mem, "temp_size_in_bytes", float("nan")) / 2**20 if mem is not None else float("nan")
    return ct, statistics.median(times), temp


def cost(a):
    W, H = (int(x) for x in a.cost_size.split("x"))
    sc = scene(W, H, a.cost_spp, jnp.float32)
    loss, q0 = make_loss(sc)
    rows = [
        ("forward render", lambda q: loss(q)),
        ("value_and_grad, plain AD", jax.value_and_grad(lambda q: loss(q))),
        ("value_and_grad, edge_gradients=True", jax.value_and_grad(lambda q: loss(q, edge_gradients=True))),
    ]
    print(f"\nCost, {W} x {H}, spp {a.cost_spp}, float32 (compile s, steady s, XLA temp MiB)\n")
    print("| what | compile (s) | time (s) | temp memory (MiB) |\n|---|---|---|---|")
    res = {}
    for name, fn in rows:
        res[name] = _compiled(fn, q0)
        print(f"| {name} | {res[name][0]:.1f} | {res[name][1]:.3f} | {res[name][2]:.1f} |", flush=True)
    p, e = res["value_and_grad, plain AD"], res["value_and_grad, edge_gradients=True"]
    f = res["forward render"]
    print(
        f"\nedge / plain gradient: time {e[1] / p[1]:.2f}x, compile {e[0] / p[0]:.2f}x, memory {e[2] / p[2]:.2f}x; "
        f"edge gradient / forward render: {e[1] / f[1]:.2f}x"
    )


def glass_scene(width, height, spp, ior, depth=6):
    """``scenes/glass_over_boxes.toml`` (a glass ball, ``material.glass.ior``, over a
    10 x 10 checker of thin boxes, five small balls behind it, one point light; 107
    objects) at this size."""
    s = rt.load_scene(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "glass_over_boxes.toml"))
    s = s.replace_settings(width=width, height=height, spp=spp, max_depth=depth)
    return rt.with_parameters(s, {"material.glass.ior": ior})


def one_call(name, W, H, spp, edge, devices=None):
    """First and steady time of ``value_and_grad`` and peak RSS, in this process (a child);
    ``devices``: the renders' ``devices`` (None: their default)."""
    import resource

    if name == "glass":
        sc = glass_scene(W, H, spp, 1.3)
        target = rt.render(glass_scene(W, H, spp, 1.5))

        def loss_glass(x):
            s = rt.with_parameters(sc, {"material.glass.ior": x})
            return jnp.mean((rt.render(s, edge_gradients=edge, devices=devices) - target) ** 2)

        loss, q0 = loss_glass, jnp.asarray(1.3, sc.dtype)
    else:
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", f"{name}.toml")
        sc = rt.load_scene(path, dtype=jnp.float32).replace_settings(width=W, height=H, spp=spp)
        if name == "edge_occluders":
            lo, q0 = make_loss(sc)

            def loss_scene(q):
                return lo(q, edge_gradients=edge, devices=devices)

        else:  # any other scene: every light position and object's geometry, a smooth-weighted image sum
            wgt = jnp.asarray(smooth_weights(H, W), sc.dtype)
            q0 = {k: v for k, v in rt.parameters(sc).items() if k.startswith("object[") or k.endswith("].position")}

            def loss_scene(q):
                return jnp.mean(wgt * rt.render(rt.with_parameters(sc, q), edge_gradients=edge, devices=devices))

        loss = loss_scene

    f = jax.jit(jax.value_and_grad(loss))
    t = time.perf_counter()
    jax.block_until_ready(f(q0))
    first = time.perf_counter() - t
    times = []
    for _ in range(3):
        t = time.perf_counter()
        v, g = jax.block_until_ready(f(q0))
        times.append(time.perf_counter() - t)
    g = float(g) if name == "glass" else float(sum(np.abs(np.asarray(x)).sum() for x in jax.tree.leaves(g)))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return first, statistics.median(times), rss, g


def calls(a):
    import json
    import subprocess
    import sys

    W, H = (int(x) for x in a.calls_size.split("x"))
    print(f"\nvalue_and_grad, {W} x {H}, spp {a.calls_spp}, float32, each in a fresh process\n")
    print(
        "| scene | plain first (s) | edge first (s) | ratio | plain steady (s) | edge steady (s) | ratio "
        "| plain peak RSS (GiB) | edge peak RSS (GiB) | plain grad | edge grad |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in a.calls.split(","):
        out = {}
        for edge in (False, True):
            one = f"{name},{W},{H},{a.calls_spp},{int(edge)}" + (f",{a.calls_devices}" if a.calls_devices else "")
            cmd = [sys.executable, os.path.abspath(__file__), "--one", one]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode:
                sys.exit(f"{' '.join(cmd[1:])} failed:\n{res.stderr[-3000:]}")
            out[edge] = json.loads(res.stdout.strip().splitlines()[-1])
        p, e = out[False], out[True]
        print(
            f"| {name} | {p[0]:.1f} | {e[0]:.1f} | {e[0] / p[0]:.2f} | {p[1]:.2f} | {e[1]:.2f} | {e[1] / p[1]:.2f} "
            f"| {p[2]:.2f} | {e[2]:.2f} | {p[3]:+.5f} | {e[3]:+.5f} |",
            flush=True,
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--no-accuracy", action="store_true")
    ap.add_argument("--no-cost", action="store_true")
    ap.add_argument("--ref-spp", type=int, default=9216)
    ap.add_argument("--step", type=float, default=0.015)
    ap.add_argument("--cost-size", default="64x48")
    ap.add_argument("--cost-spp", type=int, default=16)
    ap.add_argument("--calls", default="", help="comma-separated: glass and/or scenes/*.toml names")
    ap.add_argument("--calls-size", default="64x48")
    ap.add_argument("--calls-spp", type=int, default=16)
    ap.add_argument("--calls-devices", type=int, default=0, help="the renders' devices (0: their default)")
    ap.add_argument("--one", default="", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        import json

        name, W, H, spp, edge, *dev = a.one.split(",")
        devices = int(dev[0]) if dev else None
        print(json.dumps(one_call(name, int(W), int(H), int(spp), bool(int(edge)), devices)))
        return
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}")
    if not a.no_accuracy:
        accuracy(a)
    if not a.no_cost:
        cost(a)
    if a.calls:
        calls(a)


if __name__ == "__main__":
    main()
