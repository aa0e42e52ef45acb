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

The footprint is anisotropic (:func:`footprint_widths`): a ray cone meeting a
surface at a grazing angle covers a long thin ellipse, stretched along the view
direction, and the box takes that ellipse's extent along ``u`` and along ``v``
(through ray differentials of the hit, :func:`hit_with_uv_shifts`), so a far
checkered floor fades to its mean colour instead of aliasing while the pattern
stays sharp across the view direction.

The cone's width is the sample's share of the pixel at the camera and grows with
the distance travelled. A curved mirror spreads it further: reflected at a sphere
of radius ``R``, a cone of width ``w`` leaves with its spread grown by ``2 w / R``
(so a checker seen in a convex mirror is filtered over the patch the reflected
cone covers, not a patch as small as a flat mirror would show). Refraction keeps
the spread: a glass sphere's focusing is not modelled.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from . import vec as V
from .imageio import srgb_to_linear
from .materials import material_rows
from .tracing import kept_rows
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
    t00, t01, t10, t11 = (flat[iy * W + ix].T for iy, ix in ((iy0, ix0), (iy0, ix1), (iy1, ix0), (iy1, ix1)))
    t00, t01, t10, t11 = kept_rows((t00, t01, t10, t11), H * W, uv.shape[1])  # 12 values a ray
    return (
        t00 * ((1 - fx) * (1 - fy))[None]
        + t01 * (fx * (1 - fy))[None]
        + t10 * ((1 - fx) * fy)[None]
        + t11 * (fx * fy)[None]
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
    # Decoded in float64 (raytrax.imageio's sRGB curve) and rounded once: numpy's
    # float32 power differs between releases by an ulp, float64 rounded is stable.
    lin = srgb_to_linear(img)
    if name == "moon":
        lin = lin * np.asarray([1.0, 0.82, 0.62])
    return np.ascontiguousarray(lin, dtype=np.float32)


BUILTIN_IMAGES = ("moon", "astronaut", "coffee", "chelsea", "rocket", "camera", "brick", "grass", "gravel")


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


def surface_color(mats, mat, uv, wuv, filtered, rows=None):
    """Colour ``(3, n)`` of hits on materials ``mat (n,)`` at ``uv (2, n)``: the material
    colour, or its checker or stripes box-filtered over the footprint widths ``wuv
    (2, n)`` in uv units (:func:`footprint_widths`; unused unless ``filtered``), or its
    image texture (bilinear, tinted by the colour)."""
    kinds = mats.kinds_present
    if rows is None:
        rows = material_rows(mats, mat, ("color", "tex_scale", "tex_color2", "tex_direction") if kinds else ("color",))
    base = rows["color"]
    if not kinds:
        return base
    k = take_rows(mats.tex_kind, mat)
    frac = pattern_fraction(mats, k, rows, uv, wuv, filtered)
    c2 = rows["tex_color2"]
    color = base + (c2 - base) * frac[None]
    if IMAGE in kinds:
        img_id = take_rows(mats.tex_image, mat)
        for j, img in enumerate(mats.images):
            sel = (k == IMAGE) & (img_id == j)
            color = jnp.where(sel[None], base * bilinear(img, uv), color)
    return color


# ----------------------------------------------------------------------------
# Anisotropic footprints: the box of the ray cone's ellipse on the surface, in uv
# ----------------------------------------------------------------------------

MIN_COS = 0.02  # the footprint's elongation 1 / |cos| is capped at 1 / MIN_COS


def needs_footprint(mats, filtered: bool) -> bool:
    """Whether shading needs texture footprints: filtering on and a checker or stripes
    among the materials (static)."""
    return bool(filtered) and (CHECKER in mats.kinds_present or STRIPES in mats.kinds_present)


def hit_with_uv_shifts(hit_fn, o, d, needed: bool):
    """``hit_fn(o)`` (a :class:`~raytrax.intersect.Hit` of rays from origins ``o (3, n)``
    along unit ``d (3, n)``) and, when ``needed``, the ray differentials of its ``uv``:
    ``(e, duv)`` with ``e (2, 3, n)`` two unit vectors across each ray (orthogonal to
    ``d`` and to each other) and ``duv (2, 2, n)`` the change of ``uv`` per unit parallel
    shift of the ray along each of them (else ``None``).

    One forward-mode pass (``jax.jvp``, both shifts batched by ``jax.vmap``) through
    the hit: the search is stop-gradient and runs once, and only the kinds' per-ray hit
    recomputation carries the shifts. So the derivatives are exact for every kind
    (planes, spheres, box faces, triangles...; curvature included) with no per-kind
    code here: nothing needs to know how a kind lays out ``(u, v)``."""
    if not needed:
        return hit_fn(o), None
    # Two unit vectors across the rays: x (z for rays near x) without its part along d.
    ax = (jnp.abs(d[0]) < 0.9).astype(d.dtype)
    f = jnp.stack([ax, jnp.zeros_like(ax), 1.0 - ax])
    e1 = V.normalize(f - V.dot(f, d)[None] * d)
    e = jnp.stack([e1, V.cross(d, e1)])

    def shifted(s):
        return jax.jvp(hit_fn, (o,), (s,))

    hit, dhit = jax.vmap(shifted, out_axes=(None, 0))(e)
    return hit, (e, dhit.uv)


def footprint_widths(shifts, d, normal, width, min_cos=MIN_COS):
    """Box-filter widths ``(2, n)`` in uv units of ray cones meeting a surface.

    A cone of width ``width (n,)`` at the hit, along unit directions ``d (3, n)``,
    meets the surface (unit normal ``normal (3, n)``, either side) in an ellipse: its
    long axis lies along ``a``, the unit projection of ``d`` on the tangent plane, with
    length ``width / |cos|`` (``cos = d . normal``), its short axis along ``b = normal x
    a`` with length ``width``. With ``J`` the uv Jacobian along the surface, the
    ellipse's extent along ``u`` and along ``v`` is

        ``w_k = width * sqrt((J_k a / |cos|)^2 + (J_k b)^2)``  (``k = u, v``),

    and these are the widths of the box filter (the ellipse's bounding box in uv). At
    normal incidence this is the isotropic ``width * |grad_k|``; at grazing incidence
    the box is long along the view only, so a pattern averages out along the view and
    stays sharp across it. The elongation ``1 / |cos|`` is capped at ``1 / min_cos``.

    ``J a`` and ``J b`` come from the ray differentials ``shifts = (e, duv)`` of
    :func:`hit_with_uv_shifts`: shifting a ray across itself along ``m``, the part of
    the normal across the ray, moves the hit by ``-a / cos`` (this is where the ellipse
    is long), and along ``d x m`` it moves the hit by ``b``; ``m`` is written in the
    basis ``e`` and the shifts combine linearly. Finite in value and gradient
    everywhere, also at ``cos = 0`` and at normal incidence (where ``m = 0`` and any
    direction will do: the ellipse is a circle).
    """
    e, duv = shifts
    cos = V.dot(d, normal)
    mh = V.normalize(normal - cos[None] * d, fallback=e[0])
    m1, m2 = V.dot(e[0], mh), V.dot(e[1], mh)
    j_long = m1[None] * duv[0] + m2[None] * duv[1]  # J a / cos (up to sign): the long axis
    j_short = m1[None] * duv[1] - m2[None] * duv[0]  # J b (up to sign): the short axis
    ac = jnp.abs(cos)
    j_long = j_long * (ac / jnp.maximum(ac, min_cos))[None]
    return width[None] * V.safe_sqrt(j_long * j_long + j_short * j_short)
