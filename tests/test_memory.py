"""raytrax.memory: the compiler's freed memory handed back after each large compilation."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import pytest

import raytrax as rt
from raytrax import memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc_trim")
def test_trims_after_a_compilation_and_can_be_turned_off():
    try:
        assert rt.release_memory_after_compile(min_seconds=0.0)
        before = memory._state["trims"]
        jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.0)(jnp.arange(7.0, dtype=jnp.float32)).block_until_ready()
        assert memory._state["trims"] > before  # the compilation above was followed by a trim
        assert not rt.release_memory_after_compile(False)
        before = memory._state["trims"]
        jax.jit(lambda x: jnp.cos(x) * 5.0 - 2.0)(jnp.arange(9.0, dtype=jnp.float32)).block_until_ready()
        assert memory._state["trims"] == before
    finally:
        rt.release_memory_after_compile()  # the default: on, after compilations of a second or more


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc_trim")
def test_rendering_turns_it_on_by_default():
    # In a fresh process: off after ``import raytrax``, on once the renderer is imported,
    # and a choice made before that import is kept.
    code = (
        "import raytrax as rt\n"
        "from raytrax import memory\n"
        "a = memory._state['listener'] is None\n"
        "rt.render\n"
        "b = memory._state['listener'] is not None\n"
        "print(a, b)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "True"]
    code_off = (
        "import raytrax as rt\n"
        "from raytrax import memory\n"
        "rt.release_memory_after_compile(False)\n"
        "rt.render\n"
        "print(memory._state['listener'] is None)\n"
    )
    assert subprocess.run(
        [sys.executable, "-c", code_off], capture_output=True, text=True, check=True
    ).stdout.split() == ["True"]
