"""Textures: procedural checker and stripes (box-filtered over the pixel footprint)
and bilinear image textures.

Description types (:class:`Checker`, :class:`Stripes`, :class:`ImageTexture`) are
plain Python values used when building a scene; the runtime form lives in the
:class:`~raytrax.materials.Materials` table (per-material kind, second colour,
scale, stripe direction, image index) and a tuple of image arrays.

Procedural patterns are evaluated on the surface coordinates ``(u, v)`` of the
hit (see :mod:`raytrax.shapes` for each kind's mapping) times ``scale``:

- checker: ``floor(u*scale) + floor(v*scale)`` odd -> ``color2`` else the
  material colour;
- stripes: ``floor((u*du + v*dv)*scale)`` odd -> ``color2``.

With filtering on, each square wave is replaced by its exact box-filtered
average over the footprint width ``w`` (in pattern units), so edges are
anti-aliased and the texture has a non-zero derivative with respect to
anything that moves ``(u, v)`` (geometry, camera, refractive index).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from .materials import material_rows
from .vec import take_rows

NONE, CHECKER, STRIPES, IMAGE = 0, 1, 2, 3
KIND_NAMES = {"checker": CHECKER, "stripes": STRIPES, "image": IMAGE}


@dataclasses.dataclass(frozen=True)
class Checker:
    """A checkerboard alternating the material colour and ``color2``; ``scale`` cells
    per unit of ``(u, v)`` (world units on planes, ``[0, 1]`` on spheres and quads)."""

    color2: tuple = (0.0, 0.0, 0.0)
    scale: float = 1.0


@dataclasses.dataclass(frozen=True)
class Stripes:
    """Stripes alternating the material colour and ``color2`` along ``direction``
    ``(du, dv)`` in ``(u, v)``: the pattern coordinate is ``(u du + v dv) scale``
    and each stripe is one unit of it wide. Filtering is exact for axis-aligned
    directions; for diagonal ones the footprint width is ``|w_u du| + |w_v dv|``
    (a box that slightly over-blurs)."""

    color2: tuple = (0.0, 0.0, 0.0)
    scale: float = 1.0
    direction: tuple = (0.0, 1.0)


@dataclasses.dataclass(frozen=True, eq=False)
class ImageTexture:
    """An image ``(H, W, 3)`` of *linear* RGB, mapped over ``(u, v)`` in ``[0, 1]``:
    ``u`` left to right (wrapping), ``v`` bottom to top (clamped); bilinear; the
    material colour multiplies it (a tint)."""

    image: np.ndarray
    name: str = ""


def _square_integral(x):
    """Integral from 0 to x of the square wave ``floor(x) mod 2``."""
    h = x * 0.5
    return jnp.floor(h) + jnp.maximum(2.0 * (h - jnp.floor(h)) - 1.0, 0.0)


def square_wave(x, w, filtered: bool):
    """``floor(x) mod 2`` in ``{0, 1}``, or its box-filtered average over
    ``[x - w/2, x + w/2]`` (exact; equal to the hard value as ``w -> 0``)."""
    hard = jnp.mod(jnp.floor(x), 2.0)
    if not filtered:
        return hard
    ok = w > 1e-6
    ws = jnp.where(ok, w, 1.0)
    avg = (_square_integral(x + 0.5 * ws) - _square_integral(x - 0.5 * ws)) / ws
    return jnp.where(ok, avg, hard)


def checker(uv, width, scale, filtered):
    """Fraction of the footprint on ``color2`` cells: the average of XOR of two
    independent filtered square waves. ``uv`` (2, n), ``width`` (2, n) in uv units."""
    fu = square_wave(uv[0] * scale, width[0] * scale, filtered)
    fv = square_wave(uv[1] * scale, width[1] * scale, filtered)
    return fu * (1.0 - fv) + fv * (1.0 - fu)


def stripes(uv, width, scale, direction, filtered):
    s = uv[0] * direction[0] + uv[1] * direction[1]
    ws = jnp.abs(width[0] * direction[0]) + jnp.abs(width[1] * direction[1])
    return square_wave(s * scale, ws * scale, filtered)


def bilinear(image, uv):
    """Bilinear lookup of ``image (H, W, 3)`` at ``uv (2, n)``; returns ``(3, n)``.

    Texel centres sit at ``((j + 0.5)/W, 1 - (i + 0.5)/H)``; ``u`` wraps around,
    ``v`` is clamped. Differentiable with respect to the texels and to ``uv``.
    """
    H, W = image.shape[0], image.shape[1]
    x = uv[0] * W - 0.5
    y = (1.0 - uv[1]) * H - 0.5
    y = jnp.clip(y, 0.0, H - 1.0)
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx, fy = x - x0, y - y0
    ix0 = jnp.mod(x0.astype(jnp.int32), W)
    ix1 = jnp.mod(ix0 + 1, W)
    iy0 = jnp.clip(y0.astype(jnp.int32), 0, H - 1)
    iy1 = jnp.clip(iy0 + 1, 0, H - 1)
    flat = image.reshape(H * W, image.shape[2])

    def g(iy, ix):
        return flat[iy * W + ix].T

    return (
        g(iy0, ix0) * ((1 - fx) * (1 - fy))[None]
        + g(iy0, ix1) * (fx * (1 - fy))[None]
        + g(iy1, ix0) * ((1 - fx) * fy)[None]
        + g(iy1, ix1) * (fx * fy)[None]
    )


def builtin_image(name: str) -> np.ndarray:
    """Sample images shipped with scikit-image, as linear RGB float32 ``(H, W, 3)``.

    ``"moon"`` is scikit-image's grey moon photograph tinted to a warm grey, a
    stand-in planet texture (Mercury-like); the others are scikit-image's
    ``data`` images of that name (``"astronaut"``, ``"coffee"``, ``"chelsea"``,
    ``"rocket"``, ``"camera"``, ``"brick"``, ``"grass"``, ``"gravel"``...).
    """
    from skimage import data

    if name not in BUILTIN_IMAGES:
        raise ValueError(f"unknown builtin image {name!r}; expected one of {sorted(BUILTIN_IMAGES)}")
    img = np.asarray(getattr(data, name)(), dtype=np.float32) / 255.0
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    lin = srgb_to_linear_np(img)
    if name == "moon":
        lin = lin * np.asarray([1.0, 0.82, 0.62], dtype=np.float32)
    return np.ascontiguousarray(lin, dtype=np.float32)


BUILTIN_IMAGES = ("moon", "astronaut", "coffee", "chelsea", "rocket", "camera", "brick", "grass", "gravel")


def srgb_to_linear_np(x):
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


TWO_PI = 2 * math.pi


# ----------------------------------------------------------------------------
# Surface colour of hits: the material's colour or texture at (u, v)
# ----------------------------------------------------------------------------


def pattern_fraction(mats, k, rows, uv, wuv, filtered):
    """Fraction ``(n,)`` of the footprint on ``color2`` of each ray's checker or stripes
    (0 for other texture kinds ``k (n,)``); ``rows``: ``tex_scale`` and, with stripes,
    ``tex_direction``; ``wuv (2, n)``: footprint widths in uv units."""
    kinds = mats.kinds_present
    frac = jnp.zeros_like(uv[0])
    if CHECKER in kinds:
        frac = jnp.where(k == CHECKER, checker(uv, wuv, rows["tex_scale"], filtered), frac)
    if STRIPES in kinds:
        frac = jnp.where(k == STRIPES, stripes(uv, wuv, rows["tex_scale"], rows["tex_direction"], filtered), frac)
    return frac


def pattern_cell(mats, mat, uv):
    """Which colour the *hard* (unfiltered) procedural pattern shows at ``uv (2, n)``
    on materials ``mat (n,)``: 1 for ``color2``, else 0 (also for materials without a
    checker or stripes). Edge gradients cut edge pieces where it changes."""
    if CHECKER not in mats.kinds_present and STRIPES not in mats.kinds_present:
        return jnp.zeros(mat.shape, jnp.int32)
    rows = material_rows(mats, mat, ("tex_scale", "tex_direction"))
    k = take_rows(mats.tex_kind, mat)
    return pattern_fraction(mats, k, rows, uv, jnp.zeros_like(uv), False).astype(jnp.int32)


def surface_color(mats, mat, uv, rate, width, filtered, rows=None):
    kinds = mats.kinds_present
    if rows is None:
        rows = material_rows(mats, mat, ("color", "tex_scale", "tex_color2", "tex_direction") if kinds else ("color",))
    base = rows["color"]
    if not kinds:
        return base
    k = take_rows(mats.tex_kind, mat)
    frac = pattern_fraction(mats, k, rows, uv, rate * width[None], filtered)
    c2 = rows["tex_color2"]
    color = base + (c2 - base) * frac[None]
    if IMAGE in kinds:
        img_id = take_rows(mats.tex_image, mat)
        for j, img in enumerate(mats.images):
            sel = (k == IMAGE) & (img_id == j)
            color = jnp.where(sel[None], base * bilinear(img, uv), color)
    return color
