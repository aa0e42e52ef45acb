"""First calls of edge mode in a fresh process, without and with jax's persistent
compilation cache filled by an earlier process.

    python benchmarks/bench_edge_cache.py [--scene edge_occluders] [--size 32x24] [--spp 16]

Runs the same child twice with one new, empty cache folder (``rt.enable_compilation_cache``):
the first process compiles and stores, the second loads. Each child times, in this order, the
plain target render, the first eager ``jax.grad`` of an image loss with ``edge_gradients=True``
(with respect to the first light's position) and the first edge-mode render, and prints them.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def child(scene: str, width: int, height: int, spp: int) -> None:
    import jax
    import jax.numpy as jnp

    import raytrax as rt

    rt.enable_compilation_cache()
    s = rt.load_scene(ROOT / "scenes" / f"{scene}.toml")
    kw = dict(width=width, height=height, spp=spp)
    times = {}

    t = time.perf_counter()
    target = jax.block_until_ready(rt.render(s, **kw))
    times["plain render"] = time.perf_counter() - t

    def loss(p):
        img = rt.render(rt.with_parameters(s, p), edge_gradients=True, **kw)
        return jnp.mean((img - target) ** 2)

    p = {"light[0].position": rt.parameters(s)["light[0].position"]}
    t = time.perf_counter()
    jax.block_until_ready(jax.grad(loss)(p))
    times["eager jax.grad, edge mode"] = time.perf_counter() - t

    t = time.perf_counter()
    jax.block_until_ready(rt.render(s, edge_gradients=True, **kw))
    times["render, edge mode"] = time.perf_counter() - t
    for k, v in times.items():
        print(f"  {k:28s} {v:6.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="edge_occluders")
    ap.add_argument("--size", default="32x24")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))
    if a.child:
        child(a.scene, width, height, a.spp)
        return
    print(f"{a.scene}, {width} x {height}, spp {a.spp}: first calls (s) of two fresh processes sharing one cache")
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=cache)
        for label in ("process 1 (empty cache)", "process 2 (cache filled)"):
            cmd = [sys.executable, __file__, "--child", "--scene", a.scene, "--size", a.size, "--spp", str(a.spp)]
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
            print(label)
            print("\n".join(line for line in out.splitlines() if line.startswith("  ")))


if __name__ == "__main__":
    main()
