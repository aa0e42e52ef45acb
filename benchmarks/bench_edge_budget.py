"""Edge mode's cost against its ``edge_budget``: the same value_and_grad with the default
budget and with smaller ones, compiled in one process and called in alternating rounds.

    python benchmarks/bench_edge_budget.py                               # edge_occluders 64 x 48, spp 16
    python benchmarks/bench_edge_budget.py --scene glass_over_boxes --budgets 4096,8192
    python benchmarks/bench_edge_budget.py --scene edge_sphere --size 160x120 --budgets 2x,4x

Prints what the scene needs (``rt.edge_pairs``; a budget ``Nx`` is N times that), each
budget's first call and its steady time (min and median over the rounds), and the largest
difference of its gradient from the default budget's (0 where the budget holds every pair:
the same events are found either way).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import raytrax as rt
from scenes import image_size  # pyright: ignore[reportAttributeAccessIssue]

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def _budgets(text: str) -> list[int | float]:
    """Comma-separated positive integers, or multiples of what the scene needs (``4x``)."""
    out: list[int | float] = []
    try:
        for b in (b.strip() for b in text.split(",")):
            if b:
                out.append(float(b[:-1]) if b.endswith("x") else int(b))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers or multiples such as 4096,4x, got {text!r}"
        ) from None
    if any(b <= 0 for b in out):
        raise argparse.ArgumentTypeError(f"expected positive budgets, got {text!r}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="edge_occluders")
    ap.add_argument("--size", type=image_size, default=(64, 48), help="WIDTHxHEIGHT (default 64x48)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--budgets", type=_budgets, default=[4096], help="comma-separated budgets besides the default")
    ap.add_argument("--rounds", type=int, default=6)
    a = ap.parse_args()
    W, H = a.size
    path = SCENES / f"{a.scene}.toml"
    if not path.is_file():
        ap.error(
            f"--scene: no scene {path.name} in {SCENES} (one of {', '.join(sorted(p.stem for p in SCENES.glob('*.toml')))})"
        )
    scene = rt.load_scene(path)
    params = rt.parameters(scene)
    need = rt.edge_pairs(scene, width=W, height=H, spp=a.spp)
    budgets = [None] + [max(1, round(b * need)) if isinstance(b, float) else b for b in a.budgets]

    def make(budget):
        def loss(p):
            img = rt.render(
                rt.with_parameters(scene, p), width=W, height=H, spp=a.spp, edge_gradients=True, edge_budget=budget
            )
            return jnp.mean(img**2)

        return jax.jit(jax.value_and_grad(loss))

    fs, grads, first = {}, {}, {}
    for b in budgets:
        fs[b] = make(b)
        t = time.perf_counter()
        grads[b] = jax.block_until_ready(fs[b](params))[1]
        first[b] = time.perf_counter() - t
    times = {b: [] for b in budgets}
    for r in range(a.rounds):
        for b in budgets if r % 2 else budgets[::-1]:
            t = time.perf_counter()
            jax.block_until_ready(fs[b](params))
            times[b].append(time.perf_counter() - t)
    print(f"{a.scene} {W} x {H}, spp {a.spp}: value_and_grad with edge_gradients=True, {a.rounds} alternating rounds")
    print(f"rt.edge_pairs: {need}")
    print(f"{'edge_budget':>12} {'first s':>8} {'min s':>7} {'median s':>9} {'max |grad - default|':>21}")
    for b in budgets:
        ts = sorted(times[b])
        diff = max(float(jnp.max(jnp.abs(grads[b][k] - grads[None][k]))) for k in grads[None])
        name = "default" if b is None else str(b)
        print(f"{name:>12} {first[b]:8.1f} {ts[0]:7.3f} {ts[len(ts) // 2]:9.3f} {diff:21.3g}")


if __name__ == "__main__":
    main()
