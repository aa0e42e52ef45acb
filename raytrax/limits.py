"""The one set of limits, defaults and value ranges of a scene.

:class:`~raytrax.scene.SceneBuilder` and the scene-file parser
(:mod:`raytrax.scenefile`) both read them from here, so that every scene the
builder accepts can be saved and loaded back, and both reject the same values with
messages that name the same key path and say the same thing
(``material.red.color: expected an [r, g, b] array of numbers in [0, 1] in physical
shading (or one number for grey), got [2.0, 1.0, 1.0]``).

- :data:`LIMITS`: upper bounds beyond which a value is rejected as absurd (image
  size, samples, depth, counts). One mutable dict: changing an entry (tests do, with
  ``monkeypatch.setitem``) changes it for the builder and the parser alike.
- Defaults, frozen dataclass instances: :data:`RENDER_DEFAULTS` (the image is
  **640 x 480** by default, in files and in Python), :data:`CAMERA_DEFAULTS` (the
  seed raytracer's camera, vertical field of view :data:`SEED_FOV`),
  :data:`MATERIAL_DEFAULTS`, :data:`TEXTURE_DEFAULTS`.
- Value ranges (:class:`Range`): :data:`FOV`, :func:`material_ranges` (per shading
  model: in ``physical`` shading colours and reflectivities are reflectances in
  ``[0, 1]``), :data:`TEXTURE_SCALE`, :data:`ENVIRONMENT_RGB`.
- Shared checks that return the problem as ``"expected ..., got ..."`` (or
  ``None``; the caller adds the key path): :func:`check_shading`,
  :func:`check_render_value`, :func:`check_pixels`, :func:`check_count`,
  :func:`check_mesh_faces`, :func:`check_texture_pixels`, :func:`number_problem`,
  :func:`rgb_problem`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

__all__ = [
    "LIMITS",
    "SHADING_MODELS",
    "SEED_FOV",
    "RENDER_DEFAULTS",
    "CAMERA_DEFAULTS",
    "MATERIAL_DEFAULTS",
    "TEXTURE_DEFAULTS",
    "RenderDefaults",
    "CameraDefaults",
    "MaterialDefaults",
    "TextureDefaults",
    "Range",
    "FOV",
    "NON_NEGATIVE",
    "UNIT",
    "IOR",
    "POSITIVE",
    "RGB_NON_NEGATIVE",
    "RGB_PHYSICAL",
    "ENVIRONMENT_RGB",
    "TEXTURE_SCALE",
    "MATERIAL_RANGES",
    "material_ranges",
    "rgb_what",
    "number_problem",
    "rgb_problem",
    "check_render_value",
    "check_pixels",
    "show_value",
    "show_number",
    "toml_string",
    "toml_key",
    "check_shading",
    "check_count",
    "check_mesh_faces",
    "check_texture_pixels",
]

#: Upper bounds beyond which a value is rejected as absurd.
LIMITS = dict(
    side=65536,  # pixels per image side
    pixels=100_000_000,  # width * height
    spp=1024,
    max_depth=64,
    lights=256,
    materials=4096,
    objects=100_000,
    mesh_faces=5_000_000,  # over all meshes
    texture_pixels=100_000_000,  # per image texture
)

SHADING_MODELS = ("classic", "physical")

#: The seed raytracer's vertical field of view: a 20 x 20 image plane at distance 40.
SEED_FOV = 2 * math.degrees(math.atan(10 / 40))

RGB = tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class RenderDefaults:
    """``[render]`` and :class:`~raytrax.scene.SceneBuilder` defaults: the shading
    model, a **640 x 480** image, one sample per pixel, 5 specular bounces."""

    shading: str = "classic"
    width: int = 640
    height: int = 480
    spp: int = 1
    max_depth: int = 5
    background: RGB = (0.0, 0.0, 0.0)
    ambient: RGB = (0.2, 0.2, 0.2)
    filter_textures: bool = True


@dataclasses.dataclass(frozen=True)
class CameraDefaults:
    """``[camera]`` defaults: at the origin looking down -z, the seed field of view."""

    position: RGB = (0.0, 0.0, 0.0)
    look_at: RGB = (0.0, 0.0, -1.0)
    up: RGB = (0.0, 1.0, 0.0)
    fov: float = SEED_FOV


@dataclasses.dataclass(frozen=True)
class MaterialDefaults:
    """``[material.NAME]`` defaults (no texture)."""

    color: RGB = (1.0, 1.0, 1.0)
    ambient: float = 1.0
    diffuse: float = 1.0
    specular: float = 0.0
    shininess: float = 10.0
    reflectivity: RGB = (0.0, 0.0, 0.0)
    transparency: float = 0.0
    ior: float = 1.0


@dataclasses.dataclass(frozen=True)
class TextureDefaults:
    """Checker and stripes defaults (those of :class:`raytrax.Checker` and :class:`raytrax.Stripes`)."""

    color2: RGB = (0.0, 0.0, 0.0)
    scale: float = 1.0
    direction: tuple[float, float] = (0.0, 1.0)


RENDER_DEFAULTS = RenderDefaults()
CAMERA_DEFAULTS = CameraDefaults()
MATERIAL_DEFAULTS = MaterialDefaults()
TEXTURE_DEFAULTS = TextureDefaults()


@dataclasses.dataclass(frozen=True)
class Range:
    """Numbers from ``lo`` to ``hi`` (``None``: unbounded), each end closed unless
    ``lo_open`` / ``hi_open``; ``what`` names them in messages ("a number in [0, 1]";
    for RGB ranges the plural, "numbers in [0, 1]")."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    what: str = "a number"

    def __contains__(self, x) -> bool:
        x = float(x)
        if not math.isfinite(x):
            return False
        if self.lo is not None and (x < self.lo or (self.lo_open and x == self.lo)):
            return False
        return not (self.hi is not None and (x > self.hi or (self.hi_open and x == self.hi)))


FOV = Range(0.0, 180.0, lo_open=True, hi_open=True, what="a vertical field of view in degrees, in (0, 180)")
NON_NEGATIVE = Range(0.0, what="a non-negative number")
UNIT = Range(0.0, 1.0, what="a number in [0, 1]")
IOR = Range(1.0, 10.0, what="a refractive index in [1, 10]")
POSITIVE = Range(0.0, lo_open=True, what="a positive number")
RGB_NON_NEGATIVE = Range(0.0, what="non-negative numbers")
#: Colours and reflectivities in physical shading are reflectances.
RGB_PHYSICAL = Range(0.0, 1.0, what="numbers in [0, 1] in physical shading")
#: ``render.background`` and ``render.ambient`` (radiance / light colour, any shading).
ENVIRONMENT_RGB = RGB_NON_NEGATIVE
#: ``texture.scale`` of checker and stripes textures.
TEXTURE_SCALE = POSITIVE

#: Per shading model, the range of each material value (``texture.color2`` follows ``color``).
MATERIAL_RANGES: Mapping[str, Mapping[str, Range]] = MappingProxyType(
    {
        shading: MappingProxyType(
            dict(
                color=RGB_PHYSICAL if shading == "physical" else RGB_NON_NEGATIVE,
                reflectivity=RGB_PHYSICAL if shading == "physical" else RGB_NON_NEGATIVE,
                ambient=NON_NEGATIVE,
                diffuse=NON_NEGATIVE,
                specular=NON_NEGATIVE,
                shininess=NON_NEGATIVE,
                transparency=UNIT,
                ior=IOR,
            )
        )
        for shading in SHADING_MODELS
    }
)


def material_ranges(shading: str) -> Mapping[str, Range]:
    """The :class:`Range` of each material value in ``shading`` (``"classic"``, ``"physical"``)."""
    return MATERIAL_RANGES[shading]


# -----------------------------------------------------------------------------
# Messages
# -----------------------------------------------------------------------------


def show_value(v) -> str:
    """How a found value is described in messages (TOML words: "the integer 3")."""
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, int):
        return f"the integer {v}"
    if isinstance(v, float):
        return f"the number {v!r}"
    if isinstance(v, str):
        s = v if len(v) <= 40 else v[:37] + "..."
        return f"the string {s!r}"
    if isinstance(v, list):
        if not v:
            return "an empty array"
        return f"an array of {len(v)} item{'s' if len(v) != 1 else ''}"
    if isinstance(v, dict):
        return "a table" + (f" with keys {', '.join(list(v)[:6])}" if v else " (empty)")
    return f"a {type(v).__name__} ({v})"


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def show_number(v) -> str:
    """A number as messages write it: integers as integers, floats by ``repr``."""
    if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)):
        return str(int(v))
    return repr(float(v))


def _value_text(v) -> str:
    return str(v) if _is_num(v) else show_value(v)


def rgb_what(rng: Range) -> str:
    """What an RGB value in ``rng`` is called: ``an [r, g, b] array of ... (or one number for grey)``."""
    return f"an [r, g, b] array of {rng.what} (or one number for grey)"


def number_problem(x, rng: Range) -> str | None:
    """The problem with the number ``x`` (a Python or NumPy number) for ``rng``, or ``None``."""
    if not math.isfinite(float(x)):
        return f"expected a finite number, got {show_number(x)}"
    if x not in rng:
        return f"expected {rng.what}, got {show_number(x)}"
    return None


def rgb_problem(c, rng: Range, found=None) -> str | None:
    """The problem with the RGB triple ``c`` (three finite numbers) for ``rng``, or
    ``None``; ``found`` is how the value was given (one number, or ``c``)."""
    if all(x in rng for x in c):
        return None
    if found is not None and np.ndim(found) == 0:
        text = show_number(found)
    else:
        text = str([float(x) for x in c])
    return f"expected {rgb_what(rng)}, got {text}"


def check_pixels(width, height) -> str | None:
    """The problem with an image of ``width x height`` pixels (too many), or ``None``."""
    if width * height > LIMITS["pixels"]:
        return (
            f"expected at most {LIMITS['pixels']:,} pixels, got width x height = {width} x {height} "
            f"= {width * height:,}"
        )
    return None


def check_render_value(key: str, value) -> str | None:
    """The problem with a ``[render]`` setting (``width``, ``height``, ``spp``,
    ``max_depth``, ``filter_textures``) as ``"expected ..., got ..."``, or ``None``
    when it is fine. Shared by the scene loader, the builder and the CLI's overrides."""
    if key in ("width", "height"):
        if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= LIMITS["side"]:
            return f"expected an integer number of pixels in [1, {LIMITS['side']}], got {_value_text(value)}"
    elif key == "spp":
        if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= LIMITS["spp"]:
            return f"expected a square number of samples per pixel in [1, {LIMITS['spp']}], got {_value_text(value)}"
        if math.isqrt(value) ** 2 != value:
            lo = math.isqrt(value)
            return (
                f"expected a square number of samples per pixel (1, 4, 9, 16, ...; an n x n grid), got {value} "
                f"(nearest: {lo * lo} or {(lo + 1) ** 2})"
            )
    elif key == "max_depth":
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= LIMITS["max_depth"]:
            return f"expected an integer in [0, {LIMITS['max_depth']}], got {_value_text(value)}"
    elif key == "filter_textures":
        if not isinstance(value, bool):
            return f"expected true or false, got {_value_text(value)}"
    return None


# -----------------------------------------------------------------------------
# Key paths
# -----------------------------------------------------------------------------

_BARE = re.compile(r"[A-Za-z0-9_-]+")  # fullmatch: "$" would let a trailing newline through


def toml_string(s: str) -> str:
    """``s`` as a TOML basic string (quoted, escaped)."""
    out = ['"']
    for ch in s:
        o = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_key(name: str) -> str:
    """A table key as key paths write it: bare when it can be (``glass``), else
    quoted (``"my glass"``): ``material."my glass".ior``."""
    return name if _BARE.fullmatch(name) else toml_string(name)


# -----------------------------------------------------------------------------
# Shading model and counts
# -----------------------------------------------------------------------------


def check_shading(value) -> str | None:
    """The problem with a shading model name (``shading = ...``), or ``None``."""
    options = ", ".join(repr(s) for s in SHADING_MODELS)
    if not isinstance(value, str):
        return f"expected one of {options}, got {show_value(value)}"
    if value not in SHADING_MODELS:
        near = difflib.get_close_matches(value, SHADING_MODELS, n=1, cutoff=0.6)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        return f"expected one of {options}, got {value!r}{hint}"
    return None


def check_count(what: str, n: int) -> str | None:
    """The problem with ``n`` lights, materials or objects (``what``: ``"light"``,
    ``"material"``, ``"object"``; the limit is ``LIMITS[what + "s"]``), or ``None``."""
    limit = LIMITS[f"{what}s"]
    return f"expected at most {limit} {what}s, got {n}" if n > limit else None


def check_mesh_faces(total: int) -> str | None:
    """The problem with ``total`` mesh triangles so far (over all meshes), or ``None``."""
    if total > LIMITS["mesh_faces"]:
        return f"expected at most {LIMITS['mesh_faces']:,} mesh triangles in all, got {total:,} so far"
    return None


def check_texture_pixels(height: int, width: int) -> str | None:
    """The problem with an image texture of ``width x height`` pixels, or ``None``."""
    if height * width > LIMITS["texture_pixels"]:
        return f"expected at most {LIMITS['texture_pixels']:,} pixels, got {width} x {height}"
    return None
