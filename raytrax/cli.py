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
compiling (``RAYTRAX_EXECUTABLE_CACHE=0`` turns the latter off; see
:mod:`raytrax.executables`). ``raytrax --version`` prints the version;
``python -m raytrax`` is the same command.

Exit status: 0 on success, 2 on a user error (bad scene file, bad option, an
output that cannot be written), with one line on stderr and no traceback;
130 when interrupted (Ctrl-C), in any phase, with ``raytrax: interrupted; no
output written`` on stderr. A failed or interrupted run leaves no output file
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
    from . import __version__

    p = _Parser(prog=PROG, description="raytrax: a differentiable Whitted-style raytracer in JAX.")
    p.add_argument("--version", action="version", version=f"{PROG} {__version__}")
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
    sub.add_parser(
        "schema",
        help="print the JSON Schema of scene files (for TOML editors)",
        description="Print the JSON Schema of scene files, generated from the primitive kinds and light "
        "types this raytrax has, for completion and checking in TOML editors.",
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

    from . import executables
    from .imageio import save_image

    # Only once the arguments and the scene are good: a user error leaves no cache folder.
    executables.enable_compilation_cache()
    with _Phase("compiling", q) as ph_c:
        compiled, leaves, cached = executables.compiled_render(scene)
    with _Phase("rendering", q) as ph_r:
        try:
            img = np.asarray(jax.block_until_ready(compiled(leaves)))
        except jax.errors.JaxRuntimeError:
            if cached is None:
                raise
            # A cached executable that does not run (e.g. XLA lost part of it when
            # serializing): forget it and compile.
            executables.forget(cached)
            compiled, leaves, _ = executables.compiled_render(scene, use_cache=False)
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
    # Under the interrupt lock: a Ctrl-C now waits for the temporary file to be
    # complete and removed, or renamed into place (the run is then done).
    with _INT.lock:
        save_image(out, img, metadata=meta, bits=bits, before_rename=_INT.check)
        _INT.done = True
    total = time.perf_counter() - t_start
    _say(
        f"wrote {out} ({st.width} x {st.height}) in {total:.1f} s "
        f"(compile {ph_c.elapsed:.1f} s, render {ph_r.elapsed:.1f} s)",
        q,
    )
    return 0


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


def _param_text(key, v) -> str:
    import numpy as np

    a = np.asarray(v, dtype=np.float64) if not isinstance(v, str) else None
    if a is None:
        return f"{key} {v!r}"
    if a.ndim == 0:
        return f"{key} {float(a):g}"
    if a.ndim == 1:
        return f"{key} {_fmt_vec(a)}" + (" deg" if key == "rotation" else "")
    return f"{key} " + " ".join(_fmt_vec(r) for r in a)


def _object_text(o) -> str:
    """One line per object; every kind of the registry by its keys (a mesh by its size)."""
    import numpy as np

    from .shapes import BY_NAME as KIND_BY_NAME

    p = o.params
    if o.type == "mesh":
        src = f"{p['file']!r}, " if "file" in p else "inline, "
        g = src + f"{len(p['vertices'])} vertices, {len(p['faces'])} triangles"
    else:
        spec = KIND_BY_NAME[o.type]
        g = ", ".join(
            _param_text(k.name, p[k.name])
            for k in spec.keys
            if k.name in p and not (k.default is not None and np.allclose(p[k.name], k.default))
        )
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
    from .shapes import KINDS

    # Primitives the search tests: every kind's own, plus the merged triangle list.
    prims = sum(c[k.name] for k in KINDS if not k.triangle_family) + c["triangles_total"]
    return dict(
        pixels=r.width * r.height,
        camera_rays=camera,
        branches=branches,
        secondary_rays=secondary,
        shadow_rays=shadow,
        primitives=prims,
        tests=(shading_points + shadow) * prims,
    )


def _cmd_schema() -> int:
    import json

    from .scenefile.schema import json_schema

    print(json.dumps(json_schema(), indent=2))
    return 0


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
    from .lights import BY_NAME as LIGHT_BY_NAME

    units = {"intensity": " W/sr", "irradiance": " W/m^2"}
    for i, light in enumerate(d.lights):
        parts = []
        for k in LIGHT_BY_NAME[light.type].keys:
            v = light.params[k.name]
            unit = "" if d.shading == "classic" else units.get(k.name, "")
            parts.append(f"{k.name} {_fmt_rgb(v) if k.ftype == 'rgb' else _fmt_vec(v)}{unit}")
        out.append(f"  [{i}] {light.type}: " + ", ".join(parts))
    out.append(f"materials ({len(d.materials)}):")
    w = max(len(n) for n in d.materials)
    for name, m in d.materials.items():
        out.append(
            f"  {name:<{w}}  color {_fmt_rgb(m.color)}: {_material_kind(m, d.shading)}{_texture_text(m.texture)}"
        )
    out.append(f"objects ({len(d.objects)}):")
    for i, o in enumerate(d.objects):
        out.append(f"  [{i}] {_object_text(o)}")
    from .shapes import OBJECT_TYPES

    counts = d.primitive_counts()
    listed = ", ".join(
        f"{counts[k]} {k}{'es' if k == 'box' and counts[k] != 1 else ('s' if counts[k] != 1 else '')}"
        for k in OBJECT_TYPES
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


# -----------------------------------------------------------------------------
# Ctrl-C
# -----------------------------------------------------------------------------
#
# Raising KeyboardInterrupt from a signal handler while XLA compiles in its own
# threads, then tearing the interpreter down with those threads alive, crashed
# the process (SIGSEGV) most of the time. So the command does not raise: the C
# level signal handler wakes a watcher thread (``signal.set_wakeup_fd``, which
# works even while the main thread is inside XLA), and the watcher prints the
# message, flushes stdout and stderr and ends the process with ``os._exit(130)``:
# no interpreter teardown, no destructors racing XLA's threads. The one thing it
# waits for is the image file: ``_INT.lock`` is held from the creation of its
# temporary file until that is removed (interrupted: checked after the write,
# before the rename) or renamed into place (the run is then complete, and a
# Ctrl-C from then on is ignored). In-process calls (``main(argv)``) keep
# KeyboardInterrupt and return 130.


class _Interrupts:
    def __init__(self):
        self.event = threading.Event()  # a SIGINT arrived
        self.lock = threading.Lock()  # held while the output file is being written
        self.done = False  # the output is in place, or the run is over: nothing left to interrupt
        self.hard = False  # end the process (the command) rather than raise
        self._exiting = threading.Lock()

    def reset(self, hard: bool):
        self.event.clear()
        self.done = False
        self.hard = hard

    def check(self):
        """Raise KeyboardInterrupt if a Ctrl-C arrived (before the output is renamed
        into place)."""
        if self.event.is_set():
            raise KeyboardInterrupt

    def on_signal(self, signum, frame):
        """The Python-level SIGINT handler (main thread, between bytecodes)."""
        self.event.set()
        if not self.hard:
            raise KeyboardInterrupt

    def watch(self, fd):
        """Watcher thread: woken by the C-level handler through the wakeup fd."""
        import signal

        while True:
            try:
                data = os.read(fd, 64)
            except OSError:
                return
            if not data:
                return
            if signal.SIGINT in data:
                self.event.set()
                self.exit()

    def finish(self):
        """The run is over (any status): a later Ctrl-C is ignored, also while the
        interpreter shuts down (which would otherwise restore the default handler,
        and a Ctrl-C then would kill the process by SIGINT)."""
        import signal

        with self.lock:
            self.done = True
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    def exit(self):
        """Print the message and end the process with status 130, once (a second
        caller waits here for the end), unless the output is already in place."""
        self._exiting.acquire()
        with self.lock:  # not while the output file is being written
            if self.done:
                self._exiting.release()
                return
            try:
                start = "\n" if _Phase.open_line else ""
                sys.stderr.write(f"{start}{PROG}: interrupted; no output written\n")
                sys.stderr.flush()
                sys.stdout.flush()
            finally:
                os._exit(130)


_INT = _Interrupts()


def _install_interrupts(hard: bool):
    """Install the SIGINT handling (main thread only); returns a function that
    restores the previous handler (in-process use; the command keeps its own)."""
    import signal

    _INT.reset(hard)
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        return lambda: None  # (ignored: a background job, which a Ctrl-C in its terminal must not stop)
    previous = signal.signal(signal.SIGINT, _INT.on_signal)
    if hard:
        r, w = os.pipe()
        os.set_blocking(w, False)
        signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        threading.Thread(target=_INT.watch, args=(r,), name="raytrax-sigint", daemon=True).start()
    return lambda: signal.signal(signal.SIGINT, previous)


def main(argv: list | None = None) -> int:
    """Entry point of the ``raytrax`` command; returns the exit status.

    Without ``argv`` (the ``raytrax`` command, ``python -m raytrax``: arguments
    from ``sys.argv``), a Ctrl-C ends the process at once with status 130 (see
    the comment above :class:`_Interrupts`) and, once the run is over, Ctrl-C is
    ignored until the process ends. With an ``argv`` list (in-process use), a
    Ctrl-C makes it return 130 and the previous handler is restored on return.
    """
    hard = argv is None
    restore = _install_interrupts(hard)
    try:
        return _main(argv)
    finally:
        if hard:
            _INT.finish()
        else:
            restore()


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
            return _cmd_render(args)
        if args.command == "schema":
            return _cmd_schema()
        return _cmd_info(args)
    except SystemExit:  # --help, --version
        raise
    except UsageError as e:  # (before _user_errors(), which imports jax)
        return _report(e)
    except KeyboardInterrupt:
        if _INT.hard:
            _INT.exit()
        start = "\n" if _Phase.open_line else ""
        print(f"{start}{PROG}: interrupted; no output written", file=sys.stderr, flush=True)
        return 130
    except _user_errors() as e:
        return _report(e)


def _report(e) -> int:
    msg = " ".join(str(e).split("\n"))
    print(f"{PROG}: error: {msg}", file=sys.stderr, flush=True)
    return 2


if __name__ == "__main__":
    sys.exit(main())
