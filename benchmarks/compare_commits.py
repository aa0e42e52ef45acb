"""raytrax at two git revisions, alternating, in process CPU time.

    python benchmarks/compare_commits.py ae7eae7 HEAD [--size 640x480] [--grad-size 320x240] [--rounds 2]

Each revision is checked out into a temporary ``git worktree`` and measured in
a fresh subprocess (``PYTHONPATH`` pointing at it), the two alternating for
``--rounds`` rounds. Measured on the *physical* scene of ``benchmarks/scenes.py``
(spp 4, depth 6): one forward render, and ``value_and_grad`` of an image MSE
with respect to the light positions and the IORs; the first call (compilation
included) and the best of three steady calls. Process CPU time (all threads) is
reported beside wall time: on a shared machine it moves much less with the load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

WORKER = r"""
import json, resource, sys, time
sys.path.insert(0, sys.argv[1])
import equinox as eqx, jax, jax.numpy as jnp
import raytrax as rt
from scenes import physical_scene

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime

def timed(fn):
    c, t = cpu(), time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t, cpu() - c

def measure(fn):
    first = timed(fn)
    steady = min(timed(fn) for _ in range(3))
    return {"first_wall": first[0], "first_cpu": first[1], "wall": steady[0], "cpu": steady[1]}

W, H, GW, GH = (int(x) for x in sys.argv[2:6])
s = physical_scene(W, H, 4, 6)
out = {"forward": measure(lambda: rt.render(s))}
g = physical_scene(GW, GH, 4, 6)
target = rt.render(g)

def loss(lp, ior):
    sc = eqx.tree_at(lambda q: q.lights.position, g, lp)
    sc = eqx.tree_at(lambda q: q.materials.ior, sc, ior)
    return jnp.mean((rt.render(sc) - target) ** 2)

vg = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
lp, ior = g.lights.position + 0.3, g.materials.ior * 1.02
out["value_and_grad"] = measure(lambda: vg(lp, ior))
print(json.dumps(out))
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("revs", nargs=2, help="two git revisions (e.g. ae7eae7 HEAD)")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--grad-size", default="320x240")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args(argv)
    W, H = a.size.split("x")
    GW, GH = a.grad_size.split("x")
    results = {r: [] for r in a.revs}
    with tempfile.TemporaryDirectory() as tmp:
        trees = {}
        for i, r in enumerate(a.revs):
            trees[r] = os.path.join(tmp, f"rev{i}")
            subprocess.run(["git", "-C", ROOT, "worktree", "add", "-q", "--detach", trees[r], r], check=True)
        try:
            for _ in range(a.rounds):
                for r in a.revs:
                    env = dict(os.environ, PYTHONPATH=trees[r])
                    p = subprocess.run(
                        [sys.executable, "-c", WORKER, HERE, W, H, GW, GH],
                        env=env,
                        cwd=tmp,
                        capture_output=True,
                        text=True,
                        check=True,
                    )
                    results[r].append(json.loads(p.stdout.strip().splitlines()[-1]))
        finally:
            for r in a.revs:
                subprocess.run(["git", "-C", ROOT, "worktree", "remove", "--force", trees[r]], check=False)
    print(f"physical scene, spp 4, depth 6; forward {a.size}, value_and_grad {a.grad_size}; best of {a.rounds} rounds")
    print(f"{'revision':12s} {'task':15s} {'CPU s':>8s} {'wall s':>8s} {'first CPU s':>12s} {'first wall s':>13s}")
    for task in ("forward", "value_and_grad"):
        for r in a.revs:
            best = min(results[r], key=lambda x: x[task]["cpu"])[task]
            print(
                f"{r:12s} {task:15s} {best['cpu']:8.3f} {best['wall']:8.3f} {best['first_cpu']:12.2f} {best['first_wall']:13.2f}"
            )
    for task in ("forward", "value_and_grad"):
        c = [min(x[task]["cpu"] for x in results[r]) for r in a.revs]
        print(f"{task}: {a.revs[0]} / {a.revs[1]} CPU time = {c[0] / c[1]:.2f}")


if __name__ == "__main__":
    main()
