"""Render one image across several JAX *processes* (``jax.distributed``) on this machine.

    python benchmarks/multihost_demo.py                  # 2 processes x 2 CPU devices each
    python benchmarks/multihost_demo.py --processes 2 --devices-per-process 1

The launcher starts ``--processes`` copies of this script (``--worker I``), each
calling ``jax.distributed.initialize(coordinator_address="localhost:PORT",
num_processes=N, process_id=I)`` on the CPU backend (cross-process collectives:
gloo over TCP, ``jax_cpu_collectives_implementation``, jax's default on CPU) with
``jax_num_cpu_devices`` local devices each. ``jax.devices()`` is then the global
list, so ``rt.render(scene, devices="all")`` builds a mesh over every process's
devices. Each worker reports what it saw and what worked; the launcher compares
the gathered image with a single-process render of the same scene (run in a
separate process without ``jax.distributed``).

This is the experiment behind ``docs/scaling.md`` ("Many hosts"); on real hosts
the launcher is replaced by one worker per host (Slurm, Open MPI and Cloud TPU are
auto-detected by ``jax.distributed.initialize()`` without arguments).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
import traceback

TILE_RAYS = 64  # small tiles: 24 x 16 pixels = 6 tiles, spread over the devices


def _scene():
    import raytrax as rt

    # The scene of tests/test_devices.py: small, quick to compile.
    return rt.load_scene(
        os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "ball_on_checker.toml")
    )


def _step(report, name, fn):
    """Run ``fn``; record ``ok`` and its value or the error (type and first line)."""
    t = time.perf_counter()
    try:
        value = fn()
        report[name] = dict(ok=True, s=round(time.perf_counter() - t, 2))
        return value
    except Exception as e:  # noqa: BLE001 - the point is to report it
        msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
        tb = traceback.format_exc()
        print(f"--- {name} ---\n{tb}", file=sys.stderr, flush=True)
        frames = [ln.strip() for ln in tb.splitlines() if ln.strip().startswith("File ")]
        report[name] = dict(
            ok=False, error=f"{type(e).__name__}: {msg[:400]}", where=" <- ".join(reversed(frames[-3:]))[:600]
        )
        return None


def worker(args):
    import jax

    jax.config.update("jax_platforms", "cpu")
    jax.config.update("jax_num_cpu_devices", args.devices_per_process)
    rep = dict(process=args.worker)
    if args.worker >= 0:
        _step(
            rep,
            "initialize",
            lambda: jax.distributed.initialize(
                coordinator_address=f"localhost:{args.port}",
                num_processes=args.processes,
                process_id=args.worker,
                initialization_timeout=120,
            ),
        )
    import numpy as np

    import raytrax as rt

    rep.update(
        process_index=jax.process_index(),
        process_count=jax.process_count(),
        local_devices=[str(d) for d in jax.local_devices()],
        global_devices=[str(d) for d in jax.devices()],
    )
    scene = _scene()
    out = dict()

    if args.worker < 0:  # the reference: one process, one device
        img = rt.render(scene, tile_rays=TILE_RAYS)
        np.save(os.path.join(args.out, "reference.npy"), np.asarray(img))
        import equinox as eqx
        import jax.numpy as jnp

        g = eqx.filter_grad(lambda s: jnp.mean(rt.render(s, tile_rays=TILE_RAYS) ** 2))(scene)
        np.save(os.path.join(args.out, "reference-grad.npy"), np.asarray(g.lights.position))
        print(json.dumps(rep), flush=True)
        return 0

    # 1. Plain rt.render over every global device: the scene's arrays are
    #    process-local (committed to no device, built on local device 0).
    img = _step(
        rep, "render_all_devices", lambda: jax.block_until_ready(rt.render(scene, tile_rays=TILE_RAYS, devices="all"))
    )
    if img is not None:
        rep["image_sharding"] = str(img.sharding)
        rep["fully_addressable"] = bool(img.is_fully_addressable)
        rep["fully_replicated"] = bool(img.sharding.is_fully_replicated)
        # A fully replicated output can be read on every process; otherwise gather it.
        if img.is_fully_addressable:
            out["render"] = _step(rep, "read_local", lambda: np.asarray(img))
        else:
            from jax.experimental import multihost_utils

            out["render"] = _step(
                rep, "process_allgather", lambda: np.asarray(multihost_utils.process_allgather(img, tiled=True))
            )

    # 2. The same with the scene first made a global, replicated array on the
    #    global mesh (what multi-process jit expects of its arguments). The mesh
    #    has Auto axes, like the one _render builds; with jax.make_mesh's default
    #    (Explicit axes in jax 0.10) the gradient fails (step 3).
    def global_scene(axis_type):
        import equinox as eqx
        from jax.sharding import NamedSharding
        from jax.sharding import PartitionSpec as P

        mesh = jax.make_mesh((jax.device_count(),), ("tiles",), devices=jax.devices(), axis_types=(axis_type,))
        rep_sh = NamedSharding(mesh, P())
        dyn, static = eqx.partition(scene, eqx.is_array)
        dyn = jax.tree_util.tree_map(
            lambda x: jax.make_array_from_process_local_data(rep_sh, np.asarray(x), x.shape), dyn
        )
        return eqx.combine(dyn, static)

    gscene = _step(rep, "make_global_scene", lambda: global_scene(jax.sharding.AxisType.Auto))
    if gscene is not None:
        img2 = _step(
            rep,
            "render_global_scene",
            lambda: jax.block_until_ready(rt.render(gscene, tile_rays=TILE_RAYS, devices="all")),
        )
        if img2 is not None:
            rep["image2_sharding"] = str(img2.sharding)
            if img2.is_fully_addressable:
                out["render_global"] = _step(rep, "read_local2", lambda: np.asarray(img2))
            else:
                from jax.experimental import multihost_utils

                out["render_global"] = _step(
                    rep, "process_allgather2", lambda: np.asarray(multihost_utils.process_allgather(img2, tiled=True))
                )

    # 3. Gradient across processes: d mean(img^2) / d light position, with the
    #    process-local scene, the global scene (Auto axes), and a global scene on
    #    a mesh with Explicit axes.
    def grad_of(s):
        def fn():
            import equinox as eqx
            import jax.numpy as jnp
            from jax.experimental import multihost_utils

            g = eqx.filter_grad(lambda s: jnp.mean(rt.render(s, tile_rays=TILE_RAYS, devices="all") ** 2))(s)
            p = g.lights.position
            return np.asarray(p if p.is_fully_addressable else multihost_utils.process_allgather(p, tiled=True))

        return fn

    out["grad_local"] = _step(rep, "grad_local_scene", grad_of(scene))
    if gscene is not None:
        out["grad_global"] = _step(rep, "grad_global_scene", grad_of(gscene))
        xscene = _step(rep, "make_global_scene_explicit", lambda: global_scene(jax.sharding.AxisType.Explicit))
        if xscene is not None:
            out["grad_global_explicit"] = _step(rep, "grad_global_explicit", grad_of(xscene))

    for k, v in out.items():
        if v is not None:
            np.save(os.path.join(args.out, f"p{args.worker}-{k}.npy"), v)
    print(json.dumps(rep), flush=True)
    if args.worker >= 0:
        jax.distributed.shutdown()
    return 0


def _free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def launcher(args):
    import tempfile

    import numpy as np

    out = tempfile.mkdtemp(prefix="raytrax-multihost-")
    here = os.path.abspath(__file__)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env.pop("XLA_FLAGS", None)  # device counts come from jax_num_cpu_devices
    base = [
        sys.executable,
        here,
        "--out",
        out,
        "--processes",
        str(args.processes),
        "--devices-per-process",
        str(args.devices_per_process),
    ]
    print("reference: 1 process, 1 device ...", flush=True)
    ref = subprocess.run(
        base + ["--worker", "-1", "--devices-per-process", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=args.timeout,
    )
    if ref.returncode != 0:
        print(ref.stderr[-3000:])
        return 1
    port = _free_port()
    print(
        f"{args.processes} processes x {args.devices_per_process} CPU devices, coordinator localhost:{port} ...",
        flush=True,
    )
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(
            base + ["--worker", str(i), "--port", str(port)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(args.processes)
    ]
    reports = []
    for i, p in enumerate(procs):
        try:
            so, se = p.communicate(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            so, se = p.communicate()
            print(f"process {i}: TIMEOUT after {args.timeout} s")
        lines = [ln for ln in so.splitlines() if ln.startswith("{")]
        if lines:
            reports.append(json.loads(lines[-1]))
        else:
            print(f"process {i}: exit {p.returncode}, no report; stderr tail:\n{se[-3000:]}")
        if args.verbose:
            print(f"--- process {i} stderr ---\n{se[-5000:]}")
    print(f"workers done in {time.perf_counter() - t0:.1f} s\n")
    reference = np.load(os.path.join(out, "reference.npy"))
    for r in reports:
        i = r["process"]
        print(
            f"process {i}: process_index {r.get('process_index')} of {r.get('process_count')}, "
            f"local devices {r.get('local_devices')}, {len(r.get('global_devices', []))} global devices"
        )
        for k, v in r.items():
            if isinstance(v, dict) and "ok" in v:
                print(
                    f"  {k:22s} {'ok' if v['ok'] else 'FAILED'}"
                    + (f" ({v['s']} s)" if v["ok"] else f": {v['error']}\n  {'':22s} at {v['where']}")
                )
        for k in ("image_sharding", "fully_addressable", "fully_replicated", "image2_sharding"):
            if k in r:
                print(f"  {k:22s} {r[k]}")
        for what in ("render", "render_global"):
            f = os.path.join(out, f"p{i}-{what}.npy")
            if os.path.exists(f):
                img = np.load(f)
                same = img.shape == reference.shape and np.allclose(img, reference, rtol=0, atol=1e-6)
                err = float(np.abs(img - reference).max()) if img.shape == reference.shape else float("nan")
                print(
                    f"  {what:22s} image {img.shape}: {'EQUALS' if same else 'DIFFERS FROM'} the single-process "
                    f"render (max |diff| {err:.2e})"
                )
        gref = np.load(os.path.join(out, "reference-grad.npy"))
        for what in ("grad_local", "grad_global", "grad_global_explicit"):
            f = os.path.join(out, f"p{i}-{what}.npy")
            if os.path.exists(f):
                g = np.load(f)
                same = np.allclose(g, gref, rtol=1e-5, atol=1e-9)
                print(
                    f"  {what:22s} d loss / d light position {np.round(g.ravel(), 6).tolist()}: "
                    f"{'EQUALS' if same else 'DIFFERS FROM'} the single-process gradient "
                    f"{np.round(gref.ravel(), 6).tolist()}"
                )
    return 0


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--processes", type=int, default=2)
    p.add_argument("--devices-per-process", type=int, default=2)
    p.add_argument("--timeout", type=float, default=600)
    p.add_argument("--verbose", action="store_true", help="print the workers' stderr")
    p.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--port", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker is not None:
        return worker(args)
    return launcher(args)


if __name__ == "__main__":
    sys.exit(main())
