"""raytrax against Mitsuba 3 on meshes of 10^3 to 10^6 triangles.

Two scenes of ``benchmarks/scenes.py``, each size in a fresh process that times
both renderers in turn (raytrax first; ratios in one process, as the load moves):

* ``soup N``: ``many_triangles`` (a floor and N random small triangles in a slab in
  front of the camera, one light): overlapping leaves, the hard case;
* ``terrain N``: ``terrain`` (a height field of about N triangles, a mirror sphere
  above it, one light): a mesh as scanned or modelled surfaces are.

Forward render at 320 x 240, spp 1, depth 2 (``--size``, ``--spp``). raytrax:
``rt.render`` under ``jax.jit``, first call (compilation included, no persistent
cache) and the fastest of 5 steady calls, the host-side BVH build (part of
``SceneBuilder.build``), peak RSS after the forward calls. Mitsuba: the one-kernel Whitted integrator of
``mitsuba_scene.py`` (``llvm_ad_rgb``; Embree builds its BVH when the scene loads),
first (an empty Dr.Jit kernel cache) and fastest of 5 calls. ``--grad``: also ``value_and_grad`` of the image MSE
with respect to the light position (raytrax only; first call, fastest of 3, and the
peak RSS after it).

    python benchmarks/bench_meshes.py [--sizes 1000,10000,100000,1000000] [--scenes soup,terrain] [--grad]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def worker(cfg):
    sys.path.insert(0, HERE)
    import jax
    import jax.numpy as jnp
    from bench_culling import _time

    import raytrax as rt
    import scenes

    W, H = cfg["size"]
    make = scenes.many_triangles if cfg["scene"] == "soup" else scenes.terrain
    t = time.perf_counter()
    sc = make(cfg["n"], width=W, height=H, spp=cfg["spp"], max_depth=2)
    build = time.perf_counter() - t
    n_tri = int(sc.merged_triangles()[0].shape[0])
    out = dict(n=n_tri, build=build, bvh=sc.bvh is not None)
    fwd = jax.jit(rt.render)
    out["rt"] = _time(lambda: fwd(sc))
    out["rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if cfg["grad"]:
        target = fwd(sc)

        def loss(p, sc):  # the scene is an argument (closed over, its arrays would be constants of the program)
            return jnp.mean((rt.render(rt.with_parameters(sc, {"light[0].position": p})) - target * 0.9) ** 2)

        vg = jax.jit(jax.value_and_grad(loss))
        p0 = rt.parameters(sc)["light[0].position"]
        out["rt_grad"] = _time(lambda: vg(p0, sc), reps=3)
        out["rss_grad_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    try:
        import mitsuba_scene as ms

        ms.ensure_mitsuba(ms.DEFAULT_VARIANT)
        t = time.perf_counter()
        m = ms.load(sc, sampler="stratified", integrator="whitted_kernel")
        out["mi_load"] = time.perf_counter() - t
        out["mi"] = _time(lambda: ms.render_native(m))
    except Exception as e:  # noqa: BLE001 - Mitsuba is optional: say why it is missing
        out["mi_error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
    return out


def run(cfg):
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # no persistent jax cache: first calls compile
    with tempfile.TemporaryDirectory(prefix="bench_meshes_home_") as home:
        env["HOME"] = home  # Dr.Jit keeps compiled kernels under $HOME/.drjit: start empty
        out = subprocess.run(
            [sys.executable, __file__, "--worker", json.dumps(cfg)],
            capture_output=True,
            text=True,
            check=False,
            env=env,
        )
    if out.returncode:
        raise RuntimeError(f"worker {cfg} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--sizes", default="1000,10000,100000,1000000", help="triangle counts")
    p.add_argument("--scenes", default="soup,terrain")
    p.add_argument("--size", default="320x240", help="image WxH")
    p.add_argument("--spp", type=int, default=1)
    p.add_argument("--grad", action="store_true", help="also time raytrax's value_and_grad wrt the light position")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        print(json.dumps(worker(json.loads(a.worker))))
        return
    W, H = (int(v) for v in a.size.split("x"))
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE).stdout
    print(f"meshes, {W} x {H}, spp {a.spp}, depth 2; git {head.strip()}; load average {os.getloadavg()[0]:.1f}")
    print(
        f"{'scene':18s} {'build':>7s} {'raytrax':>9s} {'Mitsuba':>9s} {'ratio':>7s}"
        f"   {'first call raytrax / Mitsuba (load)':>36s} {'RSS':>8s}" + ("   value_and_grad (first)" if a.grad else "")
    )
    for scene in a.scenes.split(","):
        for n in (int(v) for v in a.sizes.split(",")):
            r = run(dict(scene=scene, n=n, size=(W, H), spp=a.spp, grad=a.grad))
            name = f"{scene} {r['n']}"
            if "mi" in r:
                mi = f"{r['mi'][1]:7.4f} s {r['rt'][1] / r['mi'][1]:6.1f}x"
                mfirst = f"{r['mi'][0]:.2f} s ({r['mi_load']:.2f} s)"
            else:
                mi, mfirst = f"{'-':>9s} {'-':>7s}", f"- ({r['mi_error']})"
            line = (
                f"{name:18s} {r['build']:5.2f} s {r['rt'][1]:7.4f} s {mi}"
                f"   {r['rt'][0]:10.2f} s / {mfirst:18s} {r['rss_mib']:5.0f} MiB"
            )
            if a.grad:
                line += f"   {r['rt_grad'][1]:.4f} s ({r['rt_grad'][0]:.1f} s, {r['rss_grad_mib']:.0f} MiB)"
            print(line, flush=True)


if __name__ == "__main__":
    main()
