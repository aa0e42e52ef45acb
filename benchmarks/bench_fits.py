"""Fits from far away with rt.fit's defaults: a table of scene, parameter, start,
truth, result, standard error, steps and time.

    python benchmarks/bench_fits.py                          # 48 x 36, spp 4
    python benchmarks/bench_fits.py --width 160 --height 120 --spp 16

Cases: the index of a glass ball over a 10 x 10 checker of thin boxes
(examples/fit_glass_over_geometry.py) from 1.30 and from 1.80 with bounds
1.2-1.9, and the position of its light started about 13 units from the truth
with bounds of +-10 units. Each case is fitted twice: one local
Levenberg-Marquardt fit (``starts=1, levels=[0]``) and the default (8 starts
on images blurred by 5% of the width, then the sharp images). Steps: the
final run's steps + the starts' steps. Time includes compilation.
"""

from __future__ import annotations

import argparse
import importlib.util
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
glass = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(glass)  # type: ignore[union-attr]

LIGHT = "light[0].position"
TRUE_LIGHT = np.array([3.0, 6.0, 2.0])
START_LIGHT = np.array([-8.0, 9.0, 8.0])  # 12.9 units away


def _fmt(v):
    a = np.atleast_1d(np.asarray(v, np.float64))
    return " ".join(f"{x:.4g}" for x in a)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=48)
    ap.add_argument("--height", type=int, default=36)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--steps", type=int, default=30)
    a = ap.parse_args(argv)
    w, h, spp = a.width, a.height, a.spp
    truth = glass.make_scene(w, h, glass.TRUE_IOR, spp)
    target = rt.render(truth)
    cases = [
        ("glass over boxes", glass.NAME, 1.30, glass.TRUE_IOR, {glass.NAME: (1.2, 1.9)}),
        ("glass over boxes", glass.NAME, 1.80, glass.TRUE_IOR, {glass.NAME: (1.2, 1.9)}),
        ("glass over boxes", LIGHT, START_LIGHT, TRUE_LIGHT, {LIGHT: ([-10.0, 1.0, -10.0], [10.0, 12.0, 10.0])}),
    ]
    rows = []
    for scene_name, name, start, true, bounds in cases:
        for mode, extra in (("local", dict(starts=1, levels=[0.0])), ("default", {})):
            s = rt.with_parameters(truth, {name: np.asarray(start, np.float32)})
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = rt.fit(s, target, [name], bounds=bounds, max_steps=a.steps, progress=False, **extra)
            dt = time.perf_counter() - t
            se = "-" if res.stderr is None else _fmt(res.stderr[name])
            steps = f"{res.steps}" + (f"+{sum(r['steps'] for r in res.starts)}" if res.starts else "")
            err = float(np.max(np.abs(np.asarray(res.params[name], np.float64) - true)))
            rows.append(
                (
                    scene_name,
                    name,
                    mode,
                    _fmt(start),
                    _fmt(true),
                    _fmt(res.params[name]),
                    f"{err:.1e}",
                    se,
                    steps,
                    f"{dt:.1f}",
                )
            )
            print(" | ".join(rows[-1]), flush=True)
    head = ("scene", "parameter", "fit", "start", "truth", "result", "max |error|", "std. error", "steps", "time s")
    print(f"\n{w} x {h}, spp {spp}, max_steps {a.steps}, {jax.devices()[0].platform}\n")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(len(head))]
    for r in [head, tuple("-" * x for x in widths)] + rows:
        print("| " + " | ".join(c.ljust(x) for c, x in zip(r, widths)) + " |")


if __name__ == "__main__":
    main()
