"""The XLA options raytrax compiles with, for your own ``jax.jit`` as well.

On CPU, XLA's default loop emitters (the MLIR fusion emitters) take 1.3-2x as
long to compile raytrax's programs as the older emitters (the forward render of
a ten-object scene: 3.3-3.6 s against 1.8 s; its ``value_and_grad``: 12.6-13.8 s
against 9.4-9.5 s), and the compiled renders run as fast either way (``benchmarks/bench_speed.py``
measures both). raytrax's own compiled entry points (:func:`raytrax.render`,
the fitting helpers, the CLI) use :func:`compiler_options`; pass it to the
``jax.jit`` (or ``eqx.filter_jit``) that wraps a render in your code::

    step = jax.jit(jax.value_and_grad(loss), compiler_options=rt.compiler_options())

or set it for the whole process before jax starts, with the environment
variable ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false``.
"""

from __future__ import annotations

import functools
from typing import Any

CPU_OPTIONS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}
"""XLA debug options for the CPU backend (the faster-compiling loop emitters)."""


def compiler_options(backend: str | None = None) -> dict[str, Any]:
    """XLA options for compiling raytrax programs on ``backend`` (default: jax's
    default backend): :data:`CPU_OPTIONS` on ``"cpu"``, none elsewhere. A new dict,
    for ``jax.jit(..., compiler_options=...)``."""
    import jax

    if backend is None:
        backend = jax.default_backend()
    return dict(CPU_OPTIONS) if backend == "cpu" else {}


def _top_level() -> bool:
    """Whether no jax transformation is tracing now: jax accepts compiler options
    only on a top-level ``jax.jit``. False where jax's internals have moved (the
    options are then left out, never wrongly passed)."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:  # pragma: no cover - another jax version
        return False
    return bool(trace_state_clean())


def filter_jit(fun):
    """``eqx.filter_jit(fun)``, compiled with :func:`compiler_options` of the default
    backend when called outside any jax transformation (nested inside another
    ``jax.jit`` or ``jax.grad``, the outer compile's options apply). The wrappers are
    made on first use, so that importing raytrax does not start jax's backends."""
    import equinox as eqx

    made: dict[Any, Any] = {}

    @functools.wraps(fun)
    def call(*args, **kwargs):
        import jax

        key = jax.default_backend() if _top_level() else None
        jitted = made.get(key)
        if jitted is None:
            if key is None:
                jitted = eqx.filter_jit(fun)
            else:
                jitted = eqx.filter_jit(fun, compiler_options=compiler_options(key))  # pyright: ignore[reportCallIssue]
            made[key] = jitted
        return jitted(*args, **kwargs)

    return call
