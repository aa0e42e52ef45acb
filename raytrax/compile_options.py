"""The XLA options raytrax compiles with, for the whole process or your own ``jax.jit``.

On CPU, XLA's default loop emitters (the MLIR fusion emitters) take 1.3-2x as
long to compile raytrax's programs as the older emitters (the forward render of
a ten-object scene: 3.3-3.6 s against 1.8 s; its ``value_and_grad``: 12.6-13.8 s
against 9.4-9.5 s; a first eager ``jax.grad``: 18.9 s against 11.4 s), and the
compiled renders run as fast either way (``benchmarks/bench_speed.py``).

On a CPU with AVX-512, XLA is also asked for 512-bit vectors (its default prefers
256): the forward render (640 x 480, spp 4, depth 6) runs in 0.126-0.131 s against
0.134-0.143 s and its ``value_and_grad`` (320 x 240) in 0.238-0.256 s against
0.246-0.294 s (fastest of seven calls; five pairs of processes, alternating; a
2-core AMD EPYC).
Images differ from 256-bit code by float rounding only (float32: at most 2e-4,
in 2 % of the pixels of that scene; the float64 golden tests agree to 1e-12).

``import raytrax`` adds these options to ``XLA_FLAGS`` (:func:`request`): each that
``XLA_FLAGS`` does not set already, if jax's backends have not started and
jaxlib is a version the options were checked with (:data:`CHECKED_JAXLIB`; XLA
stops the process on a flag it does not know). Every compilation of the process
then uses them, yours included. ``RAYTRAX_XLA_FLAGS=0`` leaves ``XLA_FLAGS``
alone. Where the flags could not be set (jax had started), raytrax's own
compiled entry points (:func:`raytrax.render`, the fitting helpers, the CLI)
still pass :func:`compiler_options`; give it to the ``jax.jit`` that wraps a
render in your code::

    step = jax.jit(jax.value_and_grad(loss), compiler_options=rt.compiler_options())
"""

from __future__ import annotations

import functools
import os
import sys
from typing import Any


def first_cpu_lines() -> list[str]:
    """The lines (newlines kept) of the first processor's entry in Linux's
    ``/proc/cpuinfo``; empty where that cannot be read."""
    lines = []
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if not line.strip():
                    break  # the first processor is enough
                lines.append(line)
    except OSError:
        pass
    return lines


def cpu_has_avx512() -> bool:
    """Whether this machine's CPU has AVX-512 (the ``avx512f`` flag of
    :func:`first_cpu_lines`; ``False`` where they cannot be read)."""
    return any(ln.startswith("flags") and "avx512f" in ln.split() for ln in first_cpu_lines())


def _cpu_options() -> dict[str, Any]:
    opts: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}
    if cpu_has_avx512():
        opts["xla_cpu_prefer_vector_width"] = 512
    return opts


CPU_OPTIONS: dict[str, Any] = _cpu_options()
"""XLA debug options for the CPU backend: the faster-compiling loop emitters, and
512-bit vectors where the CPU has AVX-512."""

CHECKED_JAXLIB = ((0, 10),)
"""jaxlib (major, minor) versions whose XLA has the options of :data:`CPU_OPTIONS`."""

ENV = "RAYTRAX_XLA_FLAGS"


def jaxlib_checked() -> bool:
    """Whether the installed jaxlib is one of :data:`CHECKED_JAXLIB` (without importing it)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(p) for p in version("jaxlib").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return False
    return (major, minor) in CHECKED_JAXLIB


def flag(name: str, value: Any) -> str:
    """``XLA_FLAGS``' spelling of one option: ``--name=value`` (booleans in lower case)."""
    return f"--{name}={str(value).lower() if isinstance(value, bool) else value}"


def request() -> bool:
    """Add the options of :data:`CPU_OPTIONS` that ``XLA_FLAGS`` does not set to it,
    for this process, when it is still free to (see the module docstring). Returns
    whether it did. Does not import jax."""
    flags = os.environ.get("XLA_FLAGS", "")
    missing = [(k, v) for k, v in CPU_OPTIONS.items() if k not in flags]  # the user's choices stay
    if os.environ.get(ENV, "1") == "0" or not missing or not jaxlib_checked():
        return False
    if "jax" in sys.modules:  # only before jax's backends start: XLA reads its flags then
        try:
            from jax._src import xla_bridge

            if xla_bridge.backends_are_initialized():
                return False
        except Exception:  # pragma: no cover - another jax version: leave it alone
            return False
    os.environ["XLA_FLAGS"] = " ".join([flags] + [flag(k, v) for k, v in missing]).strip()
    return True


def compiler_options(backend: str | None = None) -> dict[str, Any]:
    """XLA options for compiling raytrax programs on ``backend`` (default: jax's
    default backend): :data:`CPU_OPTIONS` on ``"cpu"`` with a checked jaxlib, none
    elsewhere. A new dict,
    for ``jax.jit(..., compiler_options=...)``."""
    import jax

    if backend is None:
        backend = jax.default_backend()
    return dict(CPU_OPTIONS) if backend == "cpu" and jaxlib_checked() else {}


def top_level() -> bool:
    """Whether no jax transformation is tracing now: jax accepts compiler options
    only on a top-level ``jax.jit``. False where jax's internals have moved (the
    options are then left out, never wrongly passed)."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:  # pragma: no cover - another jax version
        return False
    return bool(trace_state_clean())


_PASSING_TRACES = ("EvalTrace", "JVPTrace", "LinearizeTrace", "BatchTrace")


def evaluates_now() -> bool:
    """Whether a function of concrete (non-traced) arrays called now runs and returns
    concrete arrays: outside any transformation, or inside an eager ``jax.grad``,
    ``jax.jvp`` or ``jax.vmap`` (which pass such a call through untouched), but not
    while ``jax.jit`` (or anything else that stages) is tracing. False where jax's
    internals have moved."""
    try:
        from jax._src.core import trace_ctx
    except ImportError:  # pragma: no cover - another jax version
        return False
    t = getattr(trace_ctx, "trace", None)
    if t is None:  # pragma: no cover - another jax version
        return False
    while t is not None:
        if type(t).__name__ not in _PASSING_TRACES:
            return False
        t = getattr(t, "parent_trace", None)
    return True


def concrete(tree) -> bool:
    """Whether ``tree``'s leaves are all concrete (no jax tracer) and a function of
    them called now runs at once (:func:`evaluates_now`)."""
    import jax
    from jax.core import Tracer

    return not any(isinstance(x, Tracer) for x in jax.tree.leaves(tree)) and evaluates_now()


def filter_jit(fun):
    """``eqx.filter_jit(fun)``, compiled with :func:`compiler_options` of the default
    backend when called outside any jax transformation or with concrete arguments
    (:func:`concrete`; nested inside another ``jax.jit``, or given traced values under
    ``jax.grad``, the outer compile's options apply). The wrappers are
    made on first use, so that importing raytrax does not start jax's backends."""
    import equinox as eqx

    made: dict[Any, Any] = {}

    @functools.wraps(fun)
    def call(*args, **kwargs):
        import jax

        # Called with concrete arguments inside an eager jax.grad (the edge finder is),
        # the program runs outside the transformation: the same one as at top level.
        key = jax.default_backend() if top_level() or concrete((args, kwargs)) else None
        jitted = made.get(key)
        if jitted is None:
            if key is None:
                jitted = eqx.filter_jit(fun)
            else:
                jitted = eqx.filter_jit(fun, compiler_options=compiler_options(key))  # pyright: ignore[reportCallIssue]
            made[key] = jitted
        return jitted(*args, **kwargs)

    return call
