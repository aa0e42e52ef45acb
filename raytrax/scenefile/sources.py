"""Where this process read image textures and meshes from: a saved scene refers to the
same files again when its arrays still equal them (bit for bit)."""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import textures as tx

if TYPE_CHECKING:
    from .description import SceneDescription, TextureDesc

# -----------------------------------------------------------------------------
# Sources of images and meshes (so that saving a Scene can refer to them again)
# -----------------------------------------------------------------------------

_IMAGE_SOURCES: list = []  # (float32 image, TextureDesc without image)
_MESH_SOURCES: list = []  # (vertices float64, faces, params without arrays)
MAX_SOURCES = 32


def push(lst, item):
    lst.append(item)
    del lst[:-MAX_SOURCES]


@functools.cache
def builtin(name: str) -> np.ndarray:
    """A builtin image, read once per process (read-only)."""
    img = tx.builtin_image(name)
    img.setflags(write=False)
    return img


def remember_sources(desc: SceneDescription):
    for m in desc.materials.values():
        t = m.texture
        if t is not None and t.image is not None and t.kind in ("image", "builtin"):
            if not any(src is t.image for src, _ in _IMAGE_SOURCES):
                push(_IMAGE_SOURCES, (t.image, dataclasses.replace(t, image=None)))
    for o in desc.objects:
        if o.type == "mesh" and "source" in o.params:
            p = o.params
            if not any(v is p["vertices"] for v, _, _ in _MESH_SOURCES):
                meta = {k: p[k] for k in ("file", "source", "scale", "translate")}
                push(_MESH_SOURCES, (p["vertices"], p["faces"], meta))


def find_image_source(img: np.ndarray, builtin_desc: Callable[[str], Any]) -> TextureDesc | None:
    """The description of the file (or builtin, made by ``builtin_desc(name)``) that
    ``img`` came from, or None."""
    for src, t in reversed(_IMAGE_SOURCES):
        if src.shape == img.shape and np.array_equal(src.astype(img.dtype), img):
            if t.kind == "builtin" or (t.source and os.path.exists(t.source)):
                return t
    for name in tx.BUILTIN_IMAGES:  # a builtin used through the Python API
        try:
            b = builtin(name)
        except Exception:  # pragma: no cover - a sample image missing from scikit-image
            continue
        if b.shape == img.shape and np.array_equal(b.astype(img.dtype), img):
            return builtin_desc(name)
    return None


def find_mesh_source(v: np.ndarray, f: np.ndarray) -> dict | None:
    for sv, sf, meta in reversed(_MESH_SOURCES):
        if (
            sv.shape == v.shape
            and sf.shape == f.shape
            and np.array_equal(sf, f)
            and np.array_equal(sv.astype(v.dtype), v)
            and os.path.exists(meta["source"])
        ):
            return meta
    return None
