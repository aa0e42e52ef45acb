"""raytrax against Mitsuba 3 at its best: speed, compile time and memory, in one run.

    python benchmarks/bench_speed.py            # forward 640x480, gradient 320x240 (~6-10 min on 2 shared cores)
    python benchmarks/bench_speed.py --quick    # forward 160x120, gradient 96x72 (~2-3 min)
    python benchmarks/bench_speed.py --json benchmarks/out/speed.json

Scene: ``physical_scene`` of ``benchmarks/scenes.py`` (floor; diffuse, mirror and
glass spheres; a rotated box; a tetrahedron; two point lights), spp 4, depth 6
(``--spp``, ``--depth``).

Mitsuba 3 (``llvm_ad_rgb``) is timed with integrators that run as one LLVM kernel:

* ``whitted_kernel``: Whitted paths (direct light from each point light at every
  hit, mirror and glass followed up to ``depth`` bounces) as a Monte Carlo
  renderer traces them, a ``mi.SamplingIntegrator`` whose ``sample`` is one
  symbolic ``dr.while_loop``; at glass it follows the reflected ray with
  probability F, else the refracted one (``benchmarks/mitsuba_scene.py``). Its
  image is checked against the deterministic full-tree reference at high spp
  (PSNR printed; ``--psnr-spp 0`` skips it);
* ``path``: Mitsuba's built-in path tracer with ``max_depth = depth`` (the
  issue's setting; Mitsuba counts path segments, so it reaches fewer specular
  bounces than raytrax's ``depth``) and ``max_depth = depth + 2`` (the same
  number of vertices as raytrax's paths). It also gathers indirect diffuse
  light: more work than Whitted, and a different image;
* the deterministic full-tree Whitted wavefront of the earlier benchmark
  (``dr.compress`` / ``dr.eval`` at every depth), for comparison only.

Gradients (``--grad-size``): raytrax's ``eqx.filter_value_and_grad`` of the image
MSE to 0.5 w.r.t. the light positions and every material's IOR, and w.r.t. the
light positions alone (the like-for-like row: what Mitsuba differentiates); Mitsuba's
``mi.render`` + ``dr.backward`` of the same loss w.r.t. the light positions,
through ``path`` with ``max_depth`` 2 (direct light only) and through
``whitted_kernel`` at ``depth`` (reaches the glass). Mitsuba 3's ``dielectric``
stores its IOR as a non-differentiable scalar, so Mitsuba has no IOR gradient.

How it measures:

* first call and peak memory: each renderer and task in a fresh subprocess
  (raytrax: no persistent jax compilation cache; Mitsuba: an empty Dr.Jit
  kernel cache, ``HOME`` pointed at a new directory). "first call" is the first
  render (or gradient) in the process, compilation included; scene building and
  imports are not in it but are in "from start". Peak memory is the process's
  ``ru_maxrss`` (Python, the libraries and the scene included; "base" is it
  before the first render);
* steady times: one process renders raytrax and the Mitsuba integrators in
  turn, ``--repeats`` rounds after a warm-up; it prints the medians and the
  median of the per-round ratios (robust to the load of a shared machine). Each
  call ends with ``jax.block_until_ready`` / ``dr.eval`` + ``dr.sync_thread``.

The git HEAD is printed, and a warning when ``raytrax/`` changes during the run.
Absolute times on a shared machine vary; compare the ratios of one run.
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
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

# Mitsuba configurations: label -> (integrator, max_depth as a function of the
# benchmark's depth, what it is).
MI_FORWARD = {
    "whitted_kernel": ("whitted_kernel", lambda d: d, "Whitted one kernel, depth {}"),
    "path": ("path", lambda d: d, "path, max_depth {}"),
    "path+2": ("path", lambda d: d + 2, "path, max_depth {} (same vertices)"),
    "wavefront": ("whitted", lambda d: d, "Whitted wavefront (old), depth {}"),
}
MI_GRAD = {
    "path2": ("path", lambda d: 2, "path, max_depth {}, lights"),
    "whitted_kernel": ("whitted_kernel", lambda d: d, "Whitted kernel, depth {}, lights"),
}


def mi_name(table, label, depth):
    _, depth_of, name = table[label]
    return "Mitsuba " + name.format(depth_of(depth))


# ----------------------------------------------------------------------------
# measurement helpers (run inside the worker processes)
# ----------------------------------------------------------------------------


def _rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def _physical(W, H, spp, depth):
    import scenes

    return scenes.physical_scene(W, H, spp, depth)  # pyright: ignore[reportAttributeAccessIssue]


def rt_forward_fn(scene):
    import jax

    import raytrax as rt

    return lambda: jax.block_until_ready(rt.render(scene))


def rt_value_and_grad_fn(scene, ior=True):
    """``value_and_grad`` of the image MSE to 0.5 w.r.t. light positions and IORs
    (``ior=False``: the light positions only, as Mitsuba's gradients here)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import raytrax as rt

    def where(s):
        return (s.lights.position, s.materials.ior) if ior else s.lights.position

    def loss(params, scene):
        return jnp.mean((rt.render(eqx.tree_at(where, scene, params)) - 0.5) ** 2)

    # The options raytrax's own entry points compile with (rt.compiler_options: faster compiles on CPU).
    vg = eqx.filter_jit(eqx.filter_value_and_grad(loss), compiler_options=rt.compiler_options())
    params = where(scene)
    return lambda: jax.block_until_ready(vg(params, scene))


def _mi_scene(scene, label, table):
    import mitsuba_scene as ms

    kind, depth_of, _ = table[label]
    return ms.load(scene, integrator=kind, max_depth=depth_of(scene.settings.max_depth), sampler="stratified")


def mi_forward_fn(mscene, spp):
    import drjit as dr
    import mitsuba as mi

    def f():
        img = mi.render(mscene, spp=spp)
        dr.eval(img)
        dr.sync_thread()
        return img

    return f


def mi_grad_fn(mscene, spp):
    """``mi.render`` + ``dr.backward`` of the image MSE to 0.5 w.r.t. the light positions."""
    import drjit as dr
    import mitsuba as mi

    params = mi.traverse(mscene)
    keys = [k for k in params.keys() if k.startswith("light") and k.endswith(".position")]

    def f():
        xs = []
        for k in keys:
            x = mi.Point3f(dr.detach(params[k]))
            dr.enable_grad(x)
            params[k] = x
            xs.append(x)
        params.update()
        img = mi.render(mscene, params, spp=spp)
        loss = dr.mean(dr.square(img - 0.5), axis=None)
        dr.backward(loss)
        g = [dr.grad(x) for x in xs]
        dr.eval(loss, g)
        dr.sync_thread()
        for k, x in zip(keys, xs):
            params[k] = mi.Point3f(dr.detach(x))
        params.update()
        return loss, g

    return f


def _first_and_steady(fn, repeats):
    rss0 = _rss_mb()
    t_first = _timed(fn)
    from_start = time.perf_counter() - _T0
    times = [_timed(fn) for _ in range(repeats)]
    return dict(first=t_first, from_start=from_start, times=times, rss_base=rss0, rss=_rss_mb())


# ----------------------------------------------------------------------------
# workers
# ----------------------------------------------------------------------------


def worker_rt(cfg):
    """One raytrax task in a fresh process: first call, steady calls, peak RSS."""
    import jax

    scene = _physical(cfg["W"], cfg["H"], cfg["spp"], cfg["depth"])
    what = cfg["what"]
    fn = rt_forward_fn(scene) if what == "forward" else rt_value_and_grad_fn(scene, ior=what == "grad")
    out: dict[str, Any] = _first_and_steady(fn, cfg["repeats"])
    out["backend"] = jax.default_backend()
    return out


def worker_mi(cfg):
    """One Mitsuba integrator and task in a fresh process (empty kernel cache)."""
    import mitsuba_scene as ms

    ms.ensure_mitsuba(cfg["variant"], probe=False)
    scene = _physical(cfg["W"], cfg["H"], cfg["spp"], cfg["depth"])
    table = MI_GRAD if cfg["what"] == "grad" else MI_FORWARD
    mscene = _mi_scene(scene, cfg["label"], table)
    fn = mi_grad_fn(mscene, cfg["spp"]) if cfg["what"] == "grad" else mi_forward_fn(mscene, cfg["spp"])
    return _first_and_steady(fn, cfg["repeats"])


def _rounds(fns, repeats):
    """Warm every callable, then ``repeats`` rounds calling each in turn."""
    for f in fns.values():
        f()
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            times[k].append(_timed(f))
    return times


def worker_paired(cfg):
    """Steady times of raytrax and Mitsuba in turn, in one process."""
    import mitsuba_scene as ms

    ms.ensure_mitsuba(cfg["variant"], probe=False)
    spp, depth = cfg["spp"], cfg["depth"]
    out = {}
    scene = _physical(cfg["W"], cfg["H"], spp, depth)
    fns = {"raytrax": rt_forward_fn(scene)}
    for label in cfg["mi_forward"]:
        fns[label] = mi_forward_fn(_mi_scene(scene, label, MI_FORWARD), spp)
    out["forward"] = _rounds(fns, cfg["repeats"])
    if cfg["grad"]:
        gscene = _physical(cfg["gW"], cfg["gH"], spp, depth)
        fns = {
            "raytrax": rt_value_and_grad_fn(gscene),
            "raytrax_lights": rt_value_and_grad_fn(gscene, ior=False),
            "raytrax_forward": rt_forward_fn(gscene),
        }
        for label in MI_GRAD:
            fns[label] = mi_grad_fn(_mi_scene(gscene, label, MI_GRAD), spp)
        out["grad"] = _rounds(fns, cfg["grad_repeats"])
    return out


def worker_psnr(cfg):
    """PSNR of the one-kernel Whitted image against the deterministic full tree."""
    import mitsuba as mi
    import mitsuba_scene as ms
    import numpy as np

    ms.ensure_mitsuba(cfg["variant"], probe=False)
    W, H, depth = cfg["W"], cfg["H"], cfg["depth"]
    chunk = min(cfg["spp"], 256)
    n = max(1, cfg["spp"] // chunk)
    scene = _physical(W, H, chunk, depth)
    kern = ms.load(scene, integrator="whitted_kernel", sampler="stratified")
    tree = ms.load(scene, integrator="whitted", sampler="stratified")

    def avg(m, seed0):
        return np.mean([np.array(mi.render(m, spp=chunk, seed=seed0 + i)) for i in range(n)], axis=0)

    a, b, c = avg(kern, 0), avg(tree, 1000), avg(tree, 2000)
    lin = lambda x, y: ms.psnr(np.clip(x, 0, 1), np.clip(y, 0, 1))  # noqa: E731
    return dict(
        spp=n * chunk,
        kernel_vs_tree=lin(a, b),
        tree_vs_tree=lin(c, b),
        kernel_vs_tree_srgb=ms.psnr(ms.srgb(a), ms.srgb(b)),
        mean_kernel=float(a.mean()),
        mean_tree=float(b.mean()),
    )


WORKERS = dict(rt=worker_rt, mi=worker_mi, paired=worker_paired, psnr=worker_psnr)


# ----------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------


def run_worker(cfg, timeout=3600, fresh_home=False) -> dict[str, Any]:
    env = dict(os.environ)
    env.setdefault("JAX_PLATFORMS", "cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # no persistent jax cache: first calls compile
    home = None
    if fresh_home:  # Dr.Jit keeps compiled kernels under $HOME/.drjit
        home = tempfile.mkdtemp(prefix="bench_speed_home_")
        env["HOME"] = home
    try:
        r = subprocess.run(
            [sys.executable, os.path.abspath(__file__), "--worker", json.dumps(cfg)],
            capture_output=True,
            text=True,
            env=env,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return dict(error=f"worker timed out after {timeout} s")
    finally:
        if home:
            shutil.rmtree(home, ignore_errors=True)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    if r.returncode != 0 or not lines:
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-8:])
        return dict(error=f"worker {cfg['task']} failed (status {r.returncode}):\n{tail}")
    return json.loads(lines[-1][7:])


def source_state():
    """(git HEAD, raytrax/ modified vs HEAD?, newest mtime under raytrax/)."""
    src = os.path.join(ROOT, "raytrax")
    newest = 0.0
    for d, _, files in os.walk(src):
        for f in files:
            if f.endswith(".py"):
                newest = max(newest, os.path.getmtime(os.path.join(d, f)))

    def git(*a):
        try:
            return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.strip()
        except OSError:
            return ""

    head = git("rev-parse", "--short", "HEAD") or "?"
    dirty = bool(git("status", "--porcelain", "--", "raytrax"))
    return head, dirty, newest


def med(xs):
    return statistics.median(xs) if xs else float("nan")


def ft(x):
    if x is None or x != x:
        return "n/a"
    return f"{x:.3f}" if x < 1 else (f"{x:.2f}" if x < 100 else f"{x:.0f}")


def fr(x):
    return "n/a" if x is None or x != x else f"{x:.2f}"


def ratio(times, a, b):
    """Median over rounds of ``times[a][i] / times[b][i]``."""
    return med([x / y for x, y in zip(times[a], times[b])])


def cpu_description() -> str:
    """The CPU's model and its widest x86 vector instructions, from Linux's
    ``/proc/cpuinfo`` (elsewhere the platform's name): Mitsuba's LLVM kernels use the
    widest vectors the CPU has, so the ratios move with them between machines."""
    from raytrax.compile_options import first_cpu_lines

    lines = first_cpu_lines()
    if not lines:
        return platform.processor() or platform.machine()
    model = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")), platform.machine())
    flags = set(next((ln.split(":", 1)[1].split() for ln in lines if ln.startswith("flags")), []))
    widest = "AVX-512" if "avx512f" in flags else "AVX2, no AVX-512" if "avx2" in flags else "no AVX2"
    return f"{model}; {widest}"


def report(res):
    """Print the tables of a results dict (from a run, or from ``--json``); returns the summary."""
    c = res["config"]
    (W, H), (gW, gH), depth = c["size"], c["grad_size"], c["depth"]
    fresh, pr, psnr = res["fresh"], res["paired"], res.get("psnr")
    mi_fwd = c["mi_forward"]
    m = res["machine"]
    print(
        f"git HEAD {res['git_head']}{' (raytrax/ has uncommitted changes)' if res['raytrax_modified'] else ''}; "
        f"raytrax {m['raytrax']}, jax {m['jax']} ({m.get('jax_devices', 1)} CPU devices); Mitsuba {m['mitsuba']} ({m['variant']}), drjit {m['drjit']}; "
        f"{m['cpus']} CPUs ({m.get('cpu', 'model not recorded')}), load average {m['load_start'][0]:.1f} at the start"
    )
    print(f"physical_scene, spp {c['spp']}, depth {depth}: forward {W} x {H}, gradient {gW} x {gH}\n")
    for k, v in list(fresh.items()) + [("steady (one process)", pr)] + ([("PSNR", psnr)] if psnr else []):
        if "error" in v:
            print(f"  {k}: {v['error']}")

    def table(rt_key, rows, times):
        """One row per renderer; each ``rt/x`` is raytrax's figure over that row's."""
        print(
            f"  {'renderer':<44s} {'median s':>8s} {'rt/x':>5s} {'min s':>6s} {'rt/x':>5s} | {'first s':>7s} "
            f"{'rt/x':>5s} {'from start':>10s} | {'peak MiB':>8s} {'rt/x':>5s} {'> base':>6s} {'rt/x':>5s}"
        )
        r0 = fresh.get(rt_key, {})
        nan = float("nan")
        for key, fkey, name in rows:
            f = fresh.get(fkey, {})
            ts = times[key] if times and key in times else f.get("times", [])
            first, rss = f.get("first", nan), f.get("rss", nan)
            above = rss - f.get("rss_base", nan)
            if key == "raytrax":
                cells = [""] * 5
            else:
                rs = ratio(times, "raytrax", key) if times and key in times else nan
                rmin = min(times["raytrax"]) / min(ts) if times and key in times else nan
                r_above = r0.get("rss", nan) - r0.get("rss_base", nan)
                cells = [
                    fr(rs),
                    fr(rmin),
                    fr(r0.get("first", nan) / first),
                    fr(r0.get("rss", nan) / rss),
                    fr(r_above / above),
                ]
            print(
                f"  {name:<44s} {ft(med(ts)):>8s} {cells[0]:>5s} {ft(min(ts, default=nan)):>6s} {cells[1]:>5s} | "
                f"{ft(first):>7s} {cells[2]:>5s} {ft(f.get('from_start')):>10s} | "
                f"{rss:8.0f} {cells[3]:>5s} {above:6.0f} {cells[4]:>5s}"
            )

    fwd_t = pr.get("forward") if "error" not in pr else None
    rows = [("raytrax", "rt_forward", "raytrax")] + [
        (k, "mi_forward_" + k, mi_name(MI_FORWARD, k, depth)) for k in mi_fwd
    ]
    print(
        f"== forward, {W} x {H}: {c['repeats']} rounds in one process; rt/x: raytrax over that row "
        "(median of the per-round ratios; min over min) =="
    )
    table("rt_forward", rows, fwd_t)
    summary: dict[str, Any] = {}
    if fwd_t:
        summary["forward"] = {k: ratio(fwd_t, "raytrax", k) for k in mi_fwd}
    if c["grad"]:
        g_t = pr.get("grad") if "error" not in pr else None
        rows = [
            ("raytrax", "rt_grad", "raytrax (lights + IOR)"),
            ("raytrax_lights", "rt_grad_lights", "raytrax (lights)"),
        ]
        rows += [(k, "mi_grad_" + k, mi_name(MI_GRAD, k, depth)) for k in MI_GRAD]
        print(f"\n== value_and_grad of the image MSE, {gW} x {gH}: {c['grad_repeats']} rounds in one process ==")
        table("rt_grad", rows, g_t)
        print("  Mitsuba's dielectric IOR is a non-differentiable scalar in Mitsuba 3: no IOR gradient there.")
        if g_t and "raytrax_lights" in g_t:  # like for like: light positions only, both renderers
            summary["grad_lights"] = {k: ratio(g_t, "raytrax_lights", k) for k in MI_GRAD}
            print(
                "  raytrax (lights) over Mitsuba, same rounds (median of the per-round ratios): "
                + ", ".join(f"{fr(v)} {mi_name(MI_GRAD, k, depth)}" for k, v in summary["grad_lights"].items())
            )
        if g_t:
            summary["grad"] = {k: ratio(g_t, "raytrax", k) for k in MI_GRAD}
            summary["rt_grad_over_forward"] = ratio(g_t, "raytrax", "raytrax_forward")
            summary["rt_grad_over_forward_min"] = min(g_t["raytrax"]) / min(g_t["raytrax_forward"])
            print(
                f"  raytrax value_and_grad / raytrax forward at {gW} x {gH}, same rounds: "
                f"{summary['rt_grad_over_forward']:.2f} (median of the per-round ratios), "
                f"{summary['rt_grad_over_forward_min']:.2f} (min {ft(min(g_t['raytrax']))} s over min "
                f"{ft(min(g_t['raytrax_forward']))} s); target <= 2.5"
            )
    if psnr:
        if "error" in psnr:
            print(f"\n  PSNR check: {psnr['error']}")
        else:
            print(
                f"\nWhitted one-kernel image vs the deterministic full tree (160 x 120, spp {psnr['spp']} each): "
                f"{psnr['kernel_vs_tree']:.1f} dB linear ({psnr['kernel_vs_tree_srgb']:.1f} dB sRGB); "
                f"two tree renders with other seeds: {psnr['tree_vs_tree']:.1f} dB (sampling noise floor)"
            )
    res["summary"] = summary
    return summary


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--size", default="640x480", help="forward image size WxH (default 640x480)")
    p.add_argument("--grad-size", default="320x240", help="gradient image size WxH (default 320x240)")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--depth", type=int, default=6)
    p.add_argument("--repeats", type=int, default=7, help="steady forward rounds (default 7)")
    p.add_argument("--grad-repeats", type=int, default=5, help="steady gradient rounds (default 5)")
    p.add_argument("--psnr-spp", type=int, default=1024, help="spp of the Whitted PSNR check at 160x120 (0: skip)")
    p.add_argument("--no-grad", action="store_true", help="forward only")
    p.add_argument("--no-wavefront", action="store_true", help="leave out the old wavefront Whitted integrator")
    p.add_argument("--quick", action="store_true", help="small sizes and few repeats (a smoke run)")
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--json", help="also write every figure to this JSON file")
    p.add_argument("--report", metavar="JSON", help="print the tables of an earlier --json file and exit")
    args = p.parse_args(argv)

    if args.worker:
        cfg = json.loads(args.worker)
        print("RESULT " + json.dumps(WORKERS[cfg["task"]](cfg)), flush=True)
        return 0
    if args.report:
        with open(args.report) as f:
            report(json.load(f))
        return 0

    if args.quick:
        args.size, args.grad_size, args.repeats, args.grad_repeats = "160x120", "96x72", 3, 2
        args.psnr_spp = min(args.psnr_spp, 256)
    W, H = (int(v) for v in args.size.split("x"))
    gW, gH = (int(v) for v in args.grad_size.split("x"))
    spp, depth = args.spp, args.depth
    if int(spp**0.5) ** 2 != spp:
        p.error(f"--spp: expected a square number, got {spp}")

    import jax
    import mitsuba_scene as ms

    import raytrax as rt

    try:
        mi = ms.ensure_mitsuba(args.variant)
    except ms.MitsubaUnavailable as e:
        print(f"Mitsuba cannot start, no comparison made:\n  {e}")
        return 2
    import drjit as dr

    head, dirty, mtime0 = source_state()
    mi_fwd = [k for k in MI_FORWARD if not (args.no_wavefront and k == "wavefront")]
    res: dict[str, Any] = dict(
        git_head=head,
        raytrax_modified=dirty,
        machine=dict(
            cpus=os.cpu_count(),
            cpu=cpu_description(),
            processor=platform.processor() or platform.machine(),
            python=platform.python_version(),
            jax=jax.__version__,
            jax_devices=jax.local_device_count(),
            raytrax=rt.__version__,
            mitsuba=mi.__version__,
            drjit=getattr(dr, "__version__", "?"),
            variant=args.variant,
            load_start=os.getloadavg(),
        ),
        config=dict(
            size=[W, H],
            grad_size=[gW, gH],
            spp=spp,
            depth=depth,
            repeats=args.repeats,
            grad_repeats=args.grad_repeats,
            grad=not args.no_grad,
            mi_forward=mi_fwd,
        ),
    )
    print(f"measuring at git HEAD {head} (load average {os.getloadavg()[0]:.1f}); the tables follow", flush=True)
    base = dict(spp=spp, depth=depth, variant=args.variant)

    # Fresh processes: first call and peak memory.
    fresh = {}
    fresh["rt_forward"] = run_worker(dict(base, task="rt", what="forward", W=W, H=H, repeats=2))
    for label in mi_fwd:
        fresh["mi_forward_" + label] = run_worker(
            dict(base, task="mi", what="forward", label=label, W=W, H=H, repeats=2), fresh_home=True
        )
    if not args.no_grad:
        fresh["rt_grad"] = run_worker(dict(base, task="rt", what="grad", W=gW, H=gH, repeats=1))
        fresh["rt_grad_lights"] = run_worker(dict(base, task="rt", what="grad_lights", W=gW, H=gH, repeats=1))
        for label in MI_GRAD:
            fresh["mi_grad_" + label] = run_worker(
                dict(base, task="mi", what="grad", label=label, W=gW, H=gH, repeats=1), fresh_home=True
            )
    res["fresh"] = fresh

    # One process, in turn: steady times and per-round ratios.
    pr = run_worker(
        dict(
            base,
            task="paired",
            W=W,
            H=H,
            gW=gW,
            gH=gH,
            repeats=args.repeats,
            grad_repeats=args.grad_repeats,
            grad=not args.no_grad,
            mi_forward=mi_fwd,
        )
    )
    res["paired"] = pr
    if args.psnr_spp:
        res["psnr"] = run_worker(dict(base, task="psnr", W=160, H=120, spp=args.psnr_spp))
    print()

    report(res)
    head2, dirty2, mtime1 = source_state()
    if head2 != head or mtime1 != mtime0:
        print(
            f"\nWARNING: files under raytrax/ were modified during the run (git HEAD {head} -> {head2}); "
            "the figures may mix versions."
        )
    res["machine"]["load_end"] = os.getloadavg()
    print(f"\nload average at the end: {os.getloadavg()[0]:.1f}; {time.perf_counter() - _T0:.0f} s in all")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
