"""Where an edge-mode value_and_grad spends its time, by program, step and budget.

    python benchmarks/profile_edges.py                                  # edge_sphere, 160 x 120, spp 16
    python benchmarks/profile_edges.py --scene edge_occluders --top 20
    python benchmarks/profile_edges.py --budgets default,4x             # what the budget's size costs

The loss is ``bench_edges.py``'s for a scene file (float32): the mean of a smooth
weight times the image, differentiated with respect to every light position and
every object's geometry, ``jax.jit(jax.value_and_grad(...))`` with
``rt.compiler_options()``. Each budget's program is compiled, run twice, timed
over ``--calls`` calls, then profiled over ``--calls`` more with
``jax.profiler``; every kernel's exclusive time on XLA's worker threads (as in
``profile_ops.py``) is attributed through the compiled HLO's ``op_name`` to one
of edge mode's three programs (``_find``: finding the edges; ``_grid``: the
sample grid's image and its silhouette quadrature, differentiated;
``_edge_image``: the boundary term), to the named step inside it
(``edge_records``, ``edge_locate``, ``edge_follow``, ``edge_probes``, the
grid's traced tiles ``jit(go)``, else the program's own bookkeeping) and to the
forward or the transposed (reverse) pass. XLA's runtime (thunk executor, threads
waiting, library transposes and copies) is listed apart.

With several ``--budgets`` (``default``: the render's default edge budget;
``4x``: four times what ``rt.edge_pairs`` says the scene needs; or a number),
the table gets a column per budget and the difference between the first two:
the work that grows with the budget rather than with the edges present.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import re
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from profile_ops import exclusive_times, hlo_ops  # noqa: E402

from scenes import at_least, image_size  # noqa: E402  # pyright: ignore[reportAttributeAccessIssue]

PROGRAMS = ("jit(_find)", "jit(_grid)", "jit(_edge_image)")
STEPS = ("edge_records", "edge_locate", "edge_follow", "edge_probes", "jit(go)")
RUNTIME = ("ThunkExecutor", "Wait", "Rendezvous", "InvokeRendezvous", "Transpose", "copy")


def where(op: str) -> tuple[str, str]:
    """(program, step and pass) of a kernel's jax ``op_name``."""
    program = next((p[4:-1] for p in PROGRAMS if p in op), "outside")
    step = next((s for s in STEPS if s in op), "bookkeeping")
    return program, f"{step}{' (reverse)' if 'transpose(' in op else ''}"


def profile(scene_name: str, W: int, H: int, spp: int, budget: str, calls: int):
    """-> (median seconds per call, {(program, step): thread-ms per call}, [(ms, shape, op)])."""
    import jax
    import jax.numpy as jnp

    import raytrax as rt
    from raytrax.testing import smooth_weights

    path = os.path.join(HERE, "..", "scenes", f"{scene_name}.toml")
    sc = rt.load_scene(path, dtype=jnp.float32).replace_settings(width=W, height=H, spp=spp)
    kw = {}
    if budget == "4x":
        kw["edge_budget"] = 4 * rt.edge_pairs(sc)
    elif budget != "default":
        kw["edge_budget"] = int(budget)
    wgt = jnp.asarray(smooth_weights(H, W), sc.dtype)
    q0 = {k: v for k, v in rt.parameters(sc).items() if k.startswith("object[") or k.endswith("].position")}

    def loss(q):
        return jnp.mean(wgt * rt.render(rt.with_parameters(sc, q), edge_gradients=True, **kw))

    compiled = jax.jit(jax.value_and_grad(loss), compiler_options=rt.compiler_options()).lower(q0).compile()
    ops = hlo_ops(compiled.as_text() or "")
    for _ in range(2):
        jax.block_until_ready(compiled(q0))
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        jax.block_until_ready(compiled(q0))
        times.append(time.perf_counter() - t)
    with tempfile.TemporaryDirectory() as tmp:
        jax.profiler.start_trace(tmp)
        for _ in range(calls):
            jax.block_until_ready(compiled(q0))
        jax.profiler.stop_trace()
        (xplane,) = glob.glob(os.path.join(tmp, "**", "*.xplane.pb"), recursive=True)
        excl = exclusive_times(xplane)
    parts: collections.defaultdict[tuple[str, str], float] = collections.defaultdict(float)
    kernels = []
    for name, ns in excl.items():
        ms = ns / calls / 1e6
        base = name.split(":")[0]
        if base.startswith(RUNTIME) or base not in ops:
            parts[("runtime", re.sub(r"[.\d]+$", "", base.split("::")[0]))] += ms
            continue
        shape, op = ops[base]
        parts[where(op)] += ms
        kernels.append((ms, shape, op))
    return statistics.median(times), parts, sorted(kernels, reverse=True)


SCENES = sorted(os.path.basename(p)[:-5] for p in glob.glob(os.path.join(HERE, "..", "scenes", "*.toml")))


def budget_list(text: str) -> list[str]:
    """``--budgets``: comma-separated ``default``, ``4x`` or positive integers."""
    out = [b.strip() for b in text.split(",")]
    for b in out:
        if b not in ("default", "4x") and not (b.isdigit() and int(b) > 0):
            raise argparse.ArgumentTypeError(f"{b!r}: expected default, 4x or a positive integer")
    return out


def main():
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--scene", default="edge_sphere", choices=SCENES, help="a scenes/*.toml name")
    ap.add_argument("--size", type=image_size, default=(160, 120), help="WxH")
    ap.add_argument("--spp", type=at_least(1), default=16)
    ap.add_argument("--budgets", type=budget_list, default="default", help="comma-separated: default, 4x or a number")
    ap.add_argument("--calls", type=at_least(1), default=3)
    ap.add_argument("--top", type=at_least(0), default=12)
    args = ap.parse_args()
    W, H = args.size
    budgets = args.budgets
    runs = [profile(args.scene, W, H, args.spp, b, args.calls) for b in budgets]

    print(f"{args.scene}, {W} x {H}, spp {args.spp}, float32: jax.jit(jax.value_and_grad), edge_gradients=True")
    print("\n| budget | median call (s) | thread time per call (ms) |")
    print("|---|---|---|")
    for b, (t, parts, _) in zip(budgets, runs):
        print(f"| {b} | {t:.3f} | {sum(parts.values()):.0f} |")
    keys = sorted(set().union(*(r[1] for r in runs)), key=lambda k: -runs[0][1][k])
    diff = len(runs) > 1
    print(
        "\n| program | step | "
        + " | ".join(f"{b} (ms)" for b in budgets)
        + (f" | {budgets[0]} - {budgets[1]} (ms)" if diff else "")
        + " | share |"
    )
    print("|---|---|" + "---|" * (len(budgets) + diff + 1))
    total = sum(runs[0][1].values())
    for k in keys:
        vals = [r[1][k] for r in runs]
        if max(vals) < 0.005 * total:
            continue
        extra = f" | {vals[0] - vals[1]:+.1f}" if diff else ""
        print(f"| {k[0]} | {k[1]} | " + " | ".join(f"{v:.1f}" for v in vals) + extra + f" | {vals[0] / total:.1%} |")
    for b, (_, _, kernels) in zip(budgets, runs):
        if not args.top:
            break
        print(f"\nlargest kernels, budget {b} (thread-ms per call, output shape, jax op):")
        for ms, shape, op in kernels[: args.top]:
            print(f"  {ms:7.2f}  {shape[:40]:40s}  {op[-110:]}")


if __name__ == "__main__":
    main()
