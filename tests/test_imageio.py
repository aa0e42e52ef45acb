"""Image I/O through OpenImageIO: EXR/PNG/JPEG round trips, sRGB, atomic writes, errors."""

from __future__ import annotations

import os

import numpy as np
import pytest

import raytrax as rt
from raytrax import imageio as io


@pytest.fixture(scope="module")
def img():
    rng = np.random.default_rng(7)
    a = rng.random((9, 13, 3)).astype(np.float32)
    a[0, 0] = [0.0, 1e-4, 0.0031308]  # around the linear segment of sRGB
    a[0, 1] = [1.0, 0.5, 0.04045]
    return a


def test_api_exports():
    assert rt.save_image is io.save_image and rt.load_image is io.load_image


def test_srgb_closed_form():
    x = np.linspace(0.0, 1.0, 1001)
    expected = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(io.linear_to_srgb(x), expected, rtol=0, atol=1e-15)
    y = np.linspace(0.0, 1.0, 1001)
    expected = np.where(y <= 0.04045, y / 12.92, ((y + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(io.srgb_to_linear(y), expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(io.srgb_to_linear(io.linear_to_srgb(x)), x, atol=1e-12)
    # Known values: mid grey and the ends.
    assert io.linear_to_srgb(0.0) == 0.0 and abs(io.linear_to_srgb(1.0) - 1.0) < 1e-12
    assert abs(io.linear_to_srgb(0.214041140) - 0.5) < 1e-6


def test_exr_exact_roundtrip_with_metadata(tmp_path, img):
    hdr = img * 10.0 - 1.0  # negative and > 1 values survive in EXR
    p = tmp_path / "a.exr"
    io.save_image(p, hdr, metadata=dict(scene="cosc363", spp=4, max_depth=5, render_time_s=1.25))
    back = io.load_image(p)
    assert back.dtype == np.float32 and back.shape == hdr.shape
    np.testing.assert_array_equal(back, hdr)
    meta = io.load_image_metadata(p)
    assert meta["scene"] == "cosc363" and meta["spp"] == 4 and meta["max_depth"] == 5
    assert meta["render_time_s"] == pytest.approx(1.25)


def test_exr_half(tmp_path, img):
    p = tmp_path / "h.exr"
    io.save_image(p, img, bits=16)
    np.testing.assert_allclose(io.load_image(p), img, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("bits", [8, 16])
def test_png_roundtrip_within_quantisation(tmp_path, img, bits):
    p = tmp_path / f"a{bits}.png"
    io.save_image(p, img, bits=bits, metadata=dict(scene="x"))
    back = io.load_image(p)
    assert back.dtype == np.float32 and back.shape == img.shape
    q = 2**bits - 1
    # In the encoded domain the error is at most half a quantisation step.
    err = np.abs(io.linear_to_srgb(back) - io.linear_to_srgb(img)).max()
    assert err <= 0.5 / q + 1e-6
    # The stored integers are exactly our own sRGB encoding (no colour management on top).
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(p))
    raw = inp.read_image(0, 0, 0, 3, oiio.UINT8 if bits == 8 else oiio.UINT16)
    inp.close()
    np.testing.assert_array_equal(raw, np.round(io.linear_to_srgb(img) * q).astype(raw.dtype))
    assert io.load_image_metadata(p)["scene"] == "x"


def test_png_clips(tmp_path):
    a = np.array([[[-1.0, 2.0, 0.0]]], dtype=np.float32)
    p = tmp_path / "c.png"
    io.save_image(p, a)
    np.testing.assert_array_equal(io.load_image(p), [[[0.0, 1.0, 0.0]]])


@pytest.mark.parametrize("ext", [".png", ".exr", ".jpg"])
def test_non_finite_pixels_are_refused(tmp_path, img, ext):
    # Never silently black (or white): a clear error naming the file and the count.
    p = tmp_path / f"n{ext}"
    with pytest.raises(
        ValueError, match=rf"n\{ext}: 117 of 117 pixels are not finite \(NaN values; the first at row 0"
    ):
        io.save_image(p, np.full_like(img, np.nan))
    some = img.copy()
    some[2, 3, 1] = np.nan
    some[4, 5] = np.inf
    some[4, 6, 0] = -np.inf
    with pytest.raises(
        io.ImageError,
        match=r"3 of 117 pixels are not finite \(NaN and infinite values; the first at row 2, column 3\); nothing written",
    ):
        io.save_image(p, some)
    with pytest.raises(io.ImageError, match="1 of 1 pixels"):
        io.save_image(p, np.array([[np.nan]], np.float32))  # grey
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int64])
def test_integer_images_are_refused(tmp_path, dtype):
    # Integers are not taken for linear values (uint8 255 would be 255 times white).
    a = np.full((4, 5, 3), 128, dtype)
    p = tmp_path / "i.png"
    with pytest.raises(
        ValueError, match=rf"i\.png: expected an image of linear float values, got dtype {np.dtype(dtype)}"
    ):
        io.save_image(p, a)
    assert os.listdir(tmp_path) == []
    # The way the message says: 8-bit display values through srgb_to_linear.
    io.save_image(p, io.srgb_to_linear(np.full((4, 5, 3), 128, np.uint8) / 255))
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(p))
    raw = inp.read_image(0, 0, 0, 3, oiio.UINT8)
    inp.close()
    assert (raw == 128).all()


def test_jpeg_and_grey(tmp_path):
    grey = np.full((8, 8), 0.2, np.float32)
    p = tmp_path / "g.jpg"
    io.save_image(p, grey)
    back = io.load_image(p)
    assert back.shape == (8, 8, 3)
    np.testing.assert_allclose(back, 0.2, atol=0.01)


def test_jax_array_input(tmp_path):
    import jax.numpy as jnp

    p = tmp_path / "j.exr"
    io.save_image(p, jnp.ones((2, 3, 3), jnp.float32))
    np.testing.assert_array_equal(io.load_image(p), np.ones((2, 3, 3), np.float32))


def test_errors(tmp_path, img):
    with pytest.raises(
        io.ImageError,
        match=r"x\.bmp: cannot write images of type '\.bmp'; expected one of "
        r"\.exr, \.png, \.jpg, \.jpeg",
    ):
        io.save_image(tmp_path / "x.bmp", img)
    with pytest.raises(io.ImageError, match=r"cannot write images of type '\(no extension\)'"):
        io.save_image(tmp_path / "noext", img)
    with pytest.raises(io.ImageError, match=r"bits: expected one of \(8,\) for \.jpg files, got 16"):
        io.save_image(tmp_path / "x.jpg", img, bits=16)
    with pytest.raises(io.ImageError, match=r"expected an \(H, W, 3\) or \(H, W\) image, got shape \(2, 2, 4\)"):
        io.save_image(tmp_path / "x.png", np.zeros((2, 2, 4)))
    with pytest.raises(FileNotFoundError, match=r"folder .*nope does not exist"):
        io.save_image(tmp_path / "nope" / "x.png", img)
    with pytest.raises(FileNotFoundError, match=r"missing\.png: image file not found"):
        io.load_image(tmp_path / "missing.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"this is not a png")
    with pytest.raises(OSError, match=r"bad\.png: cannot read image"):
        io.load_image(bad)
    with pytest.raises(IsADirectoryError, match="found a folder"):
        io.load_image(tmp_path)
    assert sorted(os.listdir(tmp_path)) == ["bad.png"]  # nothing half-written


def test_atomic_write_leaves_nothing_on_failure(tmp_path, img, monkeypatch):
    target = tmp_path / "out.png"
    io.save_image(target, img)
    before = target.read_bytes()

    import OpenImageIO as oiio

    real = oiio.ImageOutput.create

    class Boom:
        def __init__(self, out):
            self.out = out

        def open(self, *a):
            return self.out.open(*a)

        def write_image(self, *a):
            raise KeyboardInterrupt

    monkeypatch.setattr(oiio.ImageOutput, "create", staticmethod(lambda name: Boom(real(name))))
    with pytest.raises(KeyboardInterrupt):
        io.save_image(target, img * 0.5)
    assert os.listdir(tmp_path) == ["out.png"]  # no temporary file left behind
    assert target.read_bytes() == before  # and the old file is untouched


def test_show_returns_axes(img):
    import matplotlib

    matplotlib.use("Agg")
    ax = io.show(img, title="t")
    assert ax.get_title() == "t"
    import matplotlib.pyplot as plt

    plt.close("all")


def test_before_rename_can_abandon_the_write(tmp_path, img):
    target = tmp_path / "out.exr"
    target.write_bytes(b"old")
    seen = []

    def stop():
        seen.append(sorted(os.listdir(tmp_path)))  # the complete temporary file is there
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        io.save_image(target, img, before_rename=stop)
    assert len(seen) == 1 and len(seen[0]) == 2 and seen[0][0].startswith(".out.exr.")
    assert os.listdir(tmp_path) == ["out.exr"] and target.read_bytes() == b"old"
    io.save_image(target, img, before_rename=lambda: None)
    np.testing.assert_array_equal(io.load_image(target), img)
