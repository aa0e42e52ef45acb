"""The XLA options raytrax compiles with (raytrax.compile_options)."""

import jax
import jax.numpy as jnp
import numpy as np
from helpers import one_sphere_scene, python_output

import raytrax as rt
from raytrax import compile_options as co

_FLAGS = "import os, raytrax; print(repr(os.environ.get('XLA_FLAGS', '')))"


def test_options_are_for_the_cpu_backend_only():
    assert co.compiler_options("gpu") == {}
    assert co.compiler_options("cpu") == (co.CPU_OPTIONS if co.jaxlib_checked() else {})
    assert rt.compiler_options() == co.compiler_options("cpu")  # the suite runs on CPU (conftest)


def test_import_sets_the_flag_only_when_free_to():
    flag = "--xla_cpu_use_fusion_emitters=false"
    if co.jaxlib_checked():
        assert flag in python_output(_FLAGS)
    assert flag not in python_output(_FLAGS, RAYTRAX_XLA_FLAGS="0")
    # jax started before raytrax: XLA has read its flags, so they are left as they are
    assert flag not in python_output("import jax.numpy as jnp; jnp.zeros(1); " + _FLAGS)
    # a choice of the user's stays
    assert "use_fusion_emitters=true" in python_output(_FLAGS, XLA_FLAGS="--xla_cpu_use_fusion_emitters=true")


def test_512_bit_vectors_exactly_where_the_cpu_has_avx512():
    want = {"xla_cpu_use_fusion_emitters": False} | (
        {"xla_cpu_prefer_vector_width": 512} if co.cpu_has_avx512() else {}
    )
    assert co.CPU_OPTIONS == want
    flags = python_output(_FLAGS, XLA_FLAGS="--xla_cpu_prefer_vector_width=256")
    assert "--xla_cpu_prefer_vector_width=256" in flags and "=512" not in flags  # the user's choice stays
    if co.jaxlib_checked():
        assert ("--xla_cpu_prefer_vector_width=512" in python_output(_FLAGS)) == co.cpu_has_avx512()
        assert "--xla_cpu_use_fusion_emitters=false" in flags  # the other option is still added
    assert co.flag("a", False) == "--a=false" and co.flag("b", 512) == "--b=512"


def test_a_render_inside_a_users_jit_equals_the_top_level_render():
    # rt.render passes its options only as a top-level jit (jax refuses them on a nested
    # one); inside jax.jit with or without the options it renders the same image.
    scene = one_sphere_scene(width=8, height=6)
    top = rt.render(scene)
    nested = jax.jit(lambda s: rt.render(s), compiler_options=rt.compiler_options())(scene)
    np.testing.assert_allclose(np.asarray(nested), np.asarray(top), rtol=1e-6, atol=1e-7)
    assert float(jnp.max(top)) > 0.05


def test_a_render_inside_a_users_jit_is_traced_once_under_grad(monkeypatch):
    # Under jax.grad the render's JVP rule is traced, not its primal as well (a jitted
    # whole would be traced for its primal, then linearised: twice the tracing time).
    from raytrax.renderer import tiles

    calls = []
    inner = tiles._render_image

    def counted(*args):
        calls.append(1)
        return inner(*args)

    monkeypatch.setattr(tiles, "_render_image", counted)
    monkeypatch.setattr(tiles, "_render_image_jit", tiles.filter_jit(counted))
    jax.clear_caches()  # no trace of an earlier test's render is reused
    scene = one_sphere_scene(width=8, height=6)

    def loss(r):
        s = rt.with_parameters(scene, {"object[0].radius": r})
        return jnp.mean(rt.render(s))

    jax.jit(jax.grad(loss)).trace(jnp.float32(1.0))
    assert len(calls) == 1
