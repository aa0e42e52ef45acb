"""Peak memory of reverse mode: a forward render vs ``value_and_grad`` of an image loss.

    python benchmarks/bench_grad_memory.py                    # 512x512, spp 4, depth 5, the seed scene
    python benchmarks/bench_grad_memory.py --tiles 4096,16384,65536 --no-run
    python benchmarks/bench_grad_memory.py --size 128x128 --json out.json

The renderer splits the image into tiles of ``tile_rays`` camera rays
(``lax.map`` over tiles, each tile under ``jax.checkpoint``), so reverse mode
keeps one tile's intermediate values at a time instead of every ray of every
bounce of the image. This script measures what that costs, each case in a fresh
subprocess:

* ``temp``: the compiled program's temporary buffers (XLA
  ``memory_analysis().temp_size_in_bytes``): the working memory the render or
  its gradient needs beyond its inputs and outputs. No execution needed.
* ``args`` / ``out``: argument and output buffer sizes.
* ``peak RSS``: the subprocess's ``ru_maxrss`` after compiling and running it
  once (includes Python, jax, the XLA compiler's own peak and the scene), and
  ``RSS before``: the resident size just before compiling. ``run``: seconds for
  one execution after compilation.

The forward case is ``render(scene)``; the gradient case is
``value_and_grad`` of ``mean((render(scene) - target)^2)`` with respect to
every float leaf of the scene (``eqx.partition(scene, eqx.is_inexact_array)``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def _rss_mib(field="VmRSS"):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def run_case(kind, scene_path, width, height, spp, depth, tile, execute):
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import raytrax as rt

    scene = rt.load_scene(scene_path).replace_settings(width=width, height=height, spp=spp, max_depth=depth)
    params, static = eqx.partition(scene, eqx.is_inexact_array)
    target = jnp.full((height, width, 3), 0.25, jnp.float32)

    def image(p):
        return rt.render(eqx.combine(p, static), tile_rays=tile)

    if kind == "forward":
        fn = jax.jit(image)
        args = (params,)
    else:

        def loss(p, t):
            return jnp.mean((image(p) - t) ** 2)

        fn = jax.jit(jax.value_and_grad(loss))
        args = (params, target)
    rss_before = _rss_mib()
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    m = compiled.memory_analysis()
    out = dict(
        kind=kind,
        tile_rays=tile,
        width=width,
        height=height,
        spp=spp,
        max_depth=depth,
        compile_s=compile_s,
        rss_before_mib=rss_before,
        peak_after_compile_mib=_rss_mib("VmHWM"),
        temp_mib=m.temp_size_in_bytes / 2**20,
        args_mib=m.argument_size_in_bytes / 2**20,
        out_mib=m.output_size_in_bytes / 2**20,
    )
    if execute:
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        out["run_s"] = time.perf_counter() - t0
    out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes", "cosc363.toml"))
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--depth", type=int, default=5)
    ap.add_argument("--tiles", default="16384", help="comma-separated tile_rays values (default: the renderer's)")
    ap.add_argument("--no-run", action="store_true", help="compile only (temp sizes; RSS then is the compiler's)")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--case", help=argparse.SUPPRESS)  # internal: run one case in this process
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.lower().split("x"))
    tiles = [int(t) for t in a.tiles.split(",")]

    if a.case:
        kind, tile = a.case.split(":")
        print(json.dumps(run_case(kind, a.scene, w, h, a.spp, a.depth, int(tile), not a.no_run)))
        return 0

    rows = []
    for tile in tiles:
        for kind in ("forward", "grad"):
            cmd = [
                sys.executable,
                os.path.abspath(__file__),
                "--case",
                f"{kind}:{tile}",
                "--scene",
                a.scene,
                "--size",
                a.size,
                "--spp",
                str(a.spp),
                "--depth",
                str(a.depth),
            ] + (["--no-run"] if a.no_run else [])
            env = dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
            r = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if r.returncode != 0:
                print(r.stderr[-3000:], file=sys.stderr)
                return 1
            row = json.loads(r.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(
                f"{kind:8s} tile_rays={tile:6d}: temp {row['temp_mib']:8.1f} MiB  args {row['args_mib']:6.1f} MiB  "
                f"out {row['out_mib']:6.1f} MiB  peak RSS {row['peak_rss_mib']:7.0f} MiB "
                f"(before compile {row['rss_before_mib']:.0f})  compile {row['compile_s']:.0f} s"
                + (f"  run {row['run_s']:.1f} s" if "run_s" in row else ""),
                flush=True,
            )
    print(
        f"\n{os.path.basename(a.scene)} at {w}x{h}, spp {a.spp}, depth {a.depth} "
        f"({w * h * a.spp} camera rays); jax {__import__('jax').__version__}, {os.cpu_count()} CPUs"
    )
    print("| tile_rays | forward temp | grad temp | grad / forward | forward peak RSS | grad peak RSS |")
    print("|---:|---:|---:|---:|---:|---:|")
    for tile in tiles:
        f = next(r for r in rows if r["kind"] == "forward" and r["tile_rays"] == tile)
        g = next(r for r in rows if r["kind"] == "grad" and r["tile_rays"] == tile)
        print(
            f"| {tile} | {f['temp_mib']:.1f} MiB | {g['temp_mib']:.1f} MiB | {g['temp_mib'] / max(f['temp_mib'], 1e-9):.1f}x "
            f"| {f['peak_rss_mib']:.0f} MiB | {g['peak_rss_mib']:.0f} MiB |"
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
