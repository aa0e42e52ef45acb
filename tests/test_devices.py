"""Sharding the image over several devices and batching renders with vmap."""

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import python_output

import raytrax as rt


@pytest.fixture(scope="module")
def scene():
    # scenes/ball_on_checker.toml: small (two primitive kinds, no dielectric) because every
    # distinct configuration here is compiled once more for several devices.
    return rt.load_scene(os.path.join(os.path.dirname(__file__), "..", "scenes", "ball_on_checker.toml"))


def test_four_host_devices_available():
    # conftest.py forces four CPU devices; without them the tests below would not shard.
    assert jax.device_count() >= 4


def test_sharded_image_equals_single_device(scene):
    one = rt.render(scene, tile_rays=64, devices=1)
    many = rt.render(scene, tile_rays=64, devices="all")
    default = rt.render(scene, tile_rays=64)  # over the CPU devices: as many as there are tiles
    assert many.shape == one.shape == default.shape
    np.testing.assert_allclose(np.asarray(many), np.asarray(one), rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(default), np.asarray(one), rtol=0, atol=1e-6)
    assert float(one.mean()) > 0.01


def test_default_devices_are_the_cpu_devices_up_to_the_tiles():
    from raytrax.renderer.api import cpu_devices_in_use

    assert cpu_devices_in_use() == jax.local_device_count()  # the CPU backend (conftest)


def test_edge_mode_is_sharded_by_default_only_on_large_grids_within_the_memory_bound():
    import dataclasses

    from raytrax.renderer.api import (
        EDGE_SHARD_MAX_BYTES,
        EDGE_SHARD_MIN_SAMPLES,
        cpu_devices_in_use,
        default_devices,
        edge_shard_bytes,
    )

    st = rt.load_scene(os.path.join(os.path.dirname(__file__), "..", "scenes", "tiny.toml")).settings
    n = cpu_devices_in_use()
    assert n >= 2
    small = dataclasses.replace(st, width=16, height=12, spp=256)  # 49,152 samples
    assert default_devices(small, 16384, edge_gradients=True) == 1
    assert default_devices(small, 16384, edge_gradients=False) == min(n, 3)  # tiles of 64 pixels
    assert default_devices(dataclasses.replace(small, spp=4), 16384, edge_gradients=False) == 1  # one tile
    mid = dataclasses.replace(st, width=160, height=120, spp=16, max_depth=6)  # 307,200 samples
    assert 16 * 12 * 256 < EDGE_SHARD_MIN_SAMPLES <= 160 * 120 * 16
    assert default_devices(mid, 16384, edge_gradients=True) == n
    assert default_devices(mid, 1 << 20, edge_gradients=True) == 1  # one tile of samples
    # 320 x 240, spp 64 (4,915,200 samples): the devices beyond the first stay within the
    # memory bound. With one light and about 700 primitive ids (107 objects, a box counting
    # its faces), each costs about 0.3 GiB at depth 0 (one fits the bound) and 0.8 GiB at
    # depth 6 (none fits); more lights, or a mesh's 10^5 ids (int32 records), cost more.
    shallow = dataclasses.replace(st, width=320, height=240, spp=64, max_depth=0)
    deep = dataclasses.replace(shallow, max_depth=6)
    assert edge_shard_bytes(shallow, 1, 700) <= EDGE_SHARD_MAX_BYTES < 2 * edge_shard_bytes(shallow, 1, 700)
    assert EDGE_SHARD_MAX_BYTES < edge_shard_bytes(deep, 1, 700)
    assert edge_shard_bytes(shallow, 1, 700) < min(
        edge_shard_bytes(shallow, 2, 700), edge_shard_bytes(shallow, 1, 10**5)
    )
    assert default_devices(shallow, 16384, True, lights=1, ids=700) == 2
    assert default_devices(deep, 16384, True, lights=1, ids=700) == 1
    assert default_devices(shallow, 16384, True, lights=8, ids=700) == 1
    assert default_devices(deep, 16384, edge_gradients=False) == n


_PROBE = "import raytrax, jax; print(jax.local_device_count())"


def _devices_in_fresh_process(code, **env):
    return int(python_output(code, **env).split()[-1])


def test_import_asks_jax_for_one_cpu_device_per_core():
    from raytrax.cpu_devices import wanted

    assert _devices_in_fresh_process(_PROBE, RAYTRAX_CPU_DEVICES="3") == 3
    assert _devices_in_fresh_process(_PROBE, RAYTRAX_CPU_DEVICES="1") == 1
    # A number chosen for jax itself, or jax already started, is left as it is.
    assert _devices_in_fresh_process(_PROBE, RAYTRAX_CPU_DEVICES="3", JAX_NUM_CPU_DEVICES="2") == 2
    started = "import jax, jax.numpy as jnp; jnp.zeros(1); " + _PROBE
    assert _devices_in_fresh_process(started, RAYTRAX_CPU_DEVICES="3") == 1
    assert wanted() >= 1


def test_a_bad_cpu_device_count_names_the_variable(monkeypatch):
    from raytrax.cpu_devices import wanted

    monkeypatch.setenv("RAYTRAX_CPU_DEVICES", "many")
    with pytest.raises(ValueError, match="RAYTRAX_CPU_DEVICES.*positive integer"):
        wanted()
    # At import it is a warning, and jax keeps its single CPU device (no traceback from the CLI).
    code = "import warnings; warnings.simplefilter('error'); " + _PROBE
    import subprocess

    with pytest.raises(subprocess.CalledProcessError):
        python_output(code, RAYTRAX_CPU_DEVICES="many")  # the warning, turned into an error
    assert _devices_in_fresh_process(_PROBE, RAYTRAX_CPU_DEVICES="many") == 1


def test_sharded_gradient_equals_single_device(scene):
    def loss(s, dev):
        return jnp.mean(rt.render(s, tile_rays=64, devices=dev) ** 2)

    g1 = eqx.filter_grad(lambda s: loss(s, 1))(scene)
    g4 = eqx.filter_grad(lambda s: loss(s, 4))(scene)
    np.testing.assert_allclose(g4.lights.position, g1.lights.position, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(g4.materials.color, g1.materials.color, rtol=1e-5, atol=1e-9)
    assert np.abs(np.asarray(g1.lights.position)).max() > 0


def test_images_rendered_over_different_device_counts_combine(scene):
    # A target at many samples and a loss at few shard over different numbers of
    # devices by default (one per tile, up to the CPU's devices). Every render's image
    # is on the default device, so the two meet in a loss as any two jax results do.
    target = rt.render(scene, tile_rays=64, devices=2)
    four = rt.render(scene, tile_rays=64, devices=4)
    assert float(jnp.max(jnp.abs(four - target))) <= 1e-6
    moved = eqx.tree_at(lambda s: s.lights.position, scene, scene.lights.position + 0.5)

    def loss(s, dev):
        return jnp.mean((rt.render(s, tile_rays=64, devices=dev) - target) ** 2)

    g4 = eqx.filter_grad(lambda s: loss(s, 4))(moved)
    g1 = eqx.filter_grad(lambda s: loss(s, 1))(moved)
    np.testing.assert_allclose(g4.lights.position, g1.lights.position, rtol=1e-5, atol=1e-9)
    assert np.abs(np.asarray(g1.lights.position)).max() > 0


def test_bad_device_count_is_a_clear_error(scene):
    with pytest.raises(ValueError, match="devices"):
        rt.render(scene, devices=10_000)


def test_vmap_over_light_positions(scene):
    offsets = jnp.linspace(-1.0, 1.0, 4, dtype=jnp.float32)
    pos = scene.lights.position[None] + offsets[:, None, None] * jnp.asarray([1.0, 0.0, 0.0], jnp.float32)[None, None]

    def one(p):
        return rt.render(eqx.tree_at(lambda s: s.lights.position, scene, p), tile_rays=64)

    batch = jax.vmap(one)(pos)
    assert batch.shape == (4, 16, 24, 3)
    for i in (0, 3):
        np.testing.assert_allclose(np.asarray(batch[i]), np.asarray(one(pos[i])), rtol=1e-5, atol=1e-6)
