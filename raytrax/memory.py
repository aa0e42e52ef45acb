"""Handing the memory of a large XLA compilation back to the operating system.

Compiling a large program (an edge-mode gradient: about 1.5 GiB of compiler memory on
CPU, whatever the image size) leaves most of that memory freed but still held by the C
allocator (glibc's ``malloc`` keeps freed heap pages). The program's own buffers are
then allocated on top of it, so the process's peak memory is the compiler's plus the
program's. Calling glibc's ``malloc_trim(0)`` after each large compilation returns
the freed pages: an edge-mode ``value_and_grad`` at 320 x 240, spp 64 peaks at 1.96
GiB instead of 2.99 GiB (``benchmarks/bench_edges.py --one``), at no measurable cost
in time.

:func:`release_memory_after_compile` turns this on or off for the process (it is on
once :mod:`raytrax.renderer` is imported). It acts on every jax compilation of the
process that takes at least ``min_seconds`` (raytrax's or not), through
``jax.monitoring``; elsewhere than Linux with glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import sys

COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"

_state: dict = {"listener": None, "trims": 0, "chosen": False}


def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        return None


def release_memory_after_compile(enable: bool = True, *, min_seconds: float = 1.0) -> bool:
    """After every jax compilation of at least ``min_seconds`` in this process, return
    the compiler's freed memory to the operating system (glibc ``malloc_trim``), so
    that the peak memory of a first call is the larger of the compiler's and the
    program's, not their sum. ``enable=False`` turns it off. Returns whether it is
    on (always ``False`` where the C library has no ``malloc_trim``).

    On by default once a render is imported; a process that compiles many small
    programs quickly is unaffected (each trim takes milliseconds)."""
    import jax

    _state["chosen"] = True
    old = _state["listener"]
    if old is not None:
        jax.monitoring.unregister_event_duration_listener(old)
        _state["listener"] = None
    trim = _malloc_trim() if enable else None
    if trim is None:
        return False

    def listener(event: str, duration_secs: float, **kwargs: str | int) -> None:
        if event == COMPILE_EVENT and duration_secs >= min_seconds:
            trim(0)
            _state["trims"] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    _state["listener"] = listener
    return True


def release_by_default() -> None:
    """Turn :func:`release_memory_after_compile` on unless the process chose already."""
    if not _state["chosen"]:
        release_memory_after_compile()
