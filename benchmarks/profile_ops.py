"""Where a compiled render or value_and_grad spends its time, by phase and by XLA kernel.

    python benchmarks/profile_ops.py                      # value_and_grad, 320 x 240
    python benchmarks/profile_ops.py --task forward --size 640x480
    python benchmarks/profile_ops.py --top 30
    python benchmarks/profile_ops.py --params lights        # the light positions only

Scene and loss as in ``bench_speed.py``: ``physical_scene`` of
``benchmarks/scenes.py`` (spp 4, depth 6), the image MSE to 0.5 with respect to
the light positions and every material's IOR (``--params lights``: the light
positions only). The program is compiled with
``rt.compiler_options()``, run twice, then ``--calls`` times under
``jax.profiler``. Each event of XLA's worker threads (a kernel, a loop, a
conditional) is charged its exclusive time (its duration less that of the
events nested in it), and each kernel is attributed, through the ``op_name`` of
the compiled HLO, to a phase:

* ``forward``: the primal render and the residuals reverse mode keeps;
* ``reverse: recompute``: what reverse mode recomputes under ``jax.checkpoint``
  (the tiles' renders, then each sub-tile's shading);
* ``reverse: transpose``: the transposed (cotangent) computations;
* ``runtime``: XLA's thunk executor and the threads waiting for each other.

Percentages are of the summed exclusive time of both threads; the largest
kernels are listed with their output shape and the jax operation they come
from. Reading the profile uses ``jax._src.lib._profile_data`` (jaxlib's reader
of the ``.xplane.pb`` files ``jax.profiler`` writes), a private module that may
move between jax versions.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import re
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from scenes import at_least, image_size, physical_scene  # noqa: E402  # pyright: ignore[reportAttributeAccessIssue]


def exclusive_times(xplane: str) -> collections.Counter:
    """Event name -> summed exclusive nanoseconds over XLA's worker threads."""
    from jax._src.lib import _profile_data  # pyright: ignore[reportAttributeAccessIssue]

    data = _profile_data.ProfileData.from_file(xplane)
    out: collections.Counter = collections.Counter()
    for plane in data.planes:
        for line in plane.lines:
            if "Eigen" not in line.name:  # XLA:CPU's worker threads
                continue
            evs = sorted(((e.start_ns, e.duration_ns, e.name) for e in line.events), key=lambda x: (x[0], -x[1]))
            stack: list[tuple[int, int]] = []  # (end, index) of the enclosing events
            excl: list[int] = []
            for i, (start, dur, _) in enumerate(evs):
                while stack and stack[-1][0] <= start:
                    stack.pop()
                if stack:
                    excl[stack[-1][1]] -= dur
                excl.append(dur)
                stack.append((start + dur, i))
            for (_, _, name), e in zip(evs, excl):
                out[name] += e
    return out


def hlo_ops(hlo_text: str) -> dict[str, tuple[str, str]]:
    """HLO instruction name -> (output shape, jax op_name) of the compiled module."""
    ops = {}
    pat = re.compile(r'^\s*(?:ROOT )?%(\S+) = (\([^=]*?\)|\S+) [a-z][\w-]*\(.*?op_name="([^"]*)"', re.M)
    for m in pat.finditer(hlo_text):
        ops.setdefault(m.group(1), (m.group(2), m.group(3)))
    return ops


def phase(op_name: str) -> str:
    if "transpose(" in op_name:
        return "reverse: recompute" if "rematted_computation" in op_name else "reverse: transpose"
    return "forward"


def main():
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--task", choices=("grad", "forward"), default="grad")
    ap.add_argument("--size", type=image_size, default=None, help="WxH (default 320x240 for grad, 640x480 for forward)")
    ap.add_argument("--spp", type=at_least(1), default=4)
    ap.add_argument("--depth", type=at_least(0), default=6)
    ap.add_argument("--calls", type=at_least(1), default=3)
    ap.add_argument("--top", type=at_least(0), default=15)
    ap.add_argument(
        "--params",
        choices=("lights+ior", "lights"),
        default="lights+ior",
        help="what grad differentiates (bench_speed's rows)",
    )
    args = ap.parse_args()
    W, H = args.size or ((320, 240) if args.task == "grad" else (640, 480))

    import jax
    import jax.numpy as jnp

    import raytrax as rt

    scene = physical_scene(W, H, args.spp, args.depth)
    p = rt.parameters(scene)
    names = [k for k in p if k.startswith("light[") and k.endswith(".position")]
    if args.params == "lights+ior":
        names += [k for k in p if k.endswith(".ior")]
    q0 = {k: p[k] for k in names}

    def loss(q):
        return jnp.mean((rt.render(rt.with_parameters(scene, q)) - 0.5) ** 2)

    fn = jax.value_and_grad(loss) if args.task == "grad" else loss
    compiled = jax.jit(fn, compiler_options=rt.compiler_options()).lower(q0).compile()
    ops = hlo_ops(compiled.as_text() or "")
    for _ in range(2):
        jax.block_until_ready(compiled(q0))
    with tempfile.TemporaryDirectory() as tmp:
        jax.profiler.start_trace(tmp)
        for _ in range(args.calls):
            jax.block_until_ready(compiled(q0))
        jax.profiler.stop_trace()
        (xplane,) = glob.glob(os.path.join(tmp, "**", "*.xplane.pb"), recursive=True)
        excl = exclusive_times(xplane)

    by_phase: collections.Counter = collections.Counter()
    kernels = []
    for name, ns in excl.items():
        base = name.split(":")[0]
        if base.startswith(("ThunkExecutor", "Wait", "Rendezvous", "InvokeRendezvous")):
            by_phase["runtime"] += ns
            continue
        shape, op = ops.get(base, ("?", ""))
        by_phase[phase(op) if op else "unattributed: " + re.sub(r"[.\d]+$", "", base)] += ns
        kernels.append((ns, base, shape, op))
    total = sum(by_phase.values())
    per_call_ms = total / args.calls / 1e6
    print(f"physical scene {W}x{H}, spp {args.spp}, depth {args.depth}, {args.task}; jax {jax.__version__}")
    print(f"exclusive time of XLA's threads per call: {per_call_ms:.0f} ms (summed over threads)")
    for k, v in by_phase.most_common():
        if v < 5e-4 * total:
            continue
        print(f"  {100 * v / total:5.1f} %  {k}")
    print(f"largest {args.top} kernels:")
    for ns, base, shape, op in sorted(kernels, reverse=True)[: args.top]:
        where = op.split("/")[-1] if op else ""
        print(
            f"  {100 * ns / total:5.1f} %  {phase(op) if op else '?':20s} {base[:44]:44s} {shape[:28]:28s} {where[:40]}"
        )


if __name__ == "__main__":
    main()
