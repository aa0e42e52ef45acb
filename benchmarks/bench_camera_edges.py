"""Edge gradients with respect to the camera, against central differences, per kind of edge.

    python benchmarks/bench_camera_edges.py                         # every case, ~15 min on 2 cores
    python benchmarks/bench_camera_edges.py --cases checker --spp 64,256,1024,4096

Moving the camera moves every edge in the image at once. Each case has the camera, the
first light and the size of ``scenes/edge_occluders.toml`` (16 x 12, classic shading,
float64, the loss ``mean(R * image)`` of ``tests/test_edges.py``) and some of its objects:
``sphere`` (the ball alone, over the background), ``box`` (the rotated box alone),
``floor_sphere`` (the ball over a plain floor: silhouette and shadow), ``checker`` (the
checkered floor alone, box-filtered, the default: no geometric edge in view, only the
pattern's) and ``image`` (a checker of the same cell size as a bilinear ``ImageTexture``
on a large quad, 8 texels a cell); ``occluders`` is the scene file itself. The camera's
position is differentiated (x, y, z).

Printed per case: the reference (central differences of jittered renders, the same key
on both sides, spp ``--ref-spp``, averaged over ``--keys`` keys, at two steps, with
standard errors), plain AD and edge mode on the regular grid at each ``--spp``.
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
from raytrax.testing import jittered_central_differences, smooth_weights  # noqa: E402

SCENE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "edge_occluders.toml")
CASES = ("sphere", "box", "floor_sphere", "checker", "image", "occluders")


def case_scene(case: str):
    """The scene of ``case`` (see the module docstring), float64."""
    if case == "occluders":
        return rt.load_scene(SCENE, dtype=jnp.float64)
    file = rt.load_scene(SCENE, dtype=jnp.float64)
    st = file.settings
    b = rt.SceneBuilder(
        "classic",
        width=st.width,
        height=st.height,
        spp=64,
        max_depth=1,
        background=(0.2, 0.2, 0.25),
        ambient=(0.2, 0.2, 0.2),
    )
    b.camera(position=(0.5, 5.0, 5.5), look_at=(0.0, 0.3, 0.0), fov=38.0)  # the file's
    b.light((2.0, 5.0, 1.5), intensity=(0.7, 0.7, 0.7))
    b.material(
        "floor",
        color=(0.9, 0.9, 0.85),
        texture=rt.Checker(color2=(0.3, 0.35, 0.4), scale=1.3) if case == "checker" else None,
    )
    b.material("ball", color=(0.8, 0.3, 0.2))
    b.material("crate", color=(0.2, 0.5, 0.8))
    if case in ("floor_sphere", "checker"):
        b.plane((0, 0, 0), (0, 1, 0), "floor")
    if case == "image":
        # Cells of the checker's size (scale 1.3) over a 20 x 20 quad: 26 a side, 8 texels each.
        cells = (np.indices((26 * 8, 26 * 8)) // 8).sum(0) % 2
        texels = np.where(cells[..., None] == 1, (0.3, 0.35, 0.4), (1.0, 1.0, 1.0)) * np.asarray([0.9, 0.9, 0.85])
        b.material("board", color=(1.0, 1.0, 1.0), texture=rt.ImageTexture(texels))
        b.quad([(-10.0, 0.0, 10.0), (10.0, 0.0, 10.0), (10.0, 0.0, -10.0), (-10.0, 0.0, -10.0)], "board")
    if case in ("sphere", "floor_sphere"):
        b.sphere((-0.4, 0.9, 0.3), 0.55, "ball")
    if case == "box":
        b.box((0.6, 0.5, -0.9), (1.4, 1.2, -0.1), "crate", rotation=(0.0, 25.0, 0.0))
    return b.build(jnp.float64)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--spp", default="64,256,1024", help="regular grids of the AD and edge gradients")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--keys", type=int, default=16)
    ap.add_argument("--steps", default="0.025,0.05", help="central-difference steps (world units)")
    a = ap.parse_args()
    unknown = sorted(set(a.cases.split(",")) - set(CASES))
    if unknown:
        ap.error(f"--cases: unknown {', '.join(unknown)}; expected a comma-separated subset of {', '.join(CASES)}")
    name = "camera.position"
    for case in a.cases.split(","):
        sc = case_scene(case)
        st = sc.settings
        w = jnp.asarray(smooth_weights(st.height, st.width), jnp.float64)
        q0 = rt.parameters(sc)[name]

        def loss(q, spp, key=None, edge=False, sc=sc, w=w):
            image = rt.render(rt.with_parameters(sc, {name: q}), spp=spp, key=key, edge_gradients=edge)
            return jnp.mean(w * image)

        print(f"{case} ({st.width} x {st.height}), d loss / d {name} (x, y, z):", flush=True)
        for step in (float(s) for s in a.steps.split(",")):
            t0 = time.perf_counter()
            mean, se = jittered_central_differences(loss, q0, step, a.ref_spp, a.keys)
            cells = "  ".join(f"{m:+.6f} +- {s:.6f}" for m, s in zip(mean, se))
            print(f"  central differences, step {step}: {cells}  ({time.perf_counter() - t0:.0f} s)", flush=True)
        for spp in (int(s) for s in a.spp.split(",")):
            plain = jax.jit(jax.grad(lambda q, spp=spp, loss=loss: loss(q, spp)))(q0)
            edge = jax.grad(lambda q, spp=spp, loss=loss: loss(q, spp, edge=True))(q0)
            print(
                f"  spp {spp:5d}: plain {'  '.join(f'{float(v):+.6f}' for v in plain)}"
                f"   edge {'  '.join(f'{float(v):+.6f}' for v in edge)}",
                flush=True,
            )


if __name__ == "__main__":
    main()
