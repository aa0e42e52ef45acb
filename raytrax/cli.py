"""The ``raytrax`` command line.

``raytrax render [SCENE] [-o OUT] [--width W] [--height H] [--spp N] [--depth D]``
    renders a scene file (without SCENE: the seed scene, ``cosc363.toml``, shipped
    with the package) to an image (``.png``, ``.jpg`` or ``.exr``, by extension).
``raytrax info SCENE``
    summarises a scene: render settings, camera, lights, materials, objects, and
    an estimate of the work a render does.

Renders use jax's persistent compilation cache (``$JAX_COMPILATION_CACHE_DIR``,
default ``~/.cache/raytrax/jax``) and keep the compiled render itself there too,
so a second run of the same scene at the same settings skips tracing and
compiling (``RAYTRAX_EXECUTABLE_CACHE=0`` turns the latter off).

Exit status: 0 on success, 2 on a user error (bad scene file, bad option, an
output that cannot be written), with one line on stderr and no traceback;
130 when interrupted (Ctrl-C). A failed or interrupted run leaves no output file
behind: images are written to a temporary file in the output folder and renamed
into place when complete.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from importlib import resources

PROG = "raytrax"
SEED_SCENE = "cosc363.toml"


class UsageError(Exception):
    """A user error reported in one line with exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage block
        raise UsageError(f"{message} (see '{self.prog} --help')")


def seed_scene_path() -> str:
    """Path of the seed scene shipped inside the package."""
    return str(resources.files("raytrax").joinpath("data", "scenes", SEED_SCENE))


def _integer(name):
    def conv(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {s!r}") from None
        return v

    conv.__name__ = name
    return conv


def _build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="raytrax: a differentiable Whitted-style raytracer in JAX.")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    r = sub.add_parser(
        "render",
        help="render a scene file to an image",
        description="Render a scene file (default: the seed scene cosc363.toml) to an image. "
        "The output format follows the extension: .png/.jpg (sRGB) or .exr (linear float).",
    )
    r.add_argument(
        "scene",
        nargs="?",
        default=None,
        metavar="SCENE",
        help="a TOML scene file (default: the seed scene cosc363.toml)",
    )
    r.add_argument(
        "-o",
        "--output",
        default=None,
        metavar="OUT",
        help="output image, .png, .jpg or .exr (default: <scene name>.png in the current folder)",
    )
    r.add_argument("--width", type=_integer("width"), help="image width in pixels")
    r.add_argument("--height", type=_integer("height"), help="image height in pixels")
    r.add_argument("--spp", type=_integer("spp"), help="samples per pixel, a square number")
    r.add_argument("--depth", type=_integer("depth"), help="maximum number of specular bounces (max_depth)")
    r.add_argument(
        "--bits",
        type=int,
        choices=(8, 16),
        default=None,
        help="PNG bit depth (default 8); EXR: 16 for half floats (default 32-bit float)",
    )
    r.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    i = sub.add_parser(
        "info",
        help="summarise a scene file",
        description="Summarise a scene: settings, camera, lights, materials, objects, cost.",
    )
    i.add_argument(
        "scene",
        nargs="?",
        default=None,
        metavar="SCENE",
        help="a TOML scene file (default: the seed scene cosc363.toml)",
    )
    return p


# -----------------------------------------------------------------------------
# Progress
# -----------------------------------------------------------------------------


class _Phase:
    """Prints ``raytrax: <what> ...`` and, when stderr is a terminal, a ticking
    elapsed time; then the time taken."""

    open_line = False  # a progress line without its newline is on stderr

    def __init__(self, what: str, quiet: bool):
        self.what = what
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self._stop = threading.Event()
        self._thread = None

    def __enter__(self):
        self.t0 = time.perf_counter()
        if not self.quiet:
            _Phase.open_line = True
            sys.stderr.write(f"{PROG}: {self.what} ...")
            sys.stderr.flush()
            if self.tty:
                self._thread = threading.Thread(target=self._tick, daemon=True)
                self._thread.start()
        return self

    def _tick(self):
        while not self._stop.wait(1.0):
            dt = time.perf_counter() - self.t0
            sys.stderr.write(f"\r{PROG}: {self.what} ... {dt:.0f} s")
            sys.stderr.flush()

    def __exit__(self, exc_type, exc, tb):
        self.elapsed = time.perf_counter() - self.t0
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if not self.quiet:
            end = f"{self.elapsed:.1f} s" if exc_type is None else "failed"
            sys.stderr.write(f"\r{PROG}: {self.what} ... {end}\n" if self.tty else f" {end}\n")
            sys.stderr.flush()
            _Phase.open_line = False
        return False


def _say(msg: str, quiet: bool):
    if not quiet:
        print(f"{PROG}: {msg}", file=sys.stderr, flush=True)


# -----------------------------------------------------------------------------
# Commands
# -----------------------------------------------------------------------------


def _load(scene_arg):
    from .scenefile import load_description

    path = scene_arg if scene_arg is not None else seed_scene_path()
    return path, load_description(path)


def _cmd_render(args) -> int:
    from .imageio import WRITE_FORMATS
    from .scenefile import check_render_value

    q = args.quiet
    # Check the cheap things before the expensive ones.
    overrides = {}
    for opt, key in (("width", "width"), ("height", "height"), ("spp", "spp"), ("depth", "max_depth")):
        v = getattr(args, opt)
        if v is not None:
            msg = check_render_value(key, v)
            if msg:
                raise UsageError(f"--{opt}: {msg}")
            overrides[key] = v
    out = args.output
    if out is not None:
        ext = os.path.splitext(out)[1].lower()
        if ext not in WRITE_FORMATS:
            raise UsageError(
                f"{out}: cannot write images of type {ext or '(no extension)'!r}; expected one of "
                f"{', '.join(WRITE_FORMATS)}"
            )
        allowed = WRITE_FORMATS[ext][0]
        if args.bits is not None and args.bits not in allowed:
            raise UsageError(f"--bits: expected one of {allowed} for {ext} files, got {args.bits}")
        folder = os.path.dirname(os.path.abspath(out))
        if not os.path.isdir(folder):
            raise UsageError(f"{out}: cannot write: folder {folder} does not exist")
    t_start = time.perf_counter()
    path, desc = _load(args.scene)  # silent until it succeeds: a user error stays one line
    if overrides:
        desc = desc.with_render(**overrides)
    scene = desc.build()
    if out is None:
        out = f"{desc.name or 'render'}.png"
    st = scene.settings
    _say(
        f"loaded {desc.source} in {time.perf_counter() - t_start:.1f} s: {st.width} x {st.height}, "
        f"spp {st.spp}, depth {st.max_depth}, {st.shading} shading",
        q,
    )

    import jax
    import numpy as np

    from .imageio import save_image

    with _Phase("compiling", q) as ph_c:
        compiled, leaves, cached = _compiled_render(scene)
    with _Phase("rendering", q) as ph_r:
        try:
            img = np.asarray(jax.block_until_ready(compiled(leaves)))
        except jax.errors.JaxRuntimeError:
            if cached is None:
                raise
            # A cached executable that does not run (e.g. XLA lost part of it when
            # serializing): forget it and compile.
            _forget(cached)
            compiled, leaves, _ = _compiled_render(scene, use_cache=False)
            img = np.asarray(jax.block_until_ready(compiled(leaves)))
    bits = args.bits
    meta = dict(
        scene=desc.name,
        source=os.path.abspath(path),
        width=st.width,
        height=st.height,
        spp=st.spp,
        max_depth=st.max_depth,
        shading=st.shading,
        render_time_s=round(ph_r.elapsed, 4),
        compile_time_s=round(ph_c.elapsed, 4),
    )
    if _INTERRUPTED.is_set():  # a Ctrl-C that JAX swallowed mid-compile still means: no output
        raise KeyboardInterrupt
    save_image(out, img, metadata=meta, bits=bits)
    total = time.perf_counter() - t_start
    _say(
        f"wrote {out} ({st.width} x {st.height}) in {total:.1f} s "
        f"(compile {ph_c.elapsed:.1f} s, render {ph_r.elapsed:.1f} s)",
        q,
    )
    return 0


# -----------------------------------------------------------------------------
# Compiled renders, cached across processes
# -----------------------------------------------------------------------------
#
# jax's persistent compilation cache is looked up by a hash of the lowered
# program, so a warm run still traces and lowers the whole integrator (seconds)
# before it finds the executable. The CLI also keeps the serialized executable
# itself (``jax.experimental.serialize_executable``) under a key computed without
# tracing: the raytrax sources, the jax version, backend, CPU and configuration,
# and the scene's structure (tree, static fields, leaf shapes and dtypes). A hit
# skips tracing, lowering and compiling (about 2 s of CPU for the seed scene,
# jax 0.10). Anything unexpected (no entry, an unreadable or incompatible one, a
# program XLA cannot serialize, a loaded program that fails to run) falls back to
# ``jit(...).lower(...).compile()``, which still uses jax's own cache. Entries
# live in ``<jax_compilation_cache_dir>/raytrax-executables/`` (the newest 32);
# ``RAYTRAX_EXECUTABLE_CACHE=0`` turns this off.

_EXEC_DIR = "raytrax-executables"
_EXEC_KEEP = 32  # newest entries kept
_EXEC_FORMAT = 1


def _source_digest() -> bytes:
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


def _host_digest() -> str:
    """CPU model and instruction-set flags (an executable is compiled for them)."""
    import platform

    text = platform.machine() + platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "model name", "Features", "CPU part")):
                    text += line
                elif not line.strip():
                    break  # the first processor is enough
    except OSError:
        pass
    return text


def _executable_key(scene) -> str | None:
    """Key of the compiled render of ``scene``, or None when the scene has a static
    part without a stable text form."""
    import hashlib

    import jax
    import jaxlib
    import numpy as np

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
        jaxlib.__version__,
        dev.platform,
        dev.device_kind,
        dev.client.platform_version,
        str(jax.device_count()),
        os.environ.get("XLA_FLAGS", ""),
        repr(cfg),
        _host_digest(),
    ]
    h = hashlib.sha256(_source_digest())
    h.update("\0".join(parts).encode())
    return h.hexdigest()[:40]


def _executable_path(key) -> str | None:
    import jax

    if os.environ.get("RAYTRAX_EXECUTABLE_CACHE", "1") == "0" or key is None:
        return None
    root = jax.config.jax_compilation_cache_dir
    return os.path.join(root, _EXEC_DIR, f"render-{key}.bin") if root else None


def _load_executable(path, leaves):
    """The compiled render stored at ``path``, or None."""
    import pickle

    import jax
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        with open(path, "rb") as f:
            fmt, payload, in_tree, out_tree = pickle.load(f)
        if fmt != _EXEC_FORMAT:
            return None
        compiled = deserialize_and_load(payload, in_tree, out_tree)
        expected = [(a.shape, a.dtype) for a in jax.tree_util.tree_leaves(compiled.args_info)]
        if expected != [(x.shape, x.dtype) for x in leaves]:
            return None
    except Exception:  # noqa: BLE001 - missing, truncated or incompatible: compile instead
        return None
    try:
        os.utime(path)  # recently used
    except OSError:
        pass
    return compiled


def _forget(path):
    try:
        os.unlink(path)
    except OSError:
        pass


def _store_executable(path, compiled):
    import pickle
    import tempfile

    from jax.experimental.serialize_executable import serialize

    try:
        payload, in_tree, out_tree = serialize(compiled)
        folder = os.path.dirname(path)
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".bin")
        try:
            with os.fdopen(fd, "wb") as f:
                pickle.dump((_EXEC_FORMAT, payload, in_tree, out_tree), f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
        entries = sorted(
            (os.path.getmtime(p), p)
            for p in (os.path.join(folder, n) for n in os.listdir(folder) if n.startswith("render-"))
        )
        for _, p in entries[:-_EXEC_KEEP]:
            os.unlink(p)
    except Exception:  # noqa: BLE001 - e.g. XLA cannot serialize this program; nothing is cached
        pass


def _compiled_render(scene, use_cache=True):
    """``(compiled, leaves, path)``: ``compiled(leaves)`` renders ``scene`` (its
    array leaves ``leaves``); ``path`` is the executable cache entry it was loaded
    from, or None when it was compiled here."""
    import equinox as eqx
    import jax

    dynamic, static = eqx.partition(scene, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(dynamic)
    path = _executable_path(_executable_key(scene)) if use_cache else None
    if path is not None and os.path.exists(path):
        compiled = _load_executable(path, leaves)
        if compiled is not None:
            return compiled, leaves, path
        _forget(path)  # unreadable or for other arguments

    from .integrator import render

    def fn(leaves):
        return render(eqx.combine(jax.tree_util.tree_unflatten(treedef, leaves), static))

    from jax import monitoring

    hits = []

    def on_event(event, **kw):
        if event == "/jax/compilation_cache/cache_hits":
            hits.append(event)

    monitoring.register_event_listener(on_event)
    try:
        compiled = jax.jit(fn).lower(leaves).compile()
    finally:
        monitoring.unregister_event_listener(on_event)
    # Only a program compiled here is stored: one that jax's cache deserialized
    # was seen to serialize again without all its functions (XLA:CPU, jax 0.10).
    if path is not None and not hits:
        _store_executable(path, compiled)
    return compiled, leaves, None


def _fmt_vec(v):
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


def _fmt_rgb(v):
    v = tuple(v)
    return f"{v[0]:g}" if v[0] == v[1] == v[2] else _fmt_vec(v)


def _si(n: float) -> str:
    for unit, f in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n:.0f}"


def _material_kind(m, shading) -> str:
    T, R = m.transparency, max(m.reflectivity)
    dark = max(m.color) == 0.0
    if T == 1.0 and dark and R == 0.0:
        kind = f"glass (ior {m.ior:g})"
    elif T == 0.0 and R > 0.0 and dark:
        kind = "mirror"
    elif T == 0.0 and R == 0.0:
        kind = "diffuse"
    else:
        parts = []
        if max(m.color) > 0 and T < 1:
            parts.append("diffuse")
        if R > 0:
            parts.append(f"reflective {_fmt_rgb(m.reflectivity)}")
        if T > 0:
            parts.append(f"transparent {T:g} (ior {m.ior:g})")
        kind = " + ".join(parts) or "black"
    if shading == "classic" and m.specular > 0:
        kind += f", Phong specular {m.specular:g}^{m.shininess:g}"
    return kind


def _texture_text(t) -> str:
    if t is None:
        return ""
    if t.kind == "checker":
        return f", checker with color2 {_fmt_rgb(t.color2)}, scale {t.scale:g}"
    if t.kind == "stripes":
        return f", stripes with color2 {_fmt_rgb(t.color2)}, scale {t.scale:g}, direction {_fmt_vec(t.direction)}"
    if t.kind == "builtin":
        return f", builtin image {t.name!r} {t.image.shape[1]} x {t.image.shape[0]}"
    return f", image {t.file!r} {t.image.shape[1]} x {t.image.shape[0]}"


def _object_text(o) -> str:
    p = o.params
    if o.type == "sphere":
        g = f"center {_fmt_vec(p['center'])}, radius {p['radius']:g}"
    elif o.type == "plane":
        g = f"point {_fmt_vec(p['point'])}, normal {_fmt_vec(p['normal'])}"
    elif o.type == "quad":
        g = "corners " + " ".join(_fmt_vec(c) for c in p["corners"])
    elif o.type == "triangle":
        g = "vertices " + " ".join(_fmt_vec(c) for c in p["vertices"])
    elif o.type == "box":
        g = f"min {_fmt_vec(p['min'])}, max {_fmt_vec(p['max'])}"
        if any(p.get("rotation", (0, 0, 0))):
            g += f", rotation {_fmt_vec(p['rotation'])} deg"
    elif o.type == "tetrahedron":
        g = f"center {_fmt_vec(p['center'])}, size {p['size']:g}"
    else:
        src = f"{p['file']!r}, " if "file" in p else "inline, "
        g = src + f"{len(p['vertices'])} vertices, {len(p['faces'])} triangles"
    return f"{o.type:<11} {o.material:<14} {g}"


def cost_estimate(desc) -> dict:
    """Upper bounds on the work of one render of ``desc`` (a SceneDescription)."""
    r = desc.render
    branches = 2 if any(m.transparency > 0 for m in desc.materials.values()) else 1
    specular = any(m.transparency > 0 or max(m.reflectivity) > 0 for m in desc.materials.values())
    camera = r.width * r.height * r.spp
    secondary = camera * branches * r.max_depth if specular else 0
    shading_points = camera + secondary
    shadow = shading_points * len(desc.lights)
    c = desc.primitive_counts()
    prims = c["sphere"] + c["plane"] + c["quad"] + c["box"] + c["triangles_total"]
    return dict(
        pixels=r.width * r.height,
        camera_rays=camera,
        branches=branches,
        secondary_rays=secondary,
        shadow_rays=shadow,
        primitives=prims,
        tests=(shading_points + shadow) * prims,
    )


def _cmd_info(args) -> int:
    path, d = _load(args.scene)
    r, c = d.render, d.camera
    out = [
        f"scene {d.name!r} ({d.source})",
        f"  shading     {d.shading}",
        f"  image       {r.width} x {r.height}, spp {r.spp}, max_depth {r.max_depth}, "
        f"textures {'filtered' if r.filter_textures else 'point-sampled'}",
        f"  background  {_fmt_rgb(r.background)}"
        + (f", ambient {_fmt_rgb(r.ambient)}" if d.shading == "classic" else ""),
        f"  camera      position {_fmt_vec(c.position)}, look_at {_fmt_vec(c.look_at)}, up {_fmt_vec(c.up)}, "
        f"fov {c.fov:g} deg",
        f"lights ({len(d.lights)}):",
    ]
    unit = "" if d.shading == "classic" else " W/sr"
    for i, light in enumerate(d.lights):
        out.append(f"  [{i}] position {_fmt_vec(light.position)}, intensity {_fmt_rgb(light.intensity)}{unit}")
    out.append(f"materials ({len(d.materials)}):")
    w = max(len(n) for n in d.materials)
    for name, m in d.materials.items():
        out.append(
            f"  {name:<{w}}  color {_fmt_rgb(m.color)}: {_material_kind(m, d.shading)}{_texture_text(m.texture)}"
        )
    out.append(f"objects ({len(d.objects)}):")
    for i, o in enumerate(d.objects):
        out.append(f"  [{i}] {_object_text(o)}")
    counts = d.primitive_counts()
    listed = ", ".join(
        f"{counts[k]} {k}{'es' if k == 'box' and counts[k] != 1 else ('s' if counts[k] != 1 else '')}"
        for k in ("sphere", "plane", "quad", "triangle", "box", "tetrahedron", "mesh")
        if counts[k]
    )
    e = cost_estimate(d)
    out += [
        "estimated cost:",
        f"  primitives  {listed or 'none'}; {e['primitives']} tested per ray ({counts['triangles_total']} triangles)",
        f"  rays        {_si(e['camera_rays'])} camera ({r.width} x {r.height} x {r.spp} spp)"
        + (
            f" + up to {_si(e['secondary_rays'])} specular ({e['branches']} per sample and depth, depth {r.max_depth})"
            if e["secondary_rays"]
            else " (no specular bounces)"
        )
        + f" + up to {_si(e['shadow_rays'])} shadow ({len(d.lights)} light{'s' if len(d.lights) != 1 else ''})",
        f"  work        up to {_si(e['tests'])} ray-primitive tests",
    ]
    print("\n".join(out))
    return 0


_INTERRUPTED = threading.Event()


def _on_sigint(signum, frame):
    _INTERRUPTED.set()
    raise KeyboardInterrupt


def _enable_compilation_cache():
    """Use jax's persistent compilation cache (``$JAX_COMPILATION_CACHE_DIR`` or
    ``~/.cache/raytrax/jax``) so a second run of the same scene skips compiling."""
    import jax

    if not jax.config.jax_compilation_cache_dir:
        jax.config.update(
            "jax_compilation_cache_dir", os.path.join(os.path.expanduser("~"), ".cache", "raytrax", "jax")
        )
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def main(argv: list | None = None) -> int:
    """Entry point of the ``raytrax`` command; returns the exit status."""
    import signal

    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, _on_sigint)
    _INTERRUPTED.clear()
    try:
        return _main(argv)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _user_errors():
    """Exceptions reported in one line (imported when one is raised: ``--help`` and
    argument errors need no jax)."""
    from .imageio import ImageError
    from .scenefile import SceneError

    return (UsageError, SceneError, ImageError, OSError)


def _main(argv):
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command == "render":
            _enable_compilation_cache()
            return _cmd_render(args)
        return _cmd_info(args)
    except SystemExit:  # --help
        raise
    except KeyboardInterrupt:
        start = "\n" if _Phase.open_line else ""
        print(f"{start}{PROG}: interrupted; no output written", file=sys.stderr, flush=True)
        return 130
    except _user_errors() as e:
        msg = " ".join(str(e).split("\n"))
        print(f"{PROG}: error: {msg}", file=sys.stderr, flush=True)
        return 2


if __name__ == "__main__":
    sys.exit(main())
