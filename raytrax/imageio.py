"""Reading and writing images through OpenImageIO.

- ``.exr`` keeps *linear* float32 pixels (or half floats with ``bits=16``) and
  carries metadata (scene name, spp, depth, render time...) as ``raytrax:*``
  attributes.
- ``.png`` (8 or 16 bits) and ``.jpg``/``.jpeg`` (8 bits) hold *sRGB-encoded*
  pixels: :func:`save_image` clips the linear image to ``[0, 1]``, applies the
  sRGB transfer function itself (:func:`linear_to_srgb`, not OpenImageIO's colour
  management) and quantises with rounding.
- :func:`load_image` returns linear float32 ``(H, W, 3)``: integer formats are
  decoded with :func:`srgb_to_linear` (unless the file says it is linear), float
  formats are returned as stored. Grey images are repeated to three channels and
  alpha is dropped.

:func:`save_image` takes *linear float* pixels only: an integer array (e.g.
``uint8`` display values) is refused rather than guessed at, and so is an image
with NaN or infinite values (which would otherwise turn silently into black or
white pixels).

Writes are atomic: the image goes to a temporary file in the destination
folder which is renamed over the destination only when complete, so a failed or
interrupted write never leaves a half-written (or any) output file.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping

import numpy as np

from ._atomic import atomic_path

__all__ = [
    "ImageError",
    "save_image",
    "load_image",
    "load_image_metadata",
    "linear_to_srgb",
    "srgb_to_linear",
    "to_display",
    "show",
    "WRITE_FORMATS",
]

#: extension -> (allowed bits, default bits, description)
WRITE_FORMATS = {
    ".exr": ((16, 32), 32, "OpenEXR, linear float"),
    ".png": ((8, 16), 8, "PNG, sRGB"),
    ".jpg": ((8,), 8, "JPEG, sRGB"),
    ".jpeg": ((8,), 8, "JPEG, sRGB"),
}


class ImageError(ValueError):
    """A user error about an image: unknown format, bad array shape or bit depth."""


def linear_to_srgb(x):
    """The sRGB transfer function (IEC 61966-2-1) on linear values in ``[0, 1]``:
    ``12.92 x`` for ``x <= 0.0031308``, else ``1.055 x^(1/2.4) - 0.055``."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_to_linear(x):
    """Inverse of :func:`linear_to_srgb`: ``x / 12.92`` for ``x <= 0.04045``, else
    ``((x + 0.055) / 1.055)^2.4``."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, np.power((np.maximum(x, 0.04045) + 0.055) / 1.055, 2.4))


def to_display(img) -> np.ndarray:
    """A linear image as sRGB-encoded float in ``[0, 1]`` (NaN shown black)."""
    a = np.nan_to_num(np.asarray(img, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return linear_to_srgb(np.clip(a, 0.0, 1.0))


def _as_rgb(img, what) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ImageError(f"{what}: expected an (H, W, 3) or (H, W) image, got shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ImageError(f"{what}: expected a numeric image, got dtype {a.dtype}")
    return a


def _as_linear_rgb(img, what) -> np.ndarray:
    """``img`` as an (H, W, 3) float array of finite linear values, or an ImageError."""
    a = _as_rgb(img, what)
    if not np.issubdtype(a.dtype, np.floating):
        raise ImageError(
            f"{what}: expected an image of linear float values, got dtype {a.dtype}; for 8-bit display "
            "(sRGB-encoded) values, pass srgb_to_linear(img / 255)"
        )
    bad = ~np.isfinite(a).all(axis=2)
    n = int(bad.sum())
    if n:
        H, W = a.shape[:2]
        kinds = [k for k, f in (("NaN", np.isnan), ("infinite", np.isinf)) if f(a).any()]
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise ImageError(
            f"{what}: {n} of {H * W} pixels are not finite ({' and '.join(kinds)} values; the first at "
            f"row {row}, column {col}); nothing written"
        )
    return a


def _ext(path) -> str:
    return os.path.splitext(os.fspath(path))[1].lower()


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _set_attr(spec, key, value):
    if isinstance(value, (bool, np.bool_)):
        spec.attribute(key, int(value))
    elif isinstance(value, (int, np.integer)):
        spec.attribute(key, int(value))
    elif isinstance(value, (float, np.floating)):
        spec.attribute(key, float(value))
    else:
        spec.attribute(key, str(value))


def save_image(
    path, img, *, metadata: Mapping | None = None, bits: int | None = None, before_rename: Callable | None = None
) -> None:
    """Write a linear ``(H, W, 3)`` (or grey ``(H, W)``) float image (numpy or jax
    array) to ``path``.

    The format follows the extension (see :data:`WRITE_FORMATS`): ``.exr`` stores
    linear float32 (``bits=16``: half floats); ``.png`` stores sRGB 8-bit, or
    16-bit with ``bits=16``; ``.jpg`` stores sRGB 8-bit. ``metadata`` (a mapping of
    names to strings or numbers) becomes ``raytrax:NAME`` attributes (typed in EXR;
    as text in PNG). The file appears atomically (temporary file + rename);
    ``before_rename()``, when given, is called once the temporary file is complete,
    just before the rename: it may raise to abandon the write (the temporary file
    is removed and ``path`` left as it was; the CLI does so on Ctrl-C).

    The values must be linear floats: an integer array (``uint8`` display values,
    say) raises :class:`ImageError` (a ``ValueError``) rather than being taken for
    linear values or written as they are; convert 8-bit sRGB values with
    ``srgb_to_linear(img / 255)``. An image with NaN or infinite values raises
    :class:`ImageError` naming ``path`` and the number of such pixels; nothing is
    written. Linear values outside ``[0, 1]`` are kept in EXR and clipped in PNG
    and JPEG.
    """
    path = os.fspath(path)
    ext = _ext(path)
    if ext not in WRITE_FORMATS:
        raise ImageError(
            f"{path}: cannot write images of type {ext or '(no extension)'!r}; "
            f"expected one of {', '.join(WRITE_FORMATS)}"
        )
    allowed, default, _ = WRITE_FORMATS[ext]
    if bits is None:
        bits = default
    if bits not in allowed:
        raise ImageError(f"{path}: bits: expected one of {allowed} for {ext} files, got {bits!r}")
    a = _as_linear_rgb(img, path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"{path}: cannot write: folder {folder} does not exist")
    oiio = _oiio()
    H, W = a.shape[:2]
    if ext == ".exr":
        fmt = oiio.HALF if bits == 16 else oiio.FLOAT
        data = np.ascontiguousarray(a, dtype=np.float32)
    else:
        enc = to_display(a)
        if bits == 16:
            fmt, data = oiio.UINT16, np.round(enc * 65535.0).astype(np.uint16)
        else:
            fmt, data = oiio.UINT8, np.round(enc * 255.0).astype(np.uint8)
        data = np.ascontiguousarray(data)
    spec = oiio.ImageSpec(W, H, 3, fmt)
    spec.attribute("Software", "raytrax")
    if ext == ".exr":
        spec.attribute("compression", "zip")
    elif ext in (".jpg", ".jpeg"):
        spec.attribute("Compression", "jpeg:95")
    for k, v in (metadata or {}).items():
        # EXR keeps typed attributes; PNG/JPEG text chunks keep strings only.
        _set_attr(spec, f"raytrax:{k}", v if ext == ".exr" else str(v))

    with atomic_path(path, suffix=ext) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"{path}: cannot write: {oiio.geterror()}")
        if not out.open(tmp, spec):
            msg = out.geterror()
            raise OSError(f"{path}: cannot write: {msg}")
        ok = out.write_image(data)
        msg = out.geterror() if not ok else ""
        out.close()
        if not ok:
            raise OSError(f"{path}: cannot write: {msg}")
        if before_rename is not None:
            before_rename()


def _open(path):
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: image file not found")
    if os.path.isdir(path):
        raise IsADirectoryError(f"{path}: expected an image file, found a folder")
    oiio = _oiio()
    inp = oiio.ImageInput.open(path)
    if inp is None:
        msg = oiio.geterror().strip().splitlines()
        raise OSError(f"{path}: cannot read image: {msg[0] if msg else 'unknown format'}")
    return inp


def load_image(path) -> np.ndarray:
    """Read an image as linear float32 ``(H, W, 3)`` (see the module docstring)."""
    oiio = _oiio()
    inp = _open(path)
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if data is None:
            raise OSError(f"{os.fspath(path)}: cannot read image: {inp.geterror()}")
        fmt = spec.format.basetype
        cs = str(spec.getattribute("oiio:ColorSpace") or "").lower()
    finally:
        inp.close()
    a = np.asarray(data, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[2] < 3:
        a = np.repeat(a[:, :, :1], 3, axis=2)
    a = a[:, :, :3]
    is_float = fmt in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    if not is_float and not cs.startswith("lin"):
        a = srgb_to_linear(a)
    return np.ascontiguousarray(a, dtype=np.float32)


def load_image_metadata(path) -> dict:
    """The ``raytrax:*`` attributes of an image file, without the prefix."""
    inp = _open(path)
    try:
        spec = inp.spec()
        out = {}
        for p in spec.extra_attribs:
            if p.name.startswith("raytrax:"):
                out[p.name[len("raytrax:") :]] = p.value
        return out
    finally:
        inp.close()


def show(img, *, ax=None, title: str | None = None, scale: float = 1.0):
    """Show a linear image inline (notebooks) with matplotlib, sRGB-encoded.

    ``scale`` multiplies the image first (exposure). Returns the axes.
    """
    import matplotlib.pyplot as plt

    enc = to_display(np.asarray(img, dtype=np.float64) * scale)
    if ax is None:
        h, w = enc.shape[:2]
        fig, ax = plt.subplots(figsize=(min(8.0, 4.0 * w / max(h, 1)) + 0.2, min(8.0, 4.0 * h / max(w, 1)) + 0.2))
    ax.imshow(enc, interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    return ax
