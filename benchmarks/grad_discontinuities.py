"""What the AD gradient means where the image jumps: a measured example for docs/gradients.md.

    python benchmarks/grad_discontinuities.py            # ~3-5 min on 2 shared cores (9 compilations)

A sphere on a checkered floor under one point light, seen from above at 32 x 24
pixels (classic shading, depth 1, float64). The scalar differentiated is a fixed
linear functional of the image, ``L = mean(R * image)`` with ``R`` a fixed random
image in [0, 1] (what the gradient of any image loss sees in one step: the
residual weights every pixel's derivative). For filtered textures on / off and
spp 1 / 16 we compare:

* ``AD``: ``jax.grad`` of ``L``;
* ``FD 1e-6``: a central difference with a tiny step (no sample crosses an edge:
  this is the derivative of the *sampled* image, and equals AD);
* ``FD big``: a central difference with step ``BIG`` (edges sweep across many
  samples: this sees the edges move);
* ``ref``: the big-step difference at spp 1024 (a 32 x 32 grid per pixel) with
  filtered textures: our estimate of the derivative of the pixel-integrated
  (anti-aliased) image, which is what fitting wants.

The parameters: ``light[0].position`` x (moves the sphere's shadow over the floor),
``object[1].center`` x (moves the sphere's silhouette and its shadow), and
``material.floor.texture.scale`` (moves only the checker edges).
"""

from __future__ import annotations

import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.renderer import render  # noqa: E402

W, H = 32, 24
BIG = 0.02
REF_SPP = 1024
PARAMS = [
    ("light[0].position", 0, "light x (shadow edge)"),
    ("object[1].center", 0, "sphere x (silhouette + shadow)"),
    ("material.floor.texture.scale", None, "checker scale (texture edges)"),
]


def scene():
    b = rt.SceneBuilder(
        "classic", width=W, height=H, spp=1, max_depth=1, background=(0.2, 0.2, 0.25), ambient=(0.25, 0.25, 0.25)
    )
    b.camera(position=(0.0, 4.0, 4.0), look_at=(0.0, 0.0, 0.0), fov=40)
    b.light((1.5, 4.0, 1.0), intensity=(0.9, 0.9, 0.9))
    b.material("floor", color=(0.9, 0.9, 0.9), texture=rt.Checker(color2=(0.15, 0.15, 0.15), scale=1.7))
    b.material("ball", color=(0.8, 0.3, 0.2), specular=0.3, shininess=20)
    b.plane((0, 0, 0), (0, 1, 0), "floor")
    b.sphere((0.0, 0.6, 0.0), 0.6, "ball")
    return b.build(jnp.float64)


def shifted(p, name, comp, delta):
    v = np.array(p[name], dtype=np.float64)
    if comp is None:
        v = v + delta
    else:
        v[comp] += delta
    return {**p, name: jnp.asarray(v)}


def main():
    t_start = time.time()
    s = scene()
    p = rt.parameters(s)
    R = jnp.asarray(np.random.default_rng(0).uniform(0.0, 1.0, (H, W, 3)))

    def functional(**kw):
        return lambda q: jnp.mean(R * render(rt.with_parameters(s, q), **kw))

    rows = {}
    for filt in (True, False):
        for spp in (1, 16):
            L = functional(spp=spp, filter_textures=filt)
            g = jax.grad(L)(p)
            for name, comp, label in PARAMS:
                ad = float(np.asarray(g[name]).reshape(-1)[0 if comp is None else comp])

                def fd(h):
                    return (float(L(shifted(p, name, comp, h))) - float(L(shifted(p, name, comp, -h)))) / (2 * h)

                rows[(label, filt, spp)] = dict(ad=ad, fd_small=fd(1e-6), fd_big=fd(BIG))
            print(f"  done filter={filt} spp={spp} ({time.time() - t_start:.0f} s)", flush=True)
    refs = {}
    L = functional(spp=REF_SPP, filter_textures=True)
    for name, comp, label in PARAMS:
        refs[label] = (float(L(shifted(p, name, comp, BIG))) - float(L(shifted(p, name, comp, -BIG)))) / (2 * BIG)

    print(
        f"\nsphere on a checkered floor, {W}x{H}, classic, depth 1, float64; L = mean(R * image), R fixed "
        f"random in [0, 1]; FD big step {BIG}; ref = FD big step at spp {REF_SPP} with filtered textures"
    )
    print("| parameter | textures | spp | AD | FD 1e-6 | FD big | ref | AD / ref |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for _name, _comp, label in PARAMS:
        for filt in (True, False):
            for spp in (1, 16):
                r = rows[(label, filt, spp)]
                print(
                    f"| {label} | {'filtered' if filt else 'hard'} | {spp} | {r['ad']:.4g} | {r['fd_small']:.4g} "
                    f"| {r['fd_big']:.4g} | {refs[label]:.4g} | {r['ad'] / refs[label]:.2f} |"
                )
    print(f"\n({time.time() - t_start:.0f} s; jax {jax.__version__})")


if __name__ == "__main__":
    main()
