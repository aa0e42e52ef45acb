"""The public :func:`render` and :func:`edge_pairs`."""

from __future__ import annotations

import dataclasses
import math

import jax

from ..compile_options import concrete, top_level
from ..edges import EdgeOptions
from ..edges.prims import id_offsets
from ..edges.records import compact_bytes
from ..materials import never_specular
from ..memory import release_by_default
from ..scene import Scene, Settings
from .edge_mode import budget_needed, render_edges
from .options import RAYS_PER_TILE, RenderOptions
from .tiles import render_image, render_image_jit

# A render's first call compiles a large program: hand its memory back afterwards.
release_by_default()


# Edge mode is sharded by default over grids of at least this many samples: sharded, a
# call takes a third to a half less time (glass_over_boxes at 160 x 120, spp 16, first
# call about as long); below about 10^5 samples the saving was measured too small to
# repay a longer compile within a fit's few dozen calls.
EDGE_SHARD_MIN_SAMPLES = 1 << 17
# ... and only while the memory that each further device costs stays within this many
# bytes in all: every device holds the records of the whole grid and pairs its samples
# (:func:`edge_shard_bytes`).
EDGE_SHARD_MAX_BYTES = 1 << 29


def edge_shard_bytes(settings: Settings, lights: int, ids: int) -> int:
    """Estimated memory (bytes) that each device beyond the first adds to an edge-mode
    render of ``settings`` with ``lights`` lights and ``ids`` primitive ids (a box
    counts its faces): per grid sample, the compact records of its ``max_depth + 1``
    chain levels (:func:`raytrax.edges.records.compact_bytes`), twice (the gathered
    copy and its reordering), and about 56 bytes of pairing and positions. Fitted to
    the peak resident memory of ``value_and_grad`` at 320 x 240, spp 64 on two devices
    against one (``benchmarks/bench_edges.py``): +0.33 GiB for ``scenes/edge_sphere.toml``
    (depth 0, one light), +0.74 GiB for ``scenes/glass_over_boxes.toml`` (depth 6,
    one light); the estimate gives 0.33 and 0.77 GiB."""
    samples = settings.width * settings.height * settings.spp
    return samples * (56 + 2 * (settings.max_depth + 1) * compact_bytes(lights, ids))


def cpu_devices_in_use() -> int:
    """Devices a render shards over by default: the CPU devices where jax's default
    backend is the CPU, else 1."""
    return jax.local_device_count() if jax.default_backend() == "cpu" else 1


def default_devices(settings: Settings, tile_rays: int, edge_gradients: bool, lights: int = 1, ids: int = 1) -> int:
    """The devices a render of ``settings`` (a scene's :class:`~raytrax.Settings`, with
    ``lights`` lights and ``ids`` primitive ids) shards over when ``devices=None``: the CPU's devices
    (:func:`cpu_devices_in_use`), at most one per tile of ``tile_rays`` camera rays;
    with ``edge_gradients``, one below :data:`EDGE_SHARD_MIN_SAMPLES` grid samples
    (``width * height * spp``), else as many as keep the devices beyond the first
    within :data:`EDGE_SHARD_MAX_BYTES` of memory (:func:`edge_shard_bytes` each)."""
    pixels = settings.width * settings.height
    if edge_gradients:
        samples = pixels * settings.spp
        if samples < EDGE_SHARD_MIN_SAMPLES:
            return 1
        fit = 1 + EDGE_SHARD_MAX_BYTES // max(1, edge_shard_bytes(settings, lights, ids))
        return max(1, min(cpu_devices_in_use(), math.ceil(samples / tile_rays), fit))
    per_tile = max(1, min(pixels, tile_rays // settings.spp))
    return min(cpu_devices_in_use(), math.ceil(pixels / per_tile))


def render(
    scene: Scene,
    *,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    max_depth: int | None = None,
    key=None,
    filter_textures: bool | None = None,
    branches: int | None = None,
    tile_rays: int = RAYS_PER_TILE,
    devices=None,
    edge_gradients: bool = False,
    edge_budget: int | None = None,
) -> jax.Array:
    """Render ``scene`` to an ``(height, width, 3)`` linear RGB image.

    Keywords override the scene's own render settings (same names as the scene
    file's ``[render]`` keys): ``width``, ``height`` (pixels), ``spp`` (samples per
    pixel, a square number), ``max_depth`` (specular bounces; a
    scene whose materials neither reflect nor transmit renders as depth 0, the same
    image at less cost: :func:`raytrax.materials.never_specular`), ``filter_textures`` (box-filter
    procedural textures over each sample's footprint), ``branches``
    (specular branches kept per camera sample at each depth; default 2 where a
    material can split a path into reflected and refracted rays, else 1). ``key`` (a PRNG key) jitters each sample inside
    its sub-pixel stratum; without it the ``n x n`` grid is regular. The image
    has the scene's float dtype (float32, or float64 for a float64 scene with
    x64 enabled). Row 0 is the top row.

    ``devices``: an integer or ``"all"`` shards the image tiles over that many of
    ``jax.devices()`` with ``jax.shard_map`` (same image, gradients summed over
    devices); ``1`` renders on the default device. ``None`` (default): on the CPU,
    over its devices (one per core: :mod:`raytrax.cpu_devices`), at most one per
    tile, and with ``edge_gradients=True`` only for grids of at least 2^17 samples,
    over as many devices as keep the extra memory within 0.5 GiB (each device holds
    the records of every sample: :func:`default_devices`); elsewhere on the default
    device.
    The image is returned on ``jax.devices()[0]`` however many rendered it (where a
    one-device render's image is, unless jax's default device was changed), so
    images rendered over different numbers of devices combine directly.
    ``tile_rays``: camera rays per tile (memory of reverse mode scales with it).

    ``edge_gradients=True`` adds the boundary terms of the derivative (moving
    silhouettes, surface crossings and hard-shadow edges; see
    :mod:`raytrax.edges` and ``docs/gradients.md``). The image is the same (it
    is rendered as the ``sqrt(spp) x sqrt(spp)`` grid of samples per pixel, and
    edges are found between neighbouring samples); its gradient converges to
    the derivative of the pixel-integrated image as ``spp`` grows. Needs
    ``key=None``. ``edge_budget``: the most sample pairs with an edge between
    them (default: a quarter of the samples, at least 4096 and, past 65536, at most
    the larger of 65536 and samples / (2 sqrt(spp)); rounded up to whole chunks, it
    also bounds the pairs whose samples' records differ at all; exceeding it is an
    error naming the option: a ``ValueError`` with the budget the scene needs from a
    render outside any transformation or inside an eager ``jax.grad``, a runtime
    error inside ``jax.jit`` or ``jax.vmap``;
    :func:`edge_pairs` gives what a scene needs).

    Compiled once per scene structure and option set (``eqx.filter_jit``);
    differentiable with respect to every float leaf of ``scene``. Under
    ``jax.vmap`` a batch over what only colours a hit's light (light parameters,
    material colours and Phong terms, texture colours, pattern scales and directions,
    background and ambient) is batched inside the render (camera, reflected and
    refracted rays and their hits are shared: a quarter to two thirds of a loop's
    cost per image); a batch over anything that moves rays is rendered as a
    ``lax.map`` of single renders, at a loop's cost per image. Under
    ``jax.vmap`` of a gradient everything is batched inside: an eighth to a third of
    a loop's cost over lights or colours, 1.6-2 times it over anything else (see
    ``docs/scaling.md``).
    """
    st, opts, n_dev = _options(
        scene, width, height, spp, max_depth, key, filter_textures, branches, tile_rays, devices, edge_gradients
    )
    if edge_gradients:
        img = render_edges(scene, opts, _edge_options(st, key, edge_budget, n_dev))
    else:
        # Outside any transformation, one jitted program; under one (a jax.grad, jax.vmap
        # or a user's jax.jit), the render and its JVP rule are jitted apart, so that
        # each is traced only where the transformation needs it.
        img = (render_image_jit if top_level() else render_image)(scene, opts, key)
    return _on_default_device(img, n_dev)


def edge_pairs(
    scene: Scene,
    *,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    max_depth: int | None = None,
    filter_textures: bool | None = None,
    branches: int | None = None,
    tile_rays: int = RAYS_PER_TILE,
    devices=None,
    edge_budget: int | None = None,
) -> int:
    """The ``edge_budget`` that ``render(scene, edge_gradients=True, ...)`` with the
    same keywords needs: the number of sample pairs with an edge between them (edge
    crossings; a budget below it raises) or, where larger, of sample pairs whose
    samples' records differ at all (the pairing holds them too), plus the crossings
    found beyond a third primitive (a coarse mesh's outline beyond a face seen
    edge-on; a budget without room for them drops them). Runs the render's
    edge finder once (the program the render compiles with this ``edge_budget``,
    default the default budget) and returns a Python int; a scene that needs more
    than that budget raises the render's ``ValueError``. Call it outside ``jax.jit``, on
    a scene whose values are not traced (an eager ``jax.grad`` of other values is fine).

    The finder's arrays have the budget's size (its work past the last crossing is
    skipped, not its bookkeeping), so a budget a few times what the scene needs can
    make each edge-mode call cheaper, with the same gradient, as long as the edges
    stay within it (a third of a call on one scene, nothing measurable on another:
    ``docs/gradients.md``, "Cost")::

        need = rt.edge_pairs(scene)
        img = rt.render(scene, edge_gradients=True, edge_budget=max(1024, 4 * need))
    """
    if not concrete(scene):
        raise TypeError(
            "edge_pairs: call it with the scene's values, outside jax.jit and not on traced values "
            "(it runs the edge finder and returns a Python int); pass its result as render's edge_budget"
        )
    st, opts, n_dev = _options(
        scene, width, height, spp, max_depth, None, filter_textures, branches, tile_rays, devices, True
    )
    return budget_needed(scene, opts, _edge_options(st, None, edge_budget, n_dev))


def _options(scene, width, height, spp, max_depth, key, filter_textures, branches, tile_rays, devices, edge_gradients):
    """The settings, :class:`RenderOptions` and device count of a render of ``scene``
    with these keywords (:func:`render`'s), checked."""
    over = {
        k: v
        for k, v in dict(
            width=width, height=height, spp=spp, max_depth=max_depth, filter_textures=filter_textures, branches=branches
        ).items()
        if v is not None
    }
    st = dataclasses.replace(scene.settings, **over) if over else scene.settings
    if st.max_depth > 0 and never_specular(scene.materials):
        st = dataclasses.replace(st, max_depth=0)  # no ray goes past the camera hits: the same image
    if devices is None:
        n_dev = default_devices(st, tile_rays, edge_gradients, scene.n_lights, id_offsets(scene)["total"])
    elif devices == "all":
        n_dev = jax.device_count()
    elif isinstance(devices, int) and 1 <= devices <= jax.device_count():
        n_dev = devices
    else:
        raise ValueError(f"devices: expected None, 'all' or an integer in [1, {jax.device_count()}], got {devices!r}")
    return st, RenderOptions(settings=st, tile_rays=tile_rays, jitter=key is not None, devices=n_dev), n_dev


def _edge_options(st: Settings, key, edge_budget, n_dev: int) -> EdgeOptions:
    """The :class:`~raytrax.edges.EdgeOptions` of an edge-mode render of settings
    ``st``, its ``key`` and ``edge_budget`` checked."""
    if key is not None:
        raise ValueError("edge_gradients: edges are found on the regular n x n sample grid; pass key=None (no jitter)")
    if edge_budget is not None and (not isinstance(edge_budget, int) or edge_budget < 1):
        raise ValueError(f"edge_budget: expected a positive integer, got {edge_budget!r}")
    return EdgeOptions(math.isqrt(st.spp), edge_budget, st.max_depth + 1, n_dev)


def _on_default_device(img, n_dev: int):
    """``img`` of a render sharded over ``n_dev`` devices, placed on ``jax.devices()[0]``
    (the first device of its mesh, where a single-device render's image is by default):
    images rendered over different numbers of devices (a target at many samples, a
    loss at few) then combine without a device mismatch."""
    if n_dev <= 1:
        return img
    return jax.device_put(img, jax.devices()[0], may_alias=True)
