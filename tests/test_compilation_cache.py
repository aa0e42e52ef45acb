"""``rt.enable_compilation_cache``: jax's persistent compilation cache in one call; a
second process loads the compiled render from it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import sys
    import raytrax as rt
    d = rt.enable_compilation_cache(sys.argv[1], min_compile_time=0.0)
    assert d == sys.argv[1], d
    b = rt.SceneBuilder("classic", width=8, height=6)
    b.camera(position=(0, 0, 5), look_at=(0, 0, 0), fov=40)
    b.light((0, 5, 5))
    b.material("m", color=(0.5, 0.5, 0.5))
    b.sphere((0, 0, 0), 1.0, "m")
    print(float(rt.render(b.build()).sum()))
    """
)


def test_second_process_uses_the_cache(tmp_path):
    cache = str(tmp_path / "cache")
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="")
    runs = [subprocess.run([sys.executable, "-c", SCRIPT, cache], capture_output=True, text=True, env=env, timeout=300)]
    assert runs[0].returncode == 0, runs[0].stderr
    files = sorted(os.listdir(cache))
    assert files, "nothing was written to the compilation cache"
    runs.append(
        subprocess.run([sys.executable, "-c", SCRIPT, cache], capture_output=True, text=True, env=env, timeout=300)
    )
    assert runs[1].returncode == 0, runs[1].stderr
    assert runs[0].stdout == runs[1].stdout  # the same image from the cached program
    assert sorted(os.listdir(cache)) == files  # nothing new compiled and stored
