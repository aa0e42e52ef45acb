"""Render and gradient benchmarks for raytrax, with Mitsuba 3 in the same run.

    python benchmarks/bench_render.py                          # 320x240, both scenes (~5-10 min on 2 shared cores)
    python benchmarks/bench_render.py --sizes 640x480,1024x1024
    python benchmarks/bench_render.py --scaling --no-main      # scaling tables only
    python benchmarks/bench_render.py --json benchmarks/out/bench.json

For the seed scene (classic shading, ``scenes/cosc363.toml`` through
``rt.load_scene`` when available) and the physical benchmark scene (diffuse,
mirror and glass spheres, a rotated box, a tetrahedron, a floor, two point
lights), at each size with spp 4 and depth 5 (``--spp``, ``--depth``):

* compile: every measurement runs in a fresh subprocess. ``cold`` is the first
  call in a process whose persistent compilation cache directory starts empty
  (nothing to read; it writes its entries there), ``warm`` a second process
  using that directory (``jax_compilation_cache_dir``,
  ``jax_persistent_cache_min_compile_time_secs = 0``). ``compile ~`` is the first
  call minus the steady time; ``to first pixel`` counts from the process's start
  (imports and scene building included) to the image being ready;
* render time after compilation (median of ``--repeats``), camera rays/s and
  total rays/s (camera + specular + shadow rays of the same Whitted paths,
  counted by the Mitsuba reference integrator, which follows the full specular
  tree; physical scene only);
* peak memory: the subprocess's ``ru_maxrss`` (and the resident size before the
  first render, i.e. Python + jax + the scene);
* the same for ``eqx.filter_value_and_grad`` (under ``eqx.filter_jit``) of an
  image MSE loss with respect to the light positions and the refractive indices;
* Mitsuba 3 (``llvm_ad_rgb``) on the physical scene in the same run: forward
  ``mi.render`` (stratified sampler, box filter) with the one-kernel Whitted
  integrator of ``benchmarks/mitsuba_scene.py`` (``whitted_kernel``: one
  symbolic loop over the depth, glass sampled with probability F), the
  deterministic full-tree wavefront at raytrax's sample positions (the image
  reference; slow, many small kernels, not a speed figure), and the gradient of
  the same loss w.r.t. the light positions (``mi.render`` + ``dr.backward``
  through ``whitted_kernel``; Mitsuba's dielectric IOR is not a differentiable
  parameter, so that part is not applicable). raytrax / Mitsuba ratios are
  printed from medians, and from renders *interleaved* in one process (the
  median of per-pair ratios, robust to the load of a shared machine).
  ``benchmarks/bench_speed.py`` is the fuller comparison (Mitsuba's ``path``
  too, first calls and memory as ratios).

``--scaling``: render time against the number of spheres (10, 100, 1000) and of
triangles (10, 100, 1000, 10000) and against max_depth (1..8), raytrax and
Mitsuba, at 160 x 120; for the triangle scenes also the crossover of the triangle
BVH (``raytrax.bvh``): the same render forced to brute force (``bvh=None``) and
forced to the BVH (``bvh.MIN_TRIANGLES = 0``, topology built at any size).
"""

from __future__ import annotations

import time

_T0 = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from typing import Any  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


# ----------------------------------------------------------------------------
# helpers run inside worker processes
# ----------------------------------------------------------------------------


def _rss_mb():
    """Peak resident set size of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _setup_jax(cache):
    import jax

    if cache:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        try:
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
        except Exception:  # noqa: BLE001
            pass
    return jax


def _cache_entries(cache):
    if not cache or not os.path.isdir(cache):
        return 0
    return sum(1 for f in os.listdir(cache) if f.startswith("jit_") and "_render" in f)


def _scene(name, W, H, spp, depth):
    import scenes as scenes_module

    scenes: Any = scenes_module  # benchmarks/scenes.py (pyright resolves the name to the repo's scenes/ folder)

    if name == "seed":
        return scenes.seed_scene(W, H, spp, depth)
    if name == "physical":
        return scenes.physical_scene(W, H, spp, depth)
    if name.startswith("spheres"):
        return scenes.many_spheres(int(name[7:]), W, H, spp, depth)
    if name.startswith("tris"):
        return scenes.many_triangles(int(name[4:]), W, H, spp, depth)
    raise ValueError(name)


def _rt_fns(scene):
    """Forward and value-and-grad callables for a raytrax scene."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import raytrax as rt

    def fwd():
        return jax.block_until_ready(rt.render(scene))

    def loss(params, scene):
        lp, ior = params
        s = eqx.tree_at(lambda s: (s.lights.position, s.materials.ior), scene, (lp, ior))
        img = rt.render(s)
        return jnp.mean((img - 0.5) ** 2)

    vg = eqx.filter_jit(eqx.filter_value_and_grad(loss))
    params = (scene.lights.position, scene.materials.ior)

    def grad():
        return jax.block_until_ready(vg(params, scene))

    return fwd, grad


def _timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def worker_raytrax(cfg):
    jax = _setup_jax(cfg.get("cache"))
    scene = _scene(cfg["scene"], cfg["W"], cfg["H"], cfg["spp"], cfg["depth"])
    fwd, grad = _rt_fns(scene)
    fn = grad if cfg["what"] == "grad" else fwd
    rss0 = _rss_mb()
    n_cache = _cache_entries(cfg.get("cache"))
    t_first = _timed(fn)
    first_pixel = time.perf_counter() - _T0
    new_entries = _cache_entries(cfg.get("cache")) - n_cache
    times = [_timed(fn) for _ in range(cfg["repeats"])]
    out: dict[str, Any] = dict(
        first=t_first,
        to_first_pixel=first_pixel,
        times=times,
        rss_before=rss0,
        rss=_rss_mb(),
        backend=jax.default_backend(),
        new_cache_entries=new_entries,
    )
    if cfg.get("also_grad_first"):
        out["grad_first"] = _timed(grad)
    return out


def _mi_kernel_scene(ms, scene):
    """The Mitsuba scene with the one-kernel Whitted integrator (the one to time)."""
    return ms.load(scene, sampler="stratified", integrator="whitted_kernel")


def _mi_grad_fn(mscene, spp):
    """``mi.render`` + ``dr.backward`` of the image MSE w.r.t. the light positions."""
    import bench_speed

    return bench_speed.mi_grad_fn(mscene, spp)


def worker_mitsuba(cfg):
    import mitsuba_scene as ms

    try:
        ms.ensure_mitsuba(cfg.get("variant", ms.DEFAULT_VARIANT))
    except ms.MitsubaUnavailable as e:
        return dict(error=str(e))
    W, H, spp = cfg["W"], cfg["H"], cfg["spp"]
    scene = _scene(cfg["scene"], W, H, spp, cfg["depth"])
    mscene = _mi_kernel_scene(ms, scene)
    mref = ms.load(scene, sampler="stratified")  # deterministic wavefront: the image reference
    rss0 = _rss_mb()
    out: dict[str, Any] = dict(rss_before=rss0)
    out["native_first"] = _timed(lambda: ms.render_native(mscene, spp=spp))
    out["native_times"] = [_timed(lambda: ms.render_native(mscene, spp=spp)) for _ in range(cfg["repeats"])]
    out["rss_fwd"] = _rss_mb()
    out["grid_first"] = _timed(lambda: ms.render_grid(mref, W, H, spp))
    out["grid_times"] = [_timed(lambda: ms.render_grid(mref, W, H, spp)) for _ in range(cfg["repeats"])]
    if cfg.get("grad", True):
        g = _mi_grad_fn(mscene, spp)
        out["grad_first"] = _timed(g)
        out["grad_times"] = [_timed(g) for _ in range(cfg["grad_repeats"])]
    out["rss"] = _rss_mb()
    if cfg.get("count", True):
        out["rays"] = ms.count_rays(mref, W, H, spp)
    return out


def worker_paired(cfg):
    """raytrax and Mitsuba renders interleaved in one process (warm jax cache)."""
    _setup_jax(cfg.get("cache"))
    import mitsuba_scene as ms

    W, H, spp = cfg["W"], cfg["H"], cfg["spp"]
    scene = _scene(cfg["scene"], W, H, spp, cfg["depth"])
    fwd, grad = _rt_fns(scene)
    try:
        ms.ensure_mitsuba(cfg.get("variant", ms.DEFAULT_VARIANT))
    except ms.MitsubaUnavailable as e:
        return dict(error=str(e))
    mscene = _mi_kernel_scene(ms, scene)
    mfwd = lambda: ms.render_native(mscene, spp=spp)  # noqa: E731
    mgrad = _mi_grad_fn(mscene, spp)
    fwd(), mfwd()
    out: dict[str, Any] = dict(fwd=[], mi_fwd=[], grad=[], mi_grad=[])
    for _ in range(cfg["repeats"]):
        out["fwd"].append(_timed(fwd))
        out["mi_fwd"].append(_timed(mfwd))
    if cfg.get("grad", True):
        grad(), mgrad()
        for _ in range(cfg["grad_repeats"]):
            out["grad"].append(_timed(grad))
            out["mi_grad"].append(_timed(mgrad))
    return out


def worker_scaling(cfg):
    """Steady render times of a list of scenes, raytrax then Mitsuba, in one process."""
    _setup_jax(None)
    import mitsuba_scene as ms

    try:
        ms.ensure_mitsuba(cfg.get("variant", ms.DEFAULT_VARIANT))
        have_mi = True
    except ms.MitsubaUnavailable:
        have_mi = False
    rows = []
    for name, depth in cfg["items"]:
        scene = _scene(name, cfg["W"], cfg["H"], cfg["spp"], depth)
        fwd, _ = _rt_fns(scene)
        first = _timed(fwd)
        rt_t = statistics.median(_timed(fwd) for _ in range(cfg["repeats"]))
        r: dict[str, Any] = dict(scene=name, depth=depth, first=first, rt=rt_t, bvh=scene.bvh is not None)
        if name.startswith("tris"):  # crossover: the same render by brute force and with the BVH
            import dataclasses

            import raytrax.bvh as B

            for key, sc in (
                ("brute", dataclasses.replace(scene, bvh=None)),
                ("with_bvh", dataclasses.replace(scene, bvh=B.for_scene(scene))),
            ):
                old, B.MIN_TRIANGLES = B.MIN_TRIANGLES, 0
                try:
                    f, _ = _rt_fns(sc)
                    r[key + "_first"] = _timed(f)
                    r[key] = statistics.median(_timed(f) for _ in range(cfg["repeats"]))
                finally:
                    B.MIN_TRIANGLES = old
        if have_mi:
            m = _mi_kernel_scene(ms, scene)
            ms.render_native(m)
            r["mi"] = statistics.median(_timed(lambda: ms.render_native(m)) for _ in range(cfg["repeats"]))
        rows.append(r)
        print(json.dumps(r), file=sys.stderr, flush=True)
    return dict(rows=rows)


WORKERS = dict(raytrax=worker_raytrax, mitsuba=worker_mitsuba, paired=worker_paired, scaling=worker_scaling)


# ----------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------


def run_worker(cfg, timeout=3600) -> dict[str, Any]:
    env = dict(os.environ)
    env.setdefault("JAX_PLATFORMS", "cpu")
    t = time.perf_counter()
    r = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--worker", json.dumps(cfg)],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    wall = time.perf_counter() - t
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    if r.returncode != 0 or not lines:
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-8:])
        return dict(error=f"worker failed (status {r.returncode}):\n{tail}", wall=wall)
    out = json.loads(lines[-1][7:])
    out["wall"] = wall
    return out


def source_state():
    """(git HEAD, whether raytrax/ has uncommitted changes, newest mtime of raytrax/*.py)."""
    root = os.path.dirname(HERE)
    src = os.path.join(root, "raytrax")
    newest = max((os.path.getmtime(os.path.join(src, f)) for f in os.listdir(src) if f.endswith(".py")), default=0.0)
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
        ).stdout.strip()
        dirty = bool(
            subprocess.run(
                ["git", "status", "--porcelain", "--", "raytrax"], cwd=root, capture_output=True, text=True
            ).stdout.strip()
        )
    except OSError:
        head, dirty = "?", False
    return head, dirty, newest


def med(xs):
    return statistics.median(xs) if xs else float("nan")


def fmt_t(x):
    if x is None or x != x:
        return "   n/a"
    return f"{x:6.3f}" if x < 1 else (f"{x:6.2f}" if x < 100 else f"{x:6.0f}")


def fmt_c(x):
    """A compile-time estimate (first call minus steady time); negative means noise."""
    return fmt_t(x) if x > 0 else "   <0 (noise)"


def rate(n, t):
    if not n or not t or t != t:
        return "n/a"
    r = n / t
    return f"{r / 1e6:.2f} M/s" if r >= 1e6 else f"{r / 1e3:.0f} k/s"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument(
        "--sizes",
        default="320x240",
        help="comma-separated WxH list (default 320x240; the issue's figures: 640x480,1024x1024)",
    )
    p.add_argument("--scenes", default="seed,physical")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--repeats", type=int, default=3, help="forward renders timed after the first")
    p.add_argument("--grad-repeats", type=int, default=2)
    p.add_argument("--no-grad", action="store_true")
    p.add_argument("--no-mitsuba", action="store_true")
    p.add_argument("--no-main", action="store_true", help="skip the per-size tables")
    p.add_argument("--warm-sizes", type=int, default=1, help="measure the warm cache at the first N sizes")
    p.add_argument("--scaling", action="store_true", help="add the scaling tables (objects, depth)")
    p.add_argument("--scaling-size", default="160x120")
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--json", help="also write all figures to this JSON file")
    args = p.parse_args(argv)

    if args.worker:
        cfg = json.loads(args.worker)
        out = WORKERS[cfg["task"]](cfg)
        print("RESULT " + json.dumps(out), flush=True)
        return 0

    import jax

    import raytrax as rt

    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",") if s]
    scene_names = [s for s in args.scenes.split(",") if s]
    spp, depth = args.spp, args.depth
    results: dict[str, Any] = dict(
        machine=dict(
            cpus=os.cpu_count(),
            processor=platform.processor() or platform.machine(),
            python=platform.python_version(),
            jax=jax.__version__,
            raytrax=rt.__version__,
            load=os.getloadavg(),
        ),
        runs=[],
    )
    try:
        import mitsuba

        results["machine"]["mitsuba"] = mitsuba.__version__
    except Exception:  # noqa: BLE001
        pass
    m = results["machine"]
    print(
        f"machine: {m['cpus']} CPUs ({m['processor']}), load average {m['load'][0]:.1f}; python {m['python']}, "
        f"jax {m['jax']} (cpu), raytrax {m['raytrax']}, mitsuba {m.get('mitsuba', 'not installed')}"
    )
    head, dirty, newest0 = source_state()
    results["machine"]["git"] = dict(head=head, raytrax_dirty=dirty)
    print(f"raytrax source: git {head}{' + uncommitted changes in raytrax/' if dirty else ''}")
    print("all times in seconds; every row comes from fresh subprocesses of this run\n")

    def check_source(what):
        nonlocal newest0
        newest = source_state()[2]
        if newest != newest0:
            print(f"  WARNING: raytrax/*.py changed during the {what} measurements (figures mix two versions)")
            newest0 = newest

    cache_root = tempfile.mkdtemp(prefix="raytrax-bench-cache-")
    mi_note_done = False
    try:
        for si, (W, H) in enumerate(sizes if not args.no_main else []):
            cam_rays = W * H * spp
            print(f"=== {W} x {H}, spp {spp}, depth {depth} ({cam_rays:,} camera rays) ===")
            mi_res = None
            if "physical" in scene_names and not args.no_mitsuba:
                mi_res = run_worker(
                    dict(
                        task="mitsuba",
                        scene="physical",
                        W=W,
                        H=H,
                        spp=spp,
                        depth=depth,
                        repeats=args.repeats,
                        grad_repeats=args.grad_repeats,
                        grad=not args.no_grad,
                        variant=args.variant,
                    )
                )
                if "error" in mi_res:
                    print(f"  Mitsuba: {mi_res['error']}")
                    mi_res = None
            for name in scene_names:
                cache = os.path.join(cache_root, f"{name}-{W}x{H}")
                os.makedirs(cache, exist_ok=True)
                base = dict(task="raytrax", scene=name, W=W, H=H, spp=spp, depth=depth, cache=cache)
                fw = run_worker(base | dict(what="fwd", repeats=args.repeats))
                gr = None if args.no_grad else run_worker(base | dict(what="grad", repeats=args.grad_repeats))
                warm = None
                if si < args.warm_sizes:
                    warm = run_worker(base | dict(what="fwd", repeats=0, also_grad_first=not args.no_grad))
                run: dict[str, Any] = dict(scene=name, W=W, H=H, spp=spp, depth=depth, fwd=fw, grad=gr, warm=warm)
                total_rays = None
                if name == "physical" and mi_res is not None:
                    total_rays = sum(mi_res["rays"].values())
                    run["mitsuba"] = mi_res
                print(f"-- {name} --")
                for label, r in (("forward", fw), ("value_and_grad", gr)):
                    if r is None:
                        continue
                    if "error" in r:
                        print(f"  {label}: {r['error']}")
                        continue
                    steady = med(r["times"])
                    print(
                        f"  raytrax {label:<15s} steady {fmt_t(steady)} (median of {len(r['times'])})   "
                        f"cold first call {fmt_t(r['first'])} (compile ~{fmt_c(r['first'] - steady)})   "
                        f"peak RSS {r['rss']:.0f} MiB (before render {r['rss_before']:.0f})"
                    )
                    if label == "forward":
                        print(
                            f"  {'':<24s} camera rays {rate(cam_rays, steady)}"
                            + (
                                f", total rays {rate(total_rays, steady)} ({total_rays:,} rays: "
                                + ", ".join(f"{k} {v:,}" for k, v in (mi_res or {}).get("rays", {}).items())
                                + ")"
                                if total_rays
                                else ", total rays n/a (counted for the physical scene only)"
                            )
                        )
                if warm is not None and "error" not in warm:
                    hit = "cache hit" if warm["new_cache_entries"] == 0 else "CACHE MISS: new entries written"
                    over = warm["first"] - med(fw["times"]) if "error" not in fw else float("nan")
                    print(
                        f"  warm cache (2nd process, {hit}): forward first call {fmt_t(warm['first'])} "
                        f"(~{fmt_c(over)} over the steady time), "
                        f"to first pixel {fmt_t(warm['to_first_pixel'])} from process start"
                        + (f"; value_and_grad first call {fmt_t(warm['grad_first'])}" if "grad_first" in warm else "")
                    )
                elif warm is not None:
                    print(f"  warm: {warm['error']}")
                if name == "physical" and mi_res is not None:
                    nf, gf = med(mi_res["native_times"]), med(mi_res["grid_times"])
                    print(
                        f"  Mitsuba forward (mi.render, one-kernel Whitted) steady {fmt_t(nf)} "
                        f"(first {fmt_t(mi_res['native_first'])}, camera rays {rate(cam_rays, nf)}, "
                        f"total {rate(total_rays, nf)}); peak RSS {mi_res['rss_fwd']:.0f} MiB; "
                        f"[deterministic wavefront reference at raytrax's samples: {fmt_t(gf)}]"
                    )
                    if "grad_times" in mi_res:
                        mg = med(mi_res["grad_times"])
                        print(
                            f"  Mitsuba gradient (light positions, one-kernel Whitted + dr.backward) steady {fmt_t(mg)} "
                            f"(first {fmt_t(mi_res['grad_first'])}); peak RSS {mi_res['rss']:.0f} MiB; "
                            f"ior: n/a (not differentiable in Mitsuba)"
                        )
                    if "error" not in fw:
                        print(f"  ratio raytrax / Mitsuba, forward: {med(fw['times']) / nf:.2f} (medians)")
                    if gr is not None and "error" not in gr and "grad_times" in mi_res:
                        print(
                            f"  ratio raytrax / Mitsuba, gradient: {med(gr['times']) / mg:.2f} (medians; raytrax "
                            f"also differentiates the ior)"
                        )
                    if gr is not None and "error" not in gr and "error" not in fw:
                        print(f"  raytrax gradient / own forward: {med(gr['times']) / med(fw['times']):.2f}")
                    if si < args.warm_sizes:
                        pr = run_worker(
                            dict(
                                task="paired",
                                scene="physical",
                                W=W,
                                H=H,
                                spp=spp,
                                depth=depth,
                                cache=cache,
                                repeats=args.repeats,
                                grad_repeats=args.grad_repeats,
                                grad=not args.no_grad,
                                variant=args.variant,
                            )
                        )
                        run["paired"] = pr
                        if "error" in pr:
                            print(f"  interleaved: {pr['error']}")
                        else:
                            rf = med([a / b for a, b in zip(pr["fwd"], pr["mi_fwd"])])
                            line = (
                                f"  interleaved in one process: forward raytrax {fmt_t(med(pr['fwd']))} / Mitsuba "
                                f"{fmt_t(med(pr['mi_fwd']))} -> ratio {rf:.2f}"
                            )
                            if pr["grad"]:
                                rg = med([a / b for a, b in zip(pr["grad"], pr["mi_grad"])])
                                line += (
                                    f"; gradient {fmt_t(med(pr['grad']))} / {fmt_t(med(pr['mi_grad']))} -> "
                                    f"ratio {rg:.2f}"
                                )
                            print(line + " (median of per-pair ratios)")
                    if not mi_note_done:
                        import mitsuba_scene as ms

                        print("  " + ms.HOW_THEY_DIFFER.replace("\n", "\n  "))
                        mi_note_done = True
                check_source(f"{name} {W}x{H}")
                results["runs"].append(run)
            print()

        if args.scaling:
            W, H = (int(v) for v in args.scaling_size.split("x"))
            items = (
                [(f"spheres{n}", 2) for n in (10, 100, 1000)]
                + [(f"tris{n}", 2) for n in (10, 100, 1000, 10000)]
                + [("physical", d) for d in range(1, 9)]
            )
            print(
                f"=== scaling: {W} x {H}, spp 1 (objects: floor + N diffuse objects, depth 2; depth: physical scene) ==="
            )
            sc = run_worker(
                dict(task="scaling", W=W, H=H, spp=1, repeats=3, items=items, variant=args.variant), timeout=7200
            )
            results["scaling"] = sc
            if "error" in sc:
                print(f"  {sc['error']}")
            else:
                print(
                    f"  {'scene':<14s} {'depth':>5s} {'raytrax':>8s} {'Mitsuba':>8s} {'ratio':>6s}  raytrax first call"
                )
                for r in sc["rows"]:
                    mit = r.get("mi")
                    print(
                        f"  {r['scene']:<14s} {r['depth']:>5d} {fmt_t(r['rt']):>8s} {fmt_t(mit):>8s} "
                        f"{(r['rt'] / mit if mit else float('nan')):6.2f}  {fmt_t(r['first'])}"
                        + ("  (BVH)" if r.get("bvh") else "")
                    )
                tri_rows = [r for r in sc["rows"] if "brute" in r]
                if tri_rows:
                    import raytrax.bvh

                    print(
                        f"\n  triangle BVH crossover (raytrax.bvh.MIN_TRIANGLES = {raytrax.bvh.MIN_TRIANGLES}: "
                        f"BVH above it)"
                    )
                    print(f"  {'scene':<14s} {'brute':>8s} {'BVH':>8s} {'speedup':>7s}  first call brute / BVH")
                    for r in tri_rows:
                        # The variant the scene uses by default was compiled by the row above.
                        fb = r["brute_first"] if r["bvh"] else r["first"]
                        fv = r["first"] if r["bvh"] else r["with_bvh_first"]
                        print(
                            f"  {r['scene']:<14s} {fmt_t(r['brute']):>8s} {fmt_t(r['with_bvh']):>8s} "
                            f"{r['brute'] / r['with_bvh']:7.2f}  {fmt_t(fb)} / {fmt_t(fv)}"
                        )
    finally:
        shutil.rmtree(cache_root, ignore_errors=True)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
