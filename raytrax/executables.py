"""Compiled renders, cached across processes.

jax's persistent compilation cache is looked up by a hash of the lowered
program, so a warm run still traces and lowers the whole integrator (seconds)
before it finds the executable. This module also keeps the serialized executable
itself (``jax.experimental.serialize_executable``) under a key computed without
tracing (:func:`executable_key`), so that a hit skips tracing, lowering and
compiling (about 2 s of CPU for the seed scene, jax 0.10).

The key covers everything that decides the compiled program:

- the raytrax sources: every ``raytrax/**/*.py`` file, subpackages included
  (:func:`source_digest`), names and contents;
- jax and jaxlib versions, the backend (platform, device kind, platform version,
  device count), ``$XLA_FLAGS`` and jax's configuration (its options other than
  cache and logging ones);
- the host CPU (model and instruction-set flags; :func:`host_digest`);
- the scene's structure: its pytree definition, which holds the static fields
  (render settings, shading, counts...), and the shape, dtype and weak type of
  every array leaf. The array *values* are arguments of the executable, not part
  of the key.

Anything unexpected (no entry, an unreadable or incompatible one, a program XLA
cannot serialize, a loaded program that fails to run: see :func:`forget`) falls
back to ``jit(...).lower(...).compile()``, which still uses jax's own cache.
Entries live in ``<jax_compilation_cache_dir>/raytrax-executables/`` (the
newest 32 are kept); ``RAYTRAX_EXECUTABLE_CACHE=0`` turns the cache off.
"""

from __future__ import annotations

import contextlib
import os
import time

from ._atomic import atomic_path

__all__ = [
    "CACHE_DIR",
    "compiled_render",
    "executable_key",
    "executable_path",
    "forget",
    "load_executable",
    "source_digest",
    "store_executable",
]

#: folder of the entries, inside jax's compilation cache folder
CACHE_DIR = "raytrax-executables"
_KEEP = 32  # newest entries kept
_FORMAT = 2  # version of the entry layout (2: with the ids of the devices it runs on)
_STALE_TMP_S = 3600.0  # temporary files older than this are leftovers of a killed process


def source_digest() -> bytes:
    """SHA-256 over the relative paths and contents of every ``.py`` file under
    the ``raytrax`` package folder, subpackages included, in a fixed order."""
    import hashlib

    h = hashlib.sha256()
    root = os.path.dirname(os.path.abspath(__file__))
    for dirpath, dirnames, filenames in os.walk(root):  # subpackages too
        dirnames.sort()
        for name in sorted(filenames):
            if name.endswith(".py"):
                path = os.path.join(dirpath, name)
                h.update(os.path.relpath(path, root).encode())
                with open(path, "rb") as f:
                    h.update(f.read())
    return h.digest()


def host_digest() -> str:
    """Machine type, CPU model and instruction-set flags (an executable is compiled
    for them), as text."""
    import platform

    from .compile_options import first_cpu_lines

    keep = ("flags", "model name", "Features", "CPU part")
    return platform.machine() + platform.processor() + "".join(ln for ln in first_cpu_lines() if ln.startswith(keep))


def executable_key(scene) -> str | None:
    """Key of the compiled render of ``scene`` (40 hex digits; see the module
    docstring for what it covers), or None when the scene has a static part
    without a stable text form (an object address, a summarised array)."""
    import hashlib

    import jax
    import numpy as np
    from jaxlib import version as jaxlib_version

    leaves, treedef = jax.tree_util.tree_flatten(scene)
    parts = [str(treedef)]
    for x in leaves:
        if isinstance(x, (jax.Array, np.ndarray)):
            parts.append(f"{x.shape}{x.dtype}{getattr(x, 'weak_type', False)}")
        else:
            parts.append(repr(x))
    if any(" at 0x" in p or "..." in p for p in parts):  # an address, or a summarised (large) array
        return None
    dev = jax.devices()[0]
    cfg = sorted((k, repr(v)) for k, v in jax.config.values.items() if "cache" not in k and "log" not in k)
    parts += [
        jax.__version__,
        jaxlib_version.__version__,
        dev.platform,
        dev.device_kind,
        dev.client.platform_version,
        str(jax.device_count()),
        os.environ.get("XLA_FLAGS", ""),
        repr(cfg),
        host_digest(),
    ]
    h = hashlib.sha256(source_digest())
    h.update("\0".join(parts).encode())
    return h.hexdigest()[:40]


def executable_path(key: str | None) -> str | None:
    """Path of the cache entry for ``key``, or None when there is none to use: no
    key, ``RAYTRAX_EXECUTABLE_CACHE=0``, or no jax compilation cache folder."""
    import jax

    if os.environ.get("RAYTRAX_EXECUTABLE_CACHE", "1") == "0" or key is None:
        return None
    root = jax.config.values.get("jax_compilation_cache_dir")
    return os.path.join(root, CACHE_DIR, f"render-{key}.bin") if root else None


def load_executable(path, leaves):
    """The compiled render stored at ``path``, or None when it is missing, cannot
    be read or loaded, or takes other arguments than ``leaves`` (shapes and dtypes).
    A hit marks the entry recently used."""
    import pickle

    import jax
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        with open(path, "rb") as f:
            fmt, payload, in_tree, out_tree, device_ids = pickle.load(f)
        if fmt != _FORMAT:
            return None
        # The devices it was compiled for (by default jax would load it onto all of them).
        by_id = {d.id: d for d in jax.devices()}
        compiled = deserialize_and_load(payload, in_tree, out_tree, execution_devices=[by_id[i] for i in device_ids])
        expected = [(a.shape, a.dtype) for a in jax.tree_util.tree_leaves(compiled.args_info)]
        if expected != [(x.shape, x.dtype) for x in leaves]:
            return None
    except Exception:  # noqa: BLE001 - missing, truncated or incompatible: compile instead
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used
    return compiled


def forget(path) -> None:
    """Remove the cache entry at ``path`` (e.g. one whose program failed to run)."""
    with contextlib.suppress(OSError):
        os.unlink(path)


def store_executable(path, compiled) -> bool:
    """Serialize ``compiled`` to ``path`` atomically and keep only the newest
    entries of its folder; returns whether it was stored (XLA cannot serialize
    every program; nothing is cached then)."""
    import pickle

    from jax.experimental.serialize_executable import serialize

    try:
        payload, in_tree, out_tree = serialize(compiled)
        device_ids = [d.id for d in compiled.runtime_executable().local_devices()]
        folder = os.path.dirname(path)
        os.makedirs(folder, exist_ok=True)
        with atomic_path(path, suffix=".bin") as tmp, open(tmp, "wb") as f:
            pickle.dump((_FORMAT, payload, in_tree, out_tree, device_ids), f, protocol=pickle.HIGHEST_PROTOCOL)
        _prune(folder)
    except Exception:  # noqa: BLE001 - e.g. XLA cannot serialize this program; nothing is cached
        return False
    return True


def _prune(folder) -> None:
    """Keep the newest ``_KEEP`` entries; remove temporary files left by killed
    processes (``atomic_path`` names them ``.render-*.tmp.bin``)."""
    now = time.time()
    entries = []
    for name in os.listdir(folder):
        p = os.path.join(folder, name)
        with contextlib.suppress(OSError):
            if name.startswith("render-"):
                entries.append((os.path.getmtime(p), p))
            elif name.startswith(".render-") and name.endswith(".tmp.bin"):
                if now - os.path.getmtime(p) > _STALE_TMP_S:
                    os.unlink(p)
    for _, p in sorted(entries)[:-_KEEP]:
        forget(p)


def compiled_render(scene, use_cache: bool = True):
    """Compile the render of ``scene``, or load it from the cache.

    Returns ``(compiled, leaves, entry)``: ``compiled(leaves)`` renders ``scene``
    (``leaves`` are its array leaves); ``entry`` is the cache entry the program was
    loaded from, or None when it was compiled here (pass it to :func:`forget` if
    the program then fails to run, and call again with ``use_cache=False``).
    With ``use_cache=False`` the cache is neither read nor written.
    """
    import equinox as eqx
    import jax

    dynamic, static = eqx.partition(scene, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(dynamic)
    path = executable_path(executable_key(scene)) if use_cache else None
    if path is not None and os.path.exists(path):
        compiled = load_executable(path, leaves)
        if compiled is not None:
            return compiled, leaves, path
        forget(path)  # unreadable or for other arguments

    from .compile_options import compiler_options
    from .renderer import render

    def fn(leaves):
        return render(eqx.combine(jax.tree_util.tree_unflatten(treedef, leaves), static))

    from jax import monitoring

    hits = []

    def on_event(event, **kw):
        if event == "/jax/compilation_cache/cache_hits":
            hits.append(event)

    monitoring.register_event_listener(on_event)
    try:
        compiled = jax.jit(fn, compiler_options=compiler_options()).lower(leaves).compile()
    finally:
        monitoring.unregister_event_listener(on_event)
    # Only a program compiled here is stored: one that jax's cache deserialized
    # was seen to serialize again without all its functions (XLA:CPU, jax 0.10).
    if path is not None and not hits:
        store_executable(path, compiled)
    return compiled, leaves, None


def enable_compilation_cache(directory: str | os.PathLike | None = None, *, min_compile_time: float = 1.0) -> str:
    """Turn on jax's persistent compilation cache for this process, so that a later
    process (a notebook kernel restarted, a script run again) loads compiled renders and
    gradients from disk instead of compiling them again (seconds to minutes each).

    ``directory``: where compiled programs are kept; default
    ``$JAX_COMPILATION_CACHE_DIR`` if set, else ``~/.cache/raytrax/jax`` (the CLI's
    cache). ``min_compile_time``: programs that compiled faster than this many seconds
    are not stored. Returns the directory in use. Call it before the first render::

        import raytrax as rt
        rt.enable_compilation_cache()
    """
    import jax

    if directory is None:
        directory = jax.config.values.get("jax_compilation_cache_dir") or os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if not directory:
        directory = os.path.join(os.path.expanduser("~"), ".cache", "raytrax", "jax")
    directory = os.fspath(directory)
    os.makedirs(directory, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", directory)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time))
    return directory
