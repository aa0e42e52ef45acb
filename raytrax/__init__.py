"""raytrax: a differentiable Whitted-style raytracer in JAX.

The public names below are imported lazily, on first use (PEP 562): ``import
raytrax`` costs almost nothing, and ``rt.render`` imports jax and equinox, but
not the fitting stack (optimistix, lineax) until ``rt.fit`` is used, nor
OpenImageIO until an image is read or written. ``from raytrax import fit`` and
``rt.FitResult`` work as before.

Importing raytrax asks jax for one CPU device per core if jax has not started yet
(:mod:`raytrax.cpu_devices`; ``RAYTRAX_CPU_DEVICES=1`` leaves jax as it is), so that
renders use every core, and for XLA's faster-compiling CPU loop emitters
(:mod:`raytrax.compile_options`; ``RAYTRAX_XLA_FLAGS=0`` leaves ``XLA_FLAGS`` as it is).
"""

import importlib

from . import compile_options as _compile_options
from . import cpu_devices as _cpu_devices

__version__ = "0.1.0"

_cpu_devices.request()  # one jax CPU device per core, if jax has not started (raytrax.cpu_devices)
_compile_options.request()  # XLA's faster-compiling CPU loop emitters, likewise (raytrax.compile_options)

# public name -> submodule that defines it
_LAZY = {
    "Camera": "camera",
    "RenderOptions": "renderer",
    "render": "renderer",
    "edge_pairs": "renderer",
    "PointLights": "lights",
    "DirectionalLights": "lights",
    "Materials": "materials",
    "fresnel_dielectric": "materials",
    "refract": "materials",
    "parameters": "params",
    "with_parameters": "params",
    "FitResult": "_fitting",
    "fit": "_fitting",
    "Environment": "scene",
    "Scene": "scene",
    "SceneBuilder": "scene",
    "Settings": "scene",
    "Boxes": "shapes",
    "Disks": "shapes",
    "Mesh": "shapes",
    "Planes": "shapes",
    "Quads": "shapes",
    "Spheres": "shapes",
    "Tetrahedra": "shapes",
    "Triangles": "shapes",
    "Checker": "textures",
    "ImageTexture": "textures",
    "Stripes": "textures",
    "builtin_image": "textures",
    "load_scene": "scenefile",
    "save_scene": "scenefile",
    "SceneError": "scenefile",
    "save_image": "imageio",
    "load_image": "imageio",
    "enable_compilation_cache": "executables",
    "compiler_options": "compile_options",
    "release_memory_after_compile": "memory",
}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
