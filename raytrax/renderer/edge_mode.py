"""Edge mode (``render(..., edge_gradients=True)``): the image from its grid of samples
plus the boundary term of :mod:`raytrax.edges`."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ..branching import any_in_batch, run_or_zeros
from ..camera import cone_spread
from ..chunks import equal_chunks, map_chunks
from ..compile_options import concrete, filter_jit
from ..edges import edge_image, find_edges
from ..intersect import prepare
from ..scene import Scene
from .options import RenderOptions
from .tiles import splat_positions
from .whitted import trace


def map_positions(fn, xy, chunk: int, sel=None, need=None, devices: int = 1):
    """``fn(xy_chunk (2, c), sel_chunk (c,) or None) -> (c, k)`` over image positions
    ``xy (2, M)`` (and per-position ``sel (M,)``) in equal chunks of at most ``chunk``
    (``lax.map``); returns ``(M, k)``. ``need (M,)``: a chunk with no needed position
    is skipped (zeros). ``devices > 1``: the chunks are dealt to that many devices."""
    M = xy.shape[1]
    n, c = equal_chunks(M, chunk, devices)
    args = {"xy": xy} | ({} if sel is None else {"sel": sel}) | ({} if need is None else {"need": need})

    def run(a):
        x, s = a["xy"], a.get("sel")
        if "need" not in a:
            return fn(x, s)
        return run_or_zeros(any_in_batch(a["need"]), fn, x, s)

    return map_chunks(run, args, M, n, c, out_axis=0, devices=devices, deal=devices > 1)


def radiance_at(scene: Scene, opts: RenderOptions, xy, n: int, light=None, grad=False, need=None, devices: int = 1):
    """Radiance ``(M, 3)`` of camera rays through image positions ``xy (2, M)`` (no
    gradient unless ``grad``; the jump across an edge). ``light`` (an index or ``(M,)``
    indices, may be traced): where below the number of lights, only what that light
    contributes, through every specular path (no ambient, no background, the other
    lights off); at or above it, everything. One trace of each ray whatever the indices.
    ``need (M,)``: the rays wanted (chunks of rays none of which is wanted are
    skipped, their radiance zero); ``devices``: the chunks dealt to that many devices."""
    st = opts.settings
    if not grad:
        scene = jax.lax.stop_gradient(scene)
    sel = None if light is None else jnp.broadcast_to(jnp.asarray(light, jnp.int32), xy.shape[1:])
    spread = cone_spread(scene.camera, st.height, n)
    kinds = prepare(scene)

    def one(x, s):
        return trace(scene, kinds, x, spread, opts, s).T

    return map_positions(one, xy, opts.tile_rays // st.branches, sel, need, devices)


def _find(scene: Scene, hard: RenderOptions, eo, check: bool):
    """:func:`raytrax.edges.find_edges` on the grid of ``scene`` (no gradient), its
    jumps measured with the ``hard`` options' renders (``check``: as there)."""
    st = hard.settings
    return find_edges(
        scene,
        st.width,
        st.height,
        eo,
        lambda xy, light, need: radiance_at(scene, hard, xy, eo.samples, light, need=need, devices=eo.devices),
        check,
    )


def _grid(scene: Scene, opts: RenderOptions, eo, quad):
    """The image from the ``n x n`` sample grid plus the silhouette quadrature's term
    (zero in value; ``quad`` from :func:`raytrax.edges.find_edges`), traced in one
    differentiable pass (one compiled trace, sharded like the plain render)."""
    st = opts.settings
    n = eo.samples
    W, H = st.width, st.height
    # Positions in pixels of the (W n, H n) sample grid, whose sample centres are
    # (j + 1/2, i + 1/2), exactly as a spp-1 render at that size places them. Image 0
    # is the grid's mean per pixel, image 1 the quadrature's term.
    Gw, Gh = W * n, H * n
    dt = scene.dtype
    jj, ii = jnp.meshgrid(jnp.arange(Gw, dtype=jnp.int32), jnp.arange(Gh, dtype=jnp.int32), indexing="xy")
    xy = jnp.stack([jj.ravel().astype(dt) + 0.5, ii.ravel().astype(dt) + 0.5])
    pixel = ((ii // n) * W + jj // n).ravel()
    weight = jnp.zeros((Gw * Gh, 2), dt).at[:, 0].set(1.0 / (n * n))
    needed = jnp.ones((Gw * Gh,), bool)
    if quad is not None:
        K, Q = quad["w"].shape
        xy = jnp.concatenate([xy, quad["xy"].reshape(2, K * Q) * n], 1)
        pixel = jnp.concatenate([pixel, jnp.repeat(quad["pixel"], Q)])
        weight = jnp.concatenate([weight, jnp.stack([jnp.zeros((K * Q,), dt), quad["w"].ravel()], 1)])
        needed = jnp.concatenate([needed, jnp.repeat(jnp.any(quad["w"] != 0, 1), Q)])
    grid = dataclasses.replace(opts, settings=dataclasses.replace(st, width=Gw, height=Gh, spp=1), jitter=False)
    spread = cone_spread(scene.camera, Gh)  # one grid sample's cone
    img, q = splat_positions(scene, grid, xy, needed, spread, pixel, weight, W * H)  # differentiable
    q = q - jax.lax.stop_gradient(q)  # the quadrature's term is zero in value
    return (img + q).reshape(H, W, 3)


def _edge_image(scene: Scene, opts: RenderOptions, found):
    return edge_image(scene, opts.settings.width, opts.settings.height, found)


_find_jit = filter_jit(_find)
_grid_jit = filter_jit(_grid)
_edge_image_jit = filter_jit(_edge_image)


def _hard(opts: RenderOptions) -> RenderOptions:
    """``opts`` with the hard (unfiltered) procedural patterns, which the finder
    measures jumps with: edge pieces are cut where the pattern changes beside the
    edge, so that the derivative the estimate converges to is that of the image as the
    samples grow, where the filter width goes to 0."""
    return dataclasses.replace(opts, settings=dataclasses.replace(opts.settings, filter_textures=False))


def render_edges(scene: Scene, opts: RenderOptions, eo):
    """The image from its ``n x n`` sample grid (``n = sqrt(spp)``), plus the boundary
    term of :mod:`raytrax.edges` (zero in value) found on the same samples.

    Three jitted programs: finding the edges (no gradient), the grid's image and
    the boundary term (both differentiable). Called outside ``jax.jit`` (a render,
    or an eager ``jax.grad``), each compiles on its own, which costs less than
    compiling them as one (XLA:CPU's compile time grows faster than the program);
    inside a ``jax.jit`` they are one program."""
    found, _, _, quad = _found(scene, opts, eo)
    return _grid_jit(scene, opts, eo, quad) + _edge_image_jit(scene, opts, found)


def budget_needed(scene: Scene, opts: RenderOptions, eo) -> int:
    """A budget that :func:`render_edges` of ``scene`` with these options needs
    (:func:`raytrax.edges.find_edges`), found with the finder that the render runs
    (``eo``'s budget; the scene's values concrete: :func:`~raytrax.compile_options.concrete`)."""
    return int(_found(scene, opts, eo)[1])


def _found(scene: Scene, opts: RenderOptions, eo):
    """The finder's results for ``scene``. Where the scene's values are concrete (a
    render outside any transformation, or an eager ``jax.grad``: the finder takes
    them without gradient), the finder returns whether the budget is exceeded and
    this raises the error here (a ``ValueError``, with the budget the scene needs);
    inside ``jax.jit`` or ``jax.vmap`` the finder raises it itself at run time. The
    finder of an eager render and of an eager gradient is then one compiled program,
    which jax's persistent compilation cache can keep (one with a run-time check
    cannot be cached)."""
    # Without gradient here too (find_edges stops it inside as well): under an eager
    # jax.grad the finder then runs as it is, with no JVP of it traced, and its
    # compiled program is the same whichever parameters are differentiated.
    scene = jax.lax.stop_gradient(scene)
    check = not concrete(scene)
    out = _find_jit(scene, _hard(opts), eo, check)
    if not check and bool(out[2]):
        raise ValueError(
            f"edge_gradients: more sample pairs straddle an edge than the edge budget holds "
            f"(edge_budget={eo.budget if eo.budget is not None else 'default'}; this render needs at least "
            f"{int(out[1])}); pass a larger edge_budget to render"
        )
    return out
