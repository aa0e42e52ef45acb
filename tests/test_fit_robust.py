"""raytrax.fit from far away (the robust default with bounds: several starts,
coarse-to-fine) and its standard errors.

Small images (24 x 18) and few compilations: the glass scene's Levenberg-
Marquardt step (sharp and blurred), the light intensity's step, and one
Jacobian of a tiny degenerate scene.
"""

from __future__ import annotations

import importlib.util
import pathlib
import warnings

import numpy as np
import pytest

import raytrax as rt

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"
W, H, SPP = 24, 18, 4


def _load(name):
    spec = importlib.util.spec_from_file_location(f"_example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


glass = _load("fit_glass_over_geometry")
NAME = glass.NAME


@pytest.fixture(scope="module")
def glass_target():
    return rt.render(glass.make_scene(W, H, glass.TRUE_IOR, SPP))


def test_far_start_missed_by_local_fit_recovered_by_default(glass_target):
    start = glass.make_scene(W, H, 1.30, SPP)
    bounds = {NAME: (1.2, 1.9)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        plain = rt.fit(start, glass_target, [NAME], bounds=bounds, starts=1, levels=[0], max_steps=10, progress=False)
    assert abs(float(plain.params[NAME]) - 1.5) > 0.1  # a local fit stays in the wrong valley
    assert plain.starts == []
    res = rt.fit(start, glass_target, [NAME], bounds=bounds, max_steps=10, start_steps=8, progress=False)
    assert abs(float(res.params[NAME]) - 1.5) < 1e-3, res.message
    # every start reported, the given one first; the kept one has the lowest loss
    assert len(res.starts) == 8
    assert float(res.starts[0]["start"][NAME]) == pytest.approx(1.30)
    starts = sorted(float(s["start"][NAME]) for s in res.starts)
    assert starts[0] >= 1.2 and starts[-1] <= 1.9 and np.ptp(starts) > 0.5  # spread over the bounds
    assert "best of 8 starts" in res.message
    assert res.stderr is not None and np.all(np.isfinite(res.stderr[NAME]))


def _ball():
    """A diffuse ball lit by one point light, 16 x 12, one sample per pixel."""
    b = rt.SceneBuilder("physical", width=16, height=12, spp=1, max_depth=1)
    b.camera(position=(0, 0, 4), look_at=(0, 0, 0), fov=40)
    b.light((2.0, 3.0, 4.0), intensity=(20, 20, 20))
    b.material("m", color=(0.6, 0.5, 0.4))
    b.sphere((0, 0, 0), 1.0, "m")
    return b.build()


def test_stderr_matches_spread_over_noisy_targets():
    """Fits of a light's intensity to 12 targets with Gaussian noise of known sigma:
    the mean reported standard error (noise estimated from the residual) matches
    the sample standard deviation of the fitted values within a factor 1.5."""
    name = "light[0].intensity"
    scene = _ball()
    clean = np.asarray(rt.render(scene))
    sigma = 0.02
    rng = np.random.default_rng(1)
    start = rt.with_parameters(scene, {name: np.array([22.0, 18.0, 21.0])})
    fitted, errs, noise = [], [], []
    for _ in range(12):
        target = clean + rng.normal(0.0, sigma, clean.shape).astype(np.float32)
        res = rt.fit(start, target, [name], max_steps=10, progress=False, check=False)
        fitted.append(res.params[name])
        errs.append(res.stderr[name])
        noise.append(res.noise)
    spread = np.std(np.asarray(fitted), axis=0, ddof=1)
    reported = np.mean(np.asarray(errs), axis=0)
    ratio = np.sqrt(np.mean(reported**2) / np.mean(spread**2))
    assert 1 / 1.5 < ratio < 1.5, (reported, spread)
    assert np.mean(noise) == pytest.approx(sigma, rel=0.1)  # sqrt(RSS / (n - p))
    assert res.covariance is not None and res.covariance.shape == (3, 3)
    assert res.covariance_labels == tuple(f"{name}[{i}]" for i in range(3))
    np.testing.assert_allclose(np.sqrt(np.diag(res.covariance)), res.stderr[name], rtol=1e-6)
    # a given noise level is used as is
    given = rt.fit(start, target, [name], max_steps=10, progress=False, check=False, noise=2 * sigma)
    assert given.noise == 2 * sigma
    np.testing.assert_allclose(given.stderr[name], 2 * sigma / res.noise * res.stderr[name], rtol=1e-2)


def test_undetermined_direction_warns_naming_parameters():
    """A light's intensity against the albedo of the only material: the image is
    their product, so J^T J is singular; the warning names both."""
    scene = _ball()
    target = rt.render(scene)
    names = ["light[0].intensity", "material.m.color"]
    with pytest.warns(RuntimeWarning, match=r"does not determine.*light\[0\]\.intensity\[0\].*material\.m\.color\[0\]"):
        res = rt.fit(scene, target, names, progress=False, check=False)
    assert len(res.undetermined) == 3  # one direction per channel
    assert np.all(np.isinf(res.stderr["material.m.color"]))


def test_search_arguments_are_checked():
    scene = glass.make_scene(W, H, 1.3, SPP)
    target = np.zeros((H, W, 3), np.float32)
    with pytest.raises(ValueError, match="no fitted parameter has both a lower and an upper bound"):
        rt.fit(scene, target, [NAME], starts=3, progress=False, check=False)
    with pytest.raises(ValueError, match="starts: expected a positive integer"):
        rt.fit(scene, target, [NAME], starts=0, progress=False)
    with pytest.raises(ValueError, match="levels: expected non-negative"):
        rt.fit(scene, target, [NAME], levels=[-1.0], progress=False)
    with pytest.raises(ValueError, match="noise: expected a positive"):
        rt.fit(scene, target, [NAME], noise=0.0, progress=False)
