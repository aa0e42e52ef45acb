"""Scenes shared by the benchmark scripts (built in Python with :class:`raytrax.SceneBuilder`)."""

from __future__ import annotations

import argparse
import math
import os

import numpy as np

import raytrax as rt

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def physical_scene(
    width=160,
    height=120,
    spp=16,
    max_depth=5,
    *,
    diffuse=True,
    mirror=True,
    glass=True,
    box=True,
    tetra=True,
    lights=(0, 1),
):
    """Floor, diffuse / mirror / glass spheres, a rotated box, a tetrahedron, two point lights.

    The keyword switches drop objects (used to isolate which light paths differ).
    """
    b = rt.SceneBuilder(
        "physical",
        width=width,
        height=height,
        spp=spp,
        max_depth=max_depth,
        background=(0.0, 0.0, 0.0),
        name="physical",
    )
    b.camera(position=(0.0, 2.2, 7.0), look_at=(0.0, 0.8, 0.0), up=(0.0, 1.0, 0.0), fov=40.0)
    all_lights = [((3.0, 6.0, 4.0), (120.0, 108.0, 90.0)), ((-4.0, 5.0, 2.0), (36.0, 45.0, 66.0))]
    for i in lights:
        b.light(*all_lights[i])
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("red", color=(0.8, 0.25, 0.2))
    b.material("green", color=(0.25, 0.7, 0.3))
    b.material("blue", color=(0.2, 0.3, 0.8))
    b.material("mirror", color=(0.0, 0.0, 0.0), reflectivity=(0.9, 0.9, 0.9))
    b.material("glass", color=(0.0, 0.0, 0.0), transparency=1.0, ior=1.5)
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    if diffuse:
        b.sphere((-1.9, 0.7, 0.2), 0.7, "red")
    if mirror:
        b.sphere((0.1, 1.0, -1.2), 1.0, "mirror")
    if glass:
        b.sphere((1.2, 0.6, 1.3), 0.6, "glass")
    if box:
        b.box((-0.85, 0.0, 1.0), (-0.15, 0.7, 1.7), "blue", rotation=(0.0, 30.0, 0.0))
    if tetra:
        a = 1.2
        b.tetrahedron((2.3, a * math.sqrt(6.0) / 12.0, -0.6), a, "green")
    return b.build()


def simple_scene(width=160, height=120, spp=16, max_depth=5):
    """Floor + one diffuse sphere + one point light (must agree with Mitsuba to > 40 dB)."""
    b = rt.SceneBuilder("physical", width=width, height=height, spp=spp, max_depth=max_depth, name="simple")
    b.camera(position=(0.0, 2.2, 7.0), look_at=(0.0, 0.8, 0.0), fov=40.0)
    b.light((3.0, 6.0, 4.0), (120.0, 108.0, 90.0))
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("red", color=(0.8, 0.25, 0.2))
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    b.sphere((-0.3, 1.0, 0.0), 1.0, "red")
    return b.build()


def seed_scene(width=640, height=480, spp=4, max_depth=5):
    """The seed (COSC 363) scene in ``classic`` shading: ``scenes/cosc363.toml`` through
    ``rt.load_scene`` when both exist, otherwise a Python rendition of the report's
    scene (checkered floor, textured / striped / mirror / glass spheres, a cube, a
    tetrahedron, two lights at (+-10, 40, -5), the 20 x 20 image plane at distance 40)."""
    path = os.path.join(ROOT, "scenes", "cosc363.toml")
    if hasattr(rt, "load_scene") and os.path.exists(path):
        sc = rt.load_scene(path)
        return sc.replace_settings(width=width, height=height, spp=spp, max_depth=max_depth)
    b = rt.SceneBuilder(
        "classic",
        width=width,
        height=height,
        spp=spp,
        max_depth=max_depth,
        background=(0.0, 0.0, 0.0),
        ambient=(0.2, 0.2, 0.2),
        name="cosc363",
    )
    b.camera(position=(0, 0, 0), look_at=(0, 0, -1), up=(0, 1, 0), fov=2 * math.degrees(math.atan(10 / 40)))
    b.light((10.0, 40.0, -5.0), (1.0, 1.0, 1.0))
    b.light((-10.0, 40.0, -5.0), (1.0, 1.0, 1.0))
    b.material("floor", color=(0.9, 0.9, 0.9), specular=0.0, texture=rt.Checker(color2=(0.2, 0.2, 0.2), scale=0.2))
    b.material("purple_mirror", color=(0.6, 0.5, 0.8), specular=1.0, shininess=50.0, reflectivity=0.8)
    b.material(
        "planet", color=(1.0, 1.0, 1.0), specular=0.3, shininess=20.0, texture=rt.ImageTexture(rt.builtin_image("moon"))
    )
    b.material(
        "stripes",
        color=(0.1, 0.7, 0.2),
        specular=0.5,
        shininess=30.0,
        texture=rt.Stripes(color2=(0.0, 0.0, 0.0), scale=8.0, direction=(1.0, 1.0)),
    )
    b.material(
        "glass", color=(0.9, 0.9, 1.0), specular=1.0, shininess=100.0, reflectivity=0.1, transparency=0.8, ior=1.5
    )
    b.material("cube", color=(0.8, 0.3, 0.1), specular=0.5, shininess=20.0)
    b.material("tetra", color=(0.9, 0.8, 0.1), specular=0.5, shininess=20.0)
    b.quad([(-40, -15, -40), (40, -15, -40), (40, -15, -200), (-40, -15, -200)], "floor")
    b.sphere((-5.0, 0.0, -110.0), 15.0, "purple_mirror")
    b.sphere((9.0, 7.0, -80.0), 4.0, "planet")
    b.sphere((-11.0, -11.0, -75.0), 4.0, "stripes")
    b.sphere((5.0, -10.0, -70.0), 5.0, "glass")
    b.box((12.0, -15.0, -100.0), (18.0, -9.0, -94.0), "cube", rotation=(0.0, 25.0, 0.0))
    b.tetrahedron((-12.0, -15.0 + 6.0 * math.sqrt(6.0) / 12.0, -95.0), 6.0, "tetra")
    return b.build()


def many_spheres(n, width=160, height=120, spp=1, max_depth=2, seed=0):
    """A floor and ``n`` small diffuse spheres in a slab in front of the camera, one light."""
    rng = np.random.default_rng(seed)
    b = rt.SceneBuilder("physical", width=width, height=height, spp=spp, max_depth=max_depth, name=f"spheres{n}")
    b.camera(position=(0.0, 3.0, 9.0), look_at=(0.0, 0.5, 0.0), fov=40.0)
    b.light((3.0, 8.0, 5.0), (80.0, 80.0, 80.0))
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("ball", color=(0.6, 0.4, 0.3))
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    r = 0.6 / max(1.0, n ** (1 / 3))
    for c in rng.uniform((-3, r, -3), (3, 2.5, 3), size=(n, 3)):
        b.sphere(c, r, "ball")
    return b.build()


def many_triangles(n, width=160, height=120, spp=1, max_depth=2, seed=0):
    """A floor and ``n`` random small triangles (as one mesh), one light."""
    rng = np.random.default_rng(seed)
    b = rt.SceneBuilder("physical", width=width, height=height, spp=spp, max_depth=max_depth, name=f"tris{n}")
    b.camera(position=(0.0, 3.0, 9.0), look_at=(0.0, 0.5, 0.0), fov=40.0)
    b.light((3.0, 8.0, 5.0), (80.0, 80.0, 80.0))
    b.material("floor", color=(0.7, 0.7, 0.7))
    b.material("tri", color=(0.3, 0.5, 0.7))
    b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
    s = 1.2 / max(1.0, n ** (1 / 3))
    c = rng.uniform((-3, 0.3, -3), (3, 2.5, 3), size=(n, 1, 3))
    v = c + rng.uniform(-s, s, size=(n, 3, 3))
    b.mesh(v.reshape(-1, 3), np.arange(3 * n).reshape(n, 3), "tri")
    return b.build()


def terrain(n, width=160, height=120, spp=1, max_depth=2, seed=0):
    """A height field of about ``n`` triangles (a k x k grid of cells, two triangles
    each, rolling hills and noise) under one light, a mirror sphere above it."""
    rng = np.random.default_rng(seed)
    k = max(2, round(math.sqrt(n / 2)))
    b = rt.SceneBuilder(
        "physical", width=width, height=height, spp=spp, max_depth=max_depth, name=f"terrain{2 * k * k}"
    )
    b.camera(position=(0.0, 2.5, 6.0), look_at=(0.0, 0.0, 0.0), fov=45.0)
    b.light((2.0, 6.0, 4.0), (60.0, 60.0, 60.0))
    b.material("ground", color=(0.5, 0.6, 0.4))
    b.material("mirror", color=(0.0, 0.0, 0.0), reflectivity=0.9)
    x, z = np.meshgrid(np.linspace(-4, 4, k + 1), np.linspace(-4, 4, k + 1))
    y = 0.4 * np.sin(1.3 * x) * np.cos(0.9 * z) + 0.02 * rng.standard_normal(x.shape)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    i = np.arange(k * (k + 1)).reshape(k, k + 1)[:, :k].ravel()
    f = np.concatenate([np.stack([i, i + k + 1, i + 1], 1), np.stack([i + 1, i + k + 1, i + k + 2], 1)])
    b.mesh(v, f, "ground")
    b.sphere((0.5, 1.2, 0.0), 0.6, "mirror")
    return b.build()


def extra_scenes(width=96, height=72, spp=16, max_depth=6):
    """Small physical scenes that exercise the corners of the model (for
    ``compare_mitsuba.py --extra``): glass meshes (box, tetrahedron), a mixed
    diffuse + mirror material, quads and triangles, nested spheres, a camera under
    the floor, a light inside glass, a mirror quad seen from both sides, and high
    index glass with total internal reflection."""

    def base(
        cam=(0.0, 2.2, 7.0),
        at=(0.0, 0.8, 0.0),
        lights=(((3.0, 6.0, 4.0), (120.0, 108.0, 90.0)), ((-4.0, 5.0, 2.0), (36.0, 45.0, 66.0))),
    ):
        b = rt.SceneBuilder("physical", width=width, height=height, spp=spp, max_depth=max_depth)
        b.camera(position=cam, look_at=at, fov=45.0)
        for p, i in lights:
            b.light(p, i)
        b.material("floor", color=(0.7, 0.7, 0.7))
        b.material("glass", color=(0.0, 0.0, 0.0), transparency=1.0, ior=1.5)
        b.material("diamond", color=(0.0, 0.0, 0.0), transparency=1.0, ior=2.4)
        b.material("mirror", color=(0.0, 0.0, 0.0), reflectivity=(0.95, 0.8, 0.6))
        b.material("tinted", color=(0.8, 0.3, 0.2), reflectivity=(0.5, 0.6, 0.7))
        b.material("wall", color=(0.3, 0.6, 0.8))
        b.plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), "floor")
        return b

    out = {}
    # Glass solids are lifted 0.01 off the floor: a face coplanar with the floor is a
    # tie that the two renderers break differently (see benchmarks/README.md).
    b = base()
    b.box((-1, 0.01, 0), (0.2, 1.21, 1.2), "glass", rotation=(0, 35, 0))
    out["glass box"] = b
    b = base()
    b.tetrahedron((0.5, 0.01 + 1.5 * math.sqrt(6) / 12, 0.5), 1.5, "glass")
    out["glass tetrahedron"] = b
    b = base()
    b.tetrahedron((0.5, 1.5 * math.sqrt(6) / 12, 0.5), 1.5, "glass")
    out["glass tetrahedron on floor (tie)"] = b
    b = base()
    b.sphere((0, 1, 0), 1, "tinted")
    out["diffuse + mirror mixture"] = b
    b = base()
    b.quad([(-2, 0, -1.5), (2, 0, -1.5), (2, 2.5, -2), (-2, 2.5, -2)], "wall")
    b.triangle([(1, 0, 1), (2.5, 0, 0.5), (1.8, 1.8, 0.8)], "wall")
    b.sphere((0, 0.7, 0.5), 0.7, "glass")
    out["quad + triangle + glass"] = b
    b = base()
    b.sphere((0, 1, 0), 1, "glass")
    b.sphere((0, 1, 0), 0.5, "wall")
    out["sphere inside glass"] = b
    b = base(cam=(0, -2, 6), at=(0, 0.5, 0), lights=(((1, 4, 2), (100, 100, 100)), ((0, -3, 3), (20, 20, 20))))
    b.sphere((0, 1, 0), 1, "wall")
    out["camera below the floor"] = b
    b = base(lights=(((0, 1, 0), (50, 50, 50)), ((3, 5, 3), (60, 60, 60))))
    b.sphere((0, 1, 0), 0.8, "glass")
    out["light inside glass"] = b
    b = base(cam=(0, 1.5, -6), at=(0, 1, 0), lights=(((2, 4, -3), (80, 80, 80)),))
    b.quad([(-2, 0, 1), (2, 0, 1), (2, 2.5, 0.5), (-2, 2.5, 0.5)], "mirror")
    b.sphere((0.5, 0.5, -1.5), 0.5, "wall")
    out["mirror quad, back side"] = b
    b = base()
    b.sphere((0, 1, 0), 1, "diamond")
    b.box((-2.5, 0, -2), (-1.5, 1, -1), "wall")
    out["ior 2.4 sphere"] = b
    b = base()
    b.box((-0.7, 0, -0.7), (0.7, 1.4, 0.7), "diamond", rotation=(20, 30, 10))
    b.sphere((1.5, 0.4, -2), 0.4, "wall")
    out["ior 2.4 tilted box (TIR)"] = b
    return {k: v.build() for k, v in out.items()}


# Shared by the benchmarks' command lines.
def spp_list(text):
    """``--spp``: comma-separated square sample counts, e.g. ``256,1024``."""
    try:
        v = [int(c) for c in text.split(",")]
    except ValueError:
        v = []
    if not v or any(s < 1 or int(s**0.5) ** 2 != s for s in v):
        raise argparse.ArgumentTypeError(f"expected comma-separated square numbers (e.g. 256,1024), got {text!r}")
    return v


def image_size(text):
    """``--size``: ``WxH`` as ``(W, H)``, both positive."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 320x240, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"expected a positive width and height, got {text!r}")
    return w, h


def at_least(minimum):
    """An argparse type: an integer of at least ``minimum``."""

    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer of at least {minimum}, got {v}")
        return v

    return parse
