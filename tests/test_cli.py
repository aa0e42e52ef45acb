"""The ``raytrax`` command line: exit codes, one-line errors, no stray files.

Renders run in subprocesses (``python -m raytrax``) sharing one persistent
JAX compilation cache, so only the first render of ``tiny.toml`` compiles from
scratch. Most error paths are checked in-process through ``main(argv)``, plus a
few through a subprocess for the real exit status and stderr.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import raytrax
from raytrax import cli, executables
from raytrax.imageio import load_image, load_image_metadata

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = os.path.join(ROOT, "scenes", "tiny.toml")
SMALL = ["--width", "16", "--height", "12", "--depth", "1"]


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    e = dict(os.environ)
    e["JAX_PLATFORMS"] = "cpu"
    # As a user runs it: one host device (conftest asks for several for the sharding tests).
    flags = [f for f in e.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
    e["XLA_FLAGS"] = " ".join(flags)
    e["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path_factory.mktemp("jax-cache"))
    e["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    return e


@pytest.fixture(scope="module")
def _main_cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("jax-cache-main"))


@pytest.fixture(autouse=True)
def _main_cache_in_the_session(_main_cache, monkeypatch):
    """``cli.main(["render", ...])`` in this process turns on jax's persistent cache
    (conftest.py turns it off again after each test): in a folder of the test
    session's, not in the user's ``~/.cache``."""
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", _main_cache)


def interruptible(module, args, **kw):
    """``python -m module args`` in a subprocess, with SIGINT at its default: a test
    run started as a background job ignores SIGINT, and so would the CLI then (it
    keeps an ignored SIGINT ignored). Pipes for stdout and stderr, as text."""
    shim = (
        "import runpy, signal; signal.signal(signal.SIGINT, signal.SIG_DFL); "
        f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"
    )
    return subprocess.Popen(
        [sys.executable, "-c", shim, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw
    )


def run(args, cwd, env, **kw):
    return subprocess.run(
        [sys.executable, "-m", "raytrax", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        **kw,
    )


def one_line(stderr: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    return lines[0]


# -----------------------------------------------------------------------------
# Subprocess: real renders, exit codes and stderr
# -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, env):
    d = tmp_path_factory.mktemp("cli")
    _SOURCES["rendered"] = executables.source_digest()
    r = run(["render", TINY, "-o", "tiny.png", *SMALL], d, env)
    return d, r


_SOURCES = {}  # digest of the raytrax sources (the executable cache key depends on them)


def test_render_png(rendered):
    d, r = rendered
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    err = r.stderr
    assert "loaded" in err and "compiling ..." in err and "rendering ..." in err
    assert "wrote tiny.png (16 x 12) in" in err  # the time taken
    assert sorted(os.listdir(d)) == ["tiny.png"]
    img = load_image(d / "tiny.png")
    assert img.shape == (12, 16, 3) and img.max() > 0.2


def test_render_exr_with_metadata_and_quiet(rendered, env):
    d, _ = rendered
    r = run(["render", TINY, "-o", "tiny.exr", "-q", *SMALL], d, env)
    assert r.returncode == 0 and r.stderr == "" and r.stdout == ""
    exr = load_image(d / "tiny.exr")
    png = load_image(d / "tiny.png")
    assert exr.dtype == np.float32 and exr.shape == (12, 16, 3)
    # Same render: the PNG is the EXR clipped, sRGB-encoded and quantised.
    from raytrax.imageio import linear_to_srgb

    # (Both runs use the same compiled program: the second comes from the persistent cache.)
    assert np.abs(linear_to_srgb(np.clip(exr, 0, 1)) - linear_to_srgb(png)).max() <= 0.5 / 255 + 1e-6
    meta = load_image_metadata(d / "tiny.exr")
    assert meta["scene"] == "tiny" and meta["spp"] == 1 and meta["max_depth"] == 1
    assert meta["width"] == 16 and meta["height"] == 12 and meta["render_time_s"] >= 0
    os.remove(d / "tiny.exr")


def test_second_render_uses_the_executable_cache(rendered, env):
    # The first render compiled (its cache dir started empty) and kept the compiled
    # program; an entry that cannot be read is forgotten and the render compiles.
    d, _ = rendered
    folder = os.path.join(env["JAX_COMPILATION_CACHE_DIR"], executables.CACHE_DIR)
    entries = [f for f in os.listdir(folder) if f.startswith("render-")] if os.path.isdir(folder) else []
    if not entries:  # XLA sometimes cannot serialise a program (seen once in six runs); nothing to test
        pytest.skip("this compiled program could not be serialised; the CLI kept no executable")
    for f in entries:
        with open(os.path.join(folder, f), "wb") as fh:
            fh.write(b"not an executable")
    r = run(["render", TINY, "-o", "again.png", "-q", *SMALL], d, env)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert np.array_equal(load_image(d / "again.png"), load_image(d / "tiny.png"))
    if executables.source_digest() == _SOURCES["rendered"]:  # (else: sources edited meanwhile, another key)
        assert not any(f in os.listdir(folder) for f in entries)
    os.remove(d / "again.png")


def test_user_error_exit_2_one_line_no_files(tmp_path, env):
    r = run(["render", "missing.toml", "-o", "out.png"], tmp_path, env)
    assert r.returncode == 2
    assert one_line(r.stderr) == "raytrax: error: missing.toml: scene file not found"
    bad = tmp_path / "bad.toml"
    bad.write_text('[material.m]\n[[object]]\ntype = "sphere"\nmaterial = "m"\ncenter = [0, 0, -5]\nradius = -1\n')
    # Through the installed console script where there is one (pyproject's [project.scripts]).
    exe = shutil.which("raytrax")
    cmd = [exe] if exe else [sys.executable, "-m", "raytrax.cli"]
    r = subprocess.run(
        [*cmd, "render", "bad.toml", "-o", "out.png"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 2
    assert one_line(r.stderr) == "raytrax: error: bad.toml: object[0].radius: expected a positive number, got -1"
    assert sorted(os.listdir(tmp_path)) == ["bad.toml"]


def test_interrupt_leaves_no_output(tmp_path, env, rendered):
    p = interruptible("raytrax.cli", ["render", TINY, "-o", "int.png", *SMALL], cwd=tmp_path, env=env)
    try:
        seen = ""
        deadline = time.time() + 120
        while "compiling" not in seen and time.time() < deadline:
            ch = p.stderr.read(1)
            if not ch:
                break
            seen += ch
        assert "compiling" in seen, seen
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    err = seen + err
    assert p.returncode == 130, err
    assert err.rstrip().splitlines()[-1] == "raytrax: interrupted; no output written"
    assert "Traceback" not in err
    assert os.listdir(tmp_path) == []


def test_interrupt_during_a_cold_compile_exits_130_without_crashing(tmp_path):
    # Ctrl-C while XLA compiles (in its own threads) used to print the message and
    # then crash the interpreter on its way out (SIGSEGV, status 139 in a shell)
    # most times 2 s into compiling. Each run compiles the seed scene from scratch
    # (fresh jax cache, no executable cache) and is interrupted 0.3 to 2 s into
    # compiling (which takes longer: 5 to 10 s on two cores).
    e = dict(os.environ, JAX_PLATFORMS="cpu", RAYTRAX_EXECUTABLE_CACHE="0")
    e["XLA_FLAGS"] = " ".join(f for f in e.get("XLA_FLAGS", "").split() if "device_count" not in f)
    codes = []
    for i, delay in enumerate((0.3, 1.2, 2.0)):
        out = tmp_path / f"out{i}"
        out.mkdir()
        e["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path / f"jax{i}")
        p = interruptible("raytrax", ["render", "-o", "seed.png", "--width", "31", "--height", "30"], cwd=out, env=e)
        try:
            seen = ""
            while "compiling" not in seen:
                ch = p.stderr.read(1)
                if not ch:
                    break
                seen += ch
            assert "compiling" in seen, seen
            time.sleep(delay)
            p.send_signal(signal.SIGINT)
            stdout, err = p.communicate(timeout=60)
        finally:
            if p.poll() is None:
                p.kill()
        err = seen + err
        assert p.returncode not in (-11, 139) and "Segmentation" not in err, (delay, p.returncode, err)
        assert "Traceback" not in err and stdout == "", err
        codes.append(p.returncode)
        if p.returncode == 0:  # (a fast machine: compiled and rendered before the Ctrl-C)
            assert "wrote seed.png" in err and os.listdir(out) == ["seed.png"], err
            continue
        assert p.returncode == 130, (delay, p.returncode, err)
        assert err.rstrip().splitlines()[-1] == "raytrax: interrupted; no output written", err
        assert os.listdir(out) == []  # no image, no temporary file
    assert codes[0] == 130


def test_interrupt_before_the_rename_keeps_the_old_output(tmp_path, monkeypatch, capsys):
    # A Ctrl-C that arrives while the image is being written (here: seen during the
    # render, as when JAX swallows it) abandons the temporary file before its rename.
    target = tmp_path / "out.png"
    target.write_bytes(b"old")

    def interrupted_render(leaves):
        cli._INT.event.set()
        return np.full((12, 16, 3), 0.5, np.float32)

    monkeypatch.setattr("raytrax.executables.enable_compilation_cache", lambda *a, **k: None)
    monkeypatch.setattr(executables, "compiled_render", lambda scene, use_cache=True: (interrupted_render, [], None))
    code, out, err = main_err(capsys, ["render", TINY, "-o", str(target), *SMALL])
    assert code == 130 and out == ""
    assert err.rstrip().splitlines()[-1] == "raytrax: interrupted; no output written"
    assert os.listdir(tmp_path) == ["out.png"] and target.read_bytes() == b"old"


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"raytrax {raytrax.__version__}\n"
    r = subprocess.run([sys.executable, "-m", "raytrax", "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout == f"raytrax {raytrax.__version__}\n" and r.stderr == ""


def test_python_m_raytrax_is_the_command(tmp_path, env, capsys):
    # `python -m raytrax` runs cli.main, as the installed `raytrax` script does.
    code, out, err = main_err(capsys, ["info", TINY])
    assert code == 0 and err == ""
    r = subprocess.run([sys.executable, "-m", "raytrax", "info", TINY], env=env, capture_output=True, text=True)
    assert (r.returncode, r.stdout, r.stderr) == (0, out, "")
    exe = shutil.which("raytrax")
    results = []
    for cmd in [[sys.executable, "-m", "raytrax"]] + ([[exe]] if exe else []):
        for args in (["render", "--help"], ["paint"]):  # (no jax to import: quick)
            r = subprocess.run([*cmd, *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
            results.append((r.returncode, r.stdout, r.stderr))
    assert [c for c, _, _ in results[:2]] == [0, 2] and "--width" in results[0][1]
    assert one_line(results[1][2]).startswith("raytrax: error: argument COMMAND: invalid choice: 'paint'")
    if exe:
        assert results[2:] == results[:2]
    assert os.listdir(tmp_path) == []


def test_seed_scene_is_one_file():
    # scenes/cosc363.toml is a link to the copy shipped in the package: editing it
    # changes what `raytrax render` (no SCENE) draws.
    seed = os.path.join(ROOT, "scenes", "cosc363.toml")
    shipped = os.path.join(ROOT, "raytrax", "data", "scenes", "cosc363.toml")
    assert os.path.islink(seed) and not os.path.islink(shipped)
    assert os.path.realpath(seed) == os.path.realpath(shipped)
    if os.path.realpath(os.path.dirname(cli.__file__)) == os.path.realpath(os.path.join(ROOT, "raytrax")):
        assert os.path.samefile(cli.seed_scene_path(), seed)


# -----------------------------------------------------------------------------
# In-process: argument handling, info, error messages
# -----------------------------------------------------------------------------


def main_err(capsys, argv):
    code = cli.main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_a_user_error_turns_on_no_compilation_cache(tmp_path, monkeypatch, capsys):
    # jax's persistent cache is turned on once the arguments and the scene are good: a
    # bad option or scene leaves no cache folder and jax's options as they were.
    import jax

    cache = tmp_path / "cache"
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(cache))
    before = jax.config.values.get("jax_compilation_cache_dir")
    bad = tmp_path / "bad.toml"
    bad.write_text('[material.m]\n[[object]]\ntype = "sphere"\nmaterial = "m"\ncenter = [0, 0, -5]\nradius = -1\n')
    for argv in (["render", "--width", "0"], ["render", str(tmp_path / "missing.toml")], ["render", str(bad)]):
        code, out, err = main_err(capsys, argv)
        assert code == 2 and out == "" and err.startswith("raytrax: error: "), (argv, code, err)
        assert not cache.exists() and jax.config.values.get("jax_compilation_cache_dir") == before, argv


@pytest.mark.parametrize(
    "argv,message",
    [
        (["render", "--width", "0"], "--width: expected an integer number of pixels in [1, 65536], got 0"),
        (
            ["render", "--width", "abc"],
            "argument --width: expected an integer, got 'abc' (see 'raytrax render --help')",
        ),
        (["render", "--height", "70000"], "--height: expected an integer number of pixels in [1, 65536], got 70000"),
        (
            ["render", "--width", "20000", "--height", "20000"],
            "{seed}: render: expected at most 100,000,000 pixels, got width x height = 20000 x 20000 = 400,000,000",
        ),
        (
            ["render", "--spp", "2"],
            "--spp: expected a square number of samples per pixel (1, 4, 9, 16, ...; an n x n "
            "grid), got 2 (nearest: 1 or 4)",
        ),
        (["render", "--spp", "4096"], "--spp: expected a square number of samples per pixel in [1, 1024], got 4096"),
        (["render", "--depth", "65"], "--depth: expected an integer in [0, 64], got 65"),
        (
            ["render", "-o", "out.tif"],
            "out.tif: cannot write images of type '.tif'; expected one of .exr, .png, .jpg, .jpeg",
        ),
        (
            ["render", "-o", "noext"],
            "noext: cannot write images of type '(no extension)'; expected one of .exr, .png, .jpg, .jpeg",
        ),
        (["render", "-o", "out.jpg", "--bits", "16"], "--bits: expected one of (8,) for .jpg files, got 16"),
        (["render", "-o", "nowhere/out.png"], "nowhere/out.png: cannot write: folder {cwd}/nowhere does not exist"),
        (["render", "a.toml", "b.toml"], "unrecognized arguments: b.toml (see 'raytrax --help')"),
        (["paint"], "argument COMMAND: invalid choice: 'paint' (choose from render, info) (see 'raytrax --help')"),
        ([], "the following arguments are required: COMMAND (see 'raytrax --help')"),
        (["info", "missing.toml"], "missing.toml: scene file not found"),
    ],
)
def test_usage_errors(capsys, tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = main_err(capsys, argv)
    assert code == 2 and out == ""
    message = message.replace("{seed}", cli.seed_scene_path()).replace("{cwd}", str(tmp_path))
    line = one_line(err)
    if "invalid choice" in message:  # argparse quotes the choices differently across Python versions
        assert line.startswith("raytrax: error: argument COMMAND: invalid choice: 'paint'")
    else:
        assert line == f"raytrax: error: {message}"
    assert os.listdir(tmp_path) == []


def test_help_exits_0(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["render", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for opt in ("--width", "--height", "--spp", "--depth", "-o OUT", "SCENE"):
        assert opt in out


def test_info_seed_scene(capsys):
    code, out, err = main_err(capsys, ["info"])  # no SCENE: the seed scene shipped with the package
    assert code == 0 and err == ""
    assert "scene 'cosc363'" in out
    assert "600 x 600, spp 4, max_depth 5" in out
    assert "lights (2):" in out and "position (10, 40, -5)" in out and "position (-10, 40, -5)" in out
    assert "materials (7):" in out and "builtin image 'moon'" in out and "checker with" in out and "stripes with" in out
    assert "objects (7):" in out
    for kind in ("plane", "sphere", "box", "tetrahedron"):
        assert kind in out
    assert "estimated cost:" in out
    assert "1.44 M camera (600 x 600 x 4 spp)" in out
    assert "ray-primitive tests" in out


def test_info_counts_meshes(capsys, tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\n")
    (tmp_path / "s.toml").write_text(
        'shading = "physical"\n[render]\nwidth = 10\nheight = 10\nmax_depth = 0\n'
        "[[light]]\nposition = [0, 5, 0]\nintensity = 100\n"
        "[material.m]\ncolor = 0.5\n"
        '[[object]]\ntype = "mesh"\nmaterial = "m"\nfile = "m.obj"\n'
    )
    code, out, err = main_err(capsys, ["info", str(tmp_path / "s.toml")])
    assert code == 0, err
    assert "'m.obj', 4 vertices, 3 triangles" in out and "intensity 100 W/sr" in out
    assert "100 camera (10 x 10 x 1 spp) (no specular bounces) + up to 100 shadow (1 light)" in out
    assert "up to 600 ray-primitive tests" in out  # (100 camera + 100 shadow rays) x 3 triangles


def test_executable_key_follows_the_scene_structure():
    from raytrax.scenefile import load_description

    desc = load_description(TINY)
    key = executables.executable_key(desc.build())
    assert key is not None and key == executables.executable_key(desc.build())
    assert executables.executable_key(desc.with_render(width=17).build()) != key  # a static setting
    assert executables.executable_key(desc.with_render(spp=4).build()) != key


def test_unreadable_executable_is_ignored(tmp_path):
    bad = tmp_path / "render-x.bin"
    bad.write_bytes(b"\x80\x05garbage")
    assert executables.load_executable(str(bad), []) is None
    assert executables.load_executable(str(tmp_path / "missing.bin"), []) is None


def test_cached_executable_that_fails_to_run_is_recompiled(tmp_path, monkeypatch, capsys):
    import jax

    entry = tmp_path / "render-entry.bin"
    entry.write_bytes(b"stale")
    calls = []

    def bad(leaves):
        raise jax.errors.JaxRuntimeError("NOT_FOUND: Function broadcast_pad_fusion not found")

    def good(leaves):
        return np.full((12, 16, 3), 0.5, np.float32)

    def fake(scene, use_cache=True):
        calls.append(use_cache)
        return (bad, [], str(entry)) if use_cache else (good, [], None)

    monkeypatch.setattr("raytrax.executables.enable_compilation_cache", lambda *a, **k: None)
    monkeypatch.setattr(executables, "compiled_render", fake)
    code, out, err = main_err(capsys, ["render", TINY, "-o", str(tmp_path / "out.png"), "-q", *SMALL])
    assert code == 0 and err == "", err
    assert calls == [True, False] and not entry.exists()
    assert load_image(tmp_path / "out.png").shape == (12, 16, 3)
