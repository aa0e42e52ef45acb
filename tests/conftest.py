"""Strict JAX settings for the whole suite (as equinox and optimistix do)."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Four host devices, so the sharded render path is tested on CPU (tests/test_devices.py).
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
# The tests' own jax.jit calls compile with the options raytrax's entry points use
# (raytrax.compile_options: the CPU loop emitters that compile about twice as fast; the
# vector width, where the CPU has AVX-512, is added by `import raytrax` in the tests).
if "xla_cpu_use_fusion_emitters" not in os.environ["XLA_FLAGS"]:
    os.environ["XLA_FLAGS"] += " --xla_cpu_use_fusion_emitters=false"

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_enable_x64", True)  # float64 available where a gradient test asks for it


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Each test file runs in one worker (``--dist loadgroup`` with the file as the
    group, like ``--dist loadfile``), except that tests marked with the same
    ``xdist_group`` share a worker across files: they reuse each other's compiled
    programs and cached results (tests/golden/cases.py)."""
    for item in items:
        if next(item.iter_markers("xdist_group"), None) is None:
            item.add_marker(pytest.mark.xdist_group(item.path.name))
    # Longest groups first (with --no-loadscope-reorder, xdist hands the groups out in
    # this order): the edge tests alone take about half of one worker's time, and
    # started late they leave the other worker idle at the end.
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}

    def group_rank(item):
        group = next(item.iter_markers("xdist_group")).args[0]
        return rank.get(group, len(rank))

    items.sort(key=group_rank)  # stable: each group keeps its own order


# The suite's longest groups (xdist_group names), longest first: about 350, 130, 80, 60, 60,
# 60 and 55 s of a worker's time on the 2-core CI machine (pytest --durations=0).
LONGEST_FIRST = (
    "edge_cases",
    "test_docs.py",
    "test_gradients.py",
    "test_fit.py",
    "test_nan.py",
    "test_edges_glass.py",
    "test_devices.py",
)


_CACHE_OPTIONS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")


@pytest.fixture(autouse=True)
def _compilation_cache_left_as_it_was():
    """A test that turns on jax's persistent compilation cache in this process (the
    CLI's in-process ``main(["render", ...])`` does, in the user's own cache folder)
    must not leave it on for the tests after it: they would read and write programs
    in ``~/.cache`` and their times would depend on earlier runs."""
    before = {name: jax.config.values.get(name) for name in _CACHE_OPTIONS}
    yield
    if any(jax.config.values.get(name) != value for name, value in before.items()):
        from jax._src import compilation_cache

        for name, value in before.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()
