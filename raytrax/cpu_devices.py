"""One jax CPU device per core, so that renders use every core.

XLA:CPU runs one program on one CPU device by splitting each of its loops over
the cores; for the many small kernels of a render (a few thousand rays each)
that costs more in hand-overs between threads than it gains. Rendering the image
tiles on one device per core instead runs each core's share as a program of its
own: 1.4-1.7x faster on a 2-core machine (``benchmarks/bench_speed.py``
measures it). :func:`raytrax.render` shards its tiles over the CPU devices by
default (its ``devices`` argument).

jax fixes the number of CPU devices when its backends start, so ``import
raytrax`` asks for one per core (:func:`request`) if jax has not started them
yet and nothing else chose a number: the environment variable
``JAX_NUM_CPU_DEVICES``, jax's option ``jax_num_cpu_devices`` or
``--xla_force_host_platform_device_count`` in ``XLA_FLAGS``. To choose the
number yourself, set ``RAYTRAX_CPU_DEVICES`` (``1``: leave jax's single CPU device
as it is) or one of those before importing raytrax. Importing raytrax after
jax has created an array leaves jax as it is.
"""

from __future__ import annotations

import os
import sys

ENV = "RAYTRAX_CPU_DEVICES"
MAX_DEVICES = 8  # more devices means more padding of small images and more tiles in memory at once


def cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def wanted() -> int:
    """CPU devices raytrax asks for: ``$RAYTRAX_CPU_DEVICES`` if set (a positive
    integer), else one per core up to :data:`MAX_DEVICES`."""
    raw = os.environ.get(ENV)
    if raw is None:
        return max(1, min(cores(), MAX_DEVICES))
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"${ENV}: expected a positive integer (CPU devices for jax), got {raw!r}")
    return n


def request() -> int | None:
    """Ask jax for :func:`wanted` CPU devices if it is still free to choose (see the
    module docstring). Returns the number asked for, or None where it left jax as it
    was (also when ``$RAYTRAX_CPU_DEVICES`` is not a positive integer: a warning).
    Does not import jax."""
    try:
        n = wanted()
    except ValueError as e:  # at import: a warning, not a traceback; jax keeps its default
        import warnings

        warnings.warn(f"{e}; using jax's default", stacklevel=3)
        return None
    if n <= 1 or "JAX_NUM_CPU_DEVICES" in os.environ:
        return None
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return None
    if "jax" not in sys.modules:
        os.environ["JAX_NUM_CPU_DEVICES"] = str(n)  # read by jax's configuration when it is imported
        return n
    try:  # jax is imported: only before its backends start, and only if its option is at the default
        import jax
        from jax._src import xla_bridge

        if xla_bridge.backends_are_initialized() or jax.config.values.get("jax_num_cpu_devices", -1) != -1:
            return None
        jax.config.update("jax_num_cpu_devices", n)
    except Exception:  # pragma: no cover - another jax version: leave it alone
        return None
    return n
