"""Fits from far away with rt.fit's defaults: a table of scene, parameter, start,
truth, result, standard error, steps and time.

    python benchmarks/bench_fits.py                          # 48 x 36, spp 4
    python benchmarks/bench_fits.py --width 160 --height 120 --spp 16 --noise 0.01 --json fits.json

Cases: the index of a glass ball over a 10 x 10 checker of thin boxes
(examples/fit_glass_over_geometry.py) from 1.30 and from 1.80 with bounds
1.2-1.9, and the position of its light started about 13 units from the truth
with bounds of +-10 units. Each case is fitted with one local
Levenberg-Marquardt fit (``starts=1, levels=[0]``) and with the default (8
starts on images blurred by 5% of the width, then the sharp images);
``--modes default`` runs only the latter. ``--noise SIGMA`` adds Gaussian
noise of that standard deviation (per pixel and channel, seed ``--seed``) to
the target; the fit estimates the noise from its residual (column "noise").
Steps: the final run's steps + the starts' steps (+ intermediate levels').
Times include compilation: "wall s" is wall time (on a shared machine an upper
bound of the time alone on it), "CPU s" the process's CPU time over all its
threads (the work done; alone on the machine the wall time is at most about
this, as the fit is CPU-bound).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import pathlib
import time
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402

_spec = importlib.util.spec_from_file_location(
    "_glass", pathlib.Path(__file__).resolve().parents[1] / "examples" / "fit_glass_over_geometry.py"
)
assert _spec is not None and _spec.loader is not None
glass = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(glass)

LIGHT = "light[0].position"
TRUE_LIGHT = np.array([3.0, 6.0, 2.0])
START_LIGHT = np.array([-8.0, 9.0, 8.0])  # 12.9 units away
CASES = {
    "ior130": ("glass over boxes", glass.NAME, 1.30, glass.TRUE_IOR, {glass.NAME: (1.2, 1.9)}),
    "ior180": ("glass over boxes", glass.NAME, 1.80, glass.TRUE_IOR, {glass.NAME: (1.2, 1.9)}),
    "light": ("glass over boxes", LIGHT, START_LIGHT, TRUE_LIGHT, {LIGHT: ([-10.0, 1.0, -10.0], [10.0, 12.0, 10.0])}),
}
MODES = {"local": dict(starts=1, levels=[0.0]), "default": {}}


def _fmt(v):
    a = np.atleast_1d(np.asarray(v, np.float64))
    return " ".join(f"{x:.4g}" for x in a)


def _list(v):
    return np.asarray(v, np.float64).tolist()


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--width", type=int, default=48)
    ap.add_argument("--height", type=int, default=36)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--steps", type=int, default=30, help="max_steps of the final run")
    ap.add_argument("--noise", type=float, default=0.0, help="Gaussian noise sigma added to the target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {','.join(CASES)}")
    ap.add_argument("--modes", default="local,default", help="comma-separated, of local,default")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    a = ap.parse_args(argv)
    w, h, spp = a.width, a.height, a.spp
    truth = glass.make_scene(w, h, glass.TRUE_IOR, spp)
    target = np.asarray(rt.render(truth))
    if a.noise > 0:
        target = target + np.random.default_rng(a.seed).normal(0.0, a.noise, target.shape).astype(target.dtype)
    rows, records = [], []
    for case in a.cases.split(","):
        scene_name, name, start, true, bounds = CASES[case]
        for mode in a.modes.split(","):
            s = rt.with_parameters(truth, {name: np.asarray(start, np.float32)})
            t, c = time.perf_counter(), time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = rt.fit(s, target, [name], bounds=bounds, max_steps=a.steps, progress=False, **MODES[mode])
            dt, dc = time.perf_counter() - t, time.process_time() - c
            search_steps = sum(r["steps"] for r in res.starts) + sum(r["steps"] for r in res.levels)
            steps = f"{res.steps}" + (f"+{search_steps}" if res.starts else "")
            err = float(np.max(np.abs(np.asarray(res.params[name], np.float64) - true)))
            se = None if res.stderr is None else res.stderr[name]
            rows.append(
                (
                    scene_name,
                    name,
                    mode,
                    _fmt(start),
                    _fmt(true),
                    _fmt(res.params[name]),
                    f"{err:.1e}",
                    "-" if se is None else _fmt(se),
                    "-" if res.noise is None else f"{res.noise:.3g}",
                    steps,
                    f"{dt:.1f}",
                    f"{dc:.1f}",
                )
            )
            records.append(
                dict(
                    scene=scene_name,
                    parameter=name,
                    mode=mode,
                    start=_list(start),
                    truth=_list(true),
                    result=_list(res.params[name]),
                    max_abs_error=err,
                    stderr=None if se is None else _list(se),
                    noise_estimated=res.noise,
                    final_steps=res.steps,
                    search_steps=search_steps,
                    converged=res.converged,
                    message=res.message,
                    seconds=dt,
                    cpu_seconds=dc,
                )
            )
            print(" | ".join(rows[-1]), flush=True)
    head = (
        "scene",
        "parameter",
        "fit",
        "start",
        "truth",
        "result",
        "max |error|",
        "std. error",
        "noise",
        "steps",
        "wall s",
        "CPU s",
    )
    sigma = f"target noise sigma {a.noise:g} (seed {a.seed})" if a.noise > 0 else "noise-free target"
    setup = f"{w} x {h}, spp {spp}, max_steps {a.steps}, {sigma}, {jax.devices()[0].platform}"
    print(f"\n{setup}\n")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(len(head))]
    for r in [head, tuple("-" * x for x in widths)] + rows:
        print("| " + " | ".join(c.ljust(x) for c, x in zip(r, widths)) + " |")
    if a.json:
        out = dict(width=w, height=h, spp=spp, max_steps=a.steps, noise=a.noise, seed=a.seed, rows=records)
        pathlib.Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
