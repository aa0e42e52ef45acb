"""raytrax ``physical`` shading against Mitsuba 3 restricted to the same light paths.

    python benchmarks/compare_mitsuba.py                    # 160 x 120, spp 16, depth 5
    python benchmarks/compare_mitsuba.py --high-spp 256     # also both at 256 spp
    python benchmarks/compare_mitsuba.py --isolate          # one object kind at a time
    python benchmarks/compare_mitsuba.py --extra            # glass meshes, back sides, TIR, ...

Prints PSNR (dB) and absolute differences for a simple scene (floor, diffuse
sphere, one light) and the physical benchmark scene (diffuse, mirror and glass
spheres, a rotated box, a tetrahedron, a floor, two lights), and writes
side-by-side PNGs to ``benchmarks/out/``.

PSNR is computed on the *linear* images clipped to [0, 1] with peak 1 (the scenes
are exposed so their brightest pixels are near 0.8), and also on the sRGB-encoded
images; both are stated. Mitsuba is rendered two ways (see
``benchmarks/mitsuba_scene.py``): ``grid``, at exactly raytrax's sub-pixel sample
positions (so any difference is a difference of models), and ``native``,
``mi.render`` with Mitsuba's jittered stratified sampler and box-filtered film
(differences then include Monte Carlo noise at edges; the ``native vs grid`` row
shows how much).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import jax  # noqa: E402
import mitsuba_scene as ms  # noqa: E402
import numpy as np  # noqa: E402

import raytrax as rt  # noqa: E402
import scenes  # noqa: E402


def metrics(a, b):
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    d = np.abs(a - b)
    return dict(
        psnr_lin=ms.psnr(np.clip(a, 0, 1), np.clip(b, 0, 1)),
        psnr_srgb=ms.psnr(ms.srgb(a), ms.srgb(b)),
        mad=float(d.mean()),
        max=float(d.max()),
        frac=float(np.mean(d.max(-1) > 0.01)),
    )


def row(name, m):
    return (
        f"  {name:<38s} {m['psnr_lin']:7.2f} {m['psnr_srgb']:8.2f}   {m['mad']:.2e}   {m['max']:.3f}"
        f"   {100 * m['frac']:6.2f}%"
    )


HEADER = "  comparison                             PSNR-lin PSNR-sRGB  mean|d|    max|d|  px|d|>.01"


def save_png(path, images, labels=None, scale=2):
    from PIL import Image

    tiles = []
    for im in images:
        if im.ndim == 2:
            im = np.repeat(im[:, :, None], 3, -1)
            tiles.append(np.clip(im, 0, 1))
        else:
            tiles.append(ms.srgb(im))
    sheet = np.concatenate(tiles, 1)
    img = Image.fromarray((sheet * 255 + 0.5).astype(np.uint8))
    img = img.resize((img.width * scale, img.height * scale), Image.NEAREST)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    img.save(path)


def render_rt(scene, **kw):
    t = time.perf_counter()
    img = np.asarray(jax.block_until_ready(rt.render(scene, **kw)))
    return img, time.perf_counter() - t


def compare(name, scene, args, full_tree=False):
    W, H, spp, depth = args.width, args.height, args.spp, args.depth
    print(f"\n== {name}: {W} x {H}, spp {spp}, max_depth {depth} ==")
    a, ta = render_rt(scene)
    m = ms.load(scene, sampler="stratified")
    t = time.perf_counter()
    g = ms.render_grid(m, W, H, spp)
    tg = time.perf_counter() - t
    t = time.perf_counter()
    n = ms.render_native(m, spp=spp, seed=args.seed)
    tn = time.perf_counter() - t
    print(f"  (first-call times incl. compilation: raytrax {ta:.1f} s, Mitsuba grid {tg:.1f} s, native {tn:.1f} s)")
    print(HEADER)
    res = {}
    res["rt_vs_grid"] = metrics(a, g)
    print(row("raytrax vs Mitsuba grid (same samples)", res["rt_vs_grid"]))
    res["rt_vs_native"] = metrics(a, n)
    print(row("raytrax vs Mitsuba native (stratified)", res["rt_vs_native"]))
    print(row("Mitsuba native vs grid (noise floor)", metrics(n, g)))
    full = None
    if full_tree:
        full, _ = render_rt(scene, branches=2**depth)
        res["rtfull_vs_grid"] = metrics(full, g)
        print(row(f"raytrax branches={2**depth} (full tree) vs grid", res["rtfull_vs_grid"]))
        print(row("raytrax branches=2 vs branches=full", metrics(a, full)))
    if args.high_spp:
        hs = args.high_spp
        ah, _ = render_rt(scene, spp=hs)
        nh = ms.render_native(ms.load(scene, spp=hs), spp=hs, seed=args.seed)
        res["high"] = metrics(ah, nh)
        print(row(f"raytrax vs Mitsuba native, spp {hs}", res["high"]))
    diff = np.abs(a - g).max(-1) * args.diff_gain
    path = os.path.join(args.out, f"compare_{name}.png")
    save_png(path, [a, g, n, diff])
    print(
        f"  wrote {os.path.relpath(path)}: raytrax | Mitsuba grid | Mitsuba native | "
        f"|raytrax - Mitsuba grid| x {args.diff_gain:g} (max over RGB)"
    )
    return res, a, g


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=120)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--high-spp", type=int, default=0, help="also compare both renderers at this spp (0: skip)")
    p.add_argument("--isolate", action="store_true", help="compare the floor plus one object kind at a time")
    p.add_argument(
        "--extra",
        action="store_true",
        help="compare small scenes that exercise the model's corners "
        "(glass meshes, mixtures, back sides, TIR...) at 96 x 72",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--diff-gain", type=float, default=10.0)
    p.add_argument("--variant", default=ms.DEFAULT_VARIANT)
    p.add_argument("--out", default=os.path.join(HERE, "out"))
    args = p.parse_args(argv)

    try:
        mi = ms.ensure_mitsuba(args.variant)
    except ms.MitsubaUnavailable as e:
        print(f"Mitsuba cannot start, no comparison made:\n  {e}")
        return 2
    print(
        f"raytrax {rt.__version__}, jax {jax.__version__} ({jax.default_backend()}), "
        f"Mitsuba {mi.__version__} ({mi.variant()}), {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs"
    )
    print(ms.HOW_THEY_DIFFER)

    W, H, spp, depth = args.width, args.height, args.spp, args.depth
    simple, _, _ = compare("simple", scenes.simple_scene(W, H, spp, depth), args)
    phys, _, _ = compare("physical", scenes.physical_scene(W, H, spp, depth), args, full_tree=True)

    if args.isolate:
        print(f"\n== physical scene, floor + one object kind (raytrax vs Mitsuba grid, {W} x {H}, spp {spp}) ==")
        print(HEADER)
        kinds = dict(diffuse=False, mirror=False, glass=False, box=False, tetra=False)
        for k in kinds:
            sc = scenes.physical_scene(W, H, spp, depth, **(kinds | {k: True}))
            a, _ = render_rt(sc)
            g = ms.render_grid(ms.load(sc), W, H, spp)
            print(row(f"floor + {k}", metrics(a, g)))
            save_png(os.path.join(args.out, f"isolate_{k}.png"), [a, g, np.abs(a - g).max(-1) * args.diff_gain])
        for li in (0, 1):
            sc = scenes.physical_scene(W, H, spp, depth, lights=(li,))
            a, _ = render_rt(sc)
            g = ms.render_grid(ms.load(sc), W, H, spp)
            print(row(f"all objects, light {li} only", metrics(a, g)))

    if args.extra:
        print(f"\n== extra scenes (raytrax vs Mitsuba grid, 96 x 72, spp {spp}, depth 6) ==")
        print(HEADER)
        for k, sc in scenes.extra_scenes(96, 72, spp, 6).items():
            a, _ = render_rt(sc)
            g = ms.render_grid(ms.load(sc), 96, 72, spp)
            print(row(k, metrics(a, g)))
            save_png(
                os.path.join(args.out, "extra_" + "".join(c if c.isalnum() else "_" for c in k) + ".png"),
                [a, g, np.abs(a - g).max(-1) * args.diff_gain],
                scale=3,
            )

    print("\n== summary (PSNR on linear images clipped to [0, 1], peak 1) ==")
    ok = simple["rt_vs_grid"]["psnr_lin"] > 40 and simple["rt_vs_native"]["psnr_lin"] > 40
    print(
        f"  simple scene:   {simple['rt_vs_grid']['psnr_lin']:.1f} dB (same samples), "
        f"{simple['rt_vs_native']['psnr_lin']:.1f} dB (Mitsuba stratified)  -> {'OK' if ok else 'FAIL'} (> 40 dB)"
    )
    print(
        f"  physical scene: {phys['rt_vs_grid']['psnr_lin']:.1f} dB (same samples), "
        f"{phys['rt_vs_native']['psnr_lin']:.1f} dB (Mitsuba stratified)"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
