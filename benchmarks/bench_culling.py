"""The culled search against brute force, on scenes of many primitives.

A kind of more than ``raytrax.intersect.CULL_MIN`` spheres, boxes, quads or disks is
searched in spatial groups that a batch of rays skips when it misses their bounding
box. This script renders the same scenes with it and with brute force
(``CULL_MIN`` set past the primitive count), each measurement in a fresh process,
the two alternating, and prints the first call (compilation included) and the
fastest steady call of each, with their ratios:

* ``spheres N``: ``benchmarks/scenes.many_spheres`` (a floor and N small diffuse
  spheres, one light), forward render at 320 x 240, spp 4, depth 2;
* ``glass``: ``bench_edges.glass_scene`` (a glass ball over a 10 x 10 checker of
  thin boxes, five spheres, one light: 100 boxes), 160 x 120, spp 16, depth 6: the
  forward render, the plain ``value_and_grad`` of an image loss with respect to the
  ball's index, and with ``--edge`` the edge-mode one (the edge finder searches by
  brute force either way; the grid's rays are culled).

    python benchmarks/bench_culling.py [--rounds 2] [--spheres 256,1024,4096] [--edge]
    python benchmarks/bench_culling.py --against one-level --spheres 2048,4096,16384

``--against one-level``: the baseline is the culled search on one level of groups
(``raytrax.intersect.SUPER_MIN`` set past the group count), to measure the second
level, which kinds of more than ``SUPER_MIN`` groups get.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def _time(f, *a, reps=5):
    import jax

    t = time.perf_counter()
    jax.block_until_ready(f(*a))
    first = time.perf_counter() - t
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        jax.block_until_ready(f(*a))
        best = min(best, time.perf_counter() - t)
    return first, best


def worker(cfg):
    sys.path.insert(0, HERE)
    import raytrax.intersect as I

    if not cfg["cull"]:
        if cfg.get("against") == "one-level":
            I.SUPER_MIN = 10**9  # culled, on one level of groups only
        else:
            I.CULL_MIN = 10**9
    import jax
    import jax.numpy as jnp

    import raytrax as rt

    if cfg["scene"] == "spheres":
        import scenes

        s = scenes.many_spheres(cfg["n"], 320, 240, 4, 2)
        kinds = {k.name: k.groups is not None for k in I.prepare(s)}
        return dict(kinds=kinds, time=_time(jax.jit(rt.render), s))
    import bench_edges as BE

    sc = BE.glass_scene(160, 120, 16, 1.3)
    target = rt.render(BE.glass_scene(160, 120, 16, 1.5))

    def with_ior(x):
        return rt.with_parameters(sc, {"material.glass.ior": x})

    x0 = jnp.asarray(1.3, sc.dtype)
    mode = cfg["mode"]
    if mode == "forward":
        f = jax.jit(lambda x: rt.render(with_ior(x)))
    else:
        edge = mode == "edge"
        f = jax.jit(jax.value_and_grad(lambda x: jnp.mean((rt.render(with_ior(x), edge_gradients=edge) - target) ** 2)))
    kinds = {k.name: k.groups is not None for k in I.prepare(sc)}
    return dict(kinds=kinds, time=_time(f, x0, reps=3 if mode == "edge" else 5))


def run(cfg):
    out = subprocess.run(
        [sys.executable, __file__, "--worker", json.dumps(cfg)], capture_output=True, text=True, check=False
    )
    if out.returncode:
        raise RuntimeError(f"worker {cfg} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=2, help="alternating pairs of processes per row")
    p.add_argument("--spheres", default="256,1024,4096", help="sphere counts ('' for none)")
    p.add_argument("--edge", action="store_true", help="also the edge-mode value_and_grad of the glass scene")
    p.add_argument(
        "--against",
        choices=("brute", "one-level"),
        default="brute",
        help="the baseline: brute force, or the culled search on one level of groups (SUPER_MIN set past the count)",
    )
    p.add_argument("--worker", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        print(json.dumps(worker(json.loads(a.worker))))
        return
    rows = [dict(scene="spheres", n=int(n)) for n in a.spheres.split(",") if n]
    if a.against == "brute":  # the glass scene's 100 boxes are one level of groups either way
        rows += [dict(scene="glass", mode=m) for m in ("forward", "value_and_grad") + (("edge",) if a.edge else ())]
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE).stdout
    base = "brute" if a.against == "brute" else "1-level"
    print(f"culled search against {a.against}, git {head.strip()}, {a.rounds} alternating pairs of processes per row")
    print(
        f"{'row':28s} {base + ' steady':>14s} {'culled':>8s} {'speed-up':>9s}   {'first call ' + base + ' / culled':>28s}"
    )
    for row in rows:
        res = {True: [], False: []}
        for _ in range(a.rounds):
            for cull in (False, True):
                res[cull].append(run(row | dict(cull=cull, against=a.against)))
        steady = {c: min(r["time"][1] for r in res[c]) for c in res}
        first = {c: sorted(r["time"][0] for r in res[c])[len(res[c]) // 2] for c in res}
        culled = [k for k, v in res[True][0]["kinds"].items() if v]
        name = f"spheres {row['n']}" if row["scene"] == "spheres" else f"glass {row['mode']}"
        print(
            f"{name:28s} {steady[False]:12.4f} s {steady[True]:7.4f} s {steady[False] / steady[True]:8.2f}x"
            f"   {first[False]:10.2f} / {first[True]:.2f} s   (culled: {', '.join(culled) or 'none'})",
            flush=True,
        )


if __name__ == "__main__":
    main()
