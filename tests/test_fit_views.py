"""raytrax.fit with several views of one scene (``target=[...]``, ``cameras=[...]``):
one least-squares problem over all views, standard errors from all of them.

Two diffuse balls side by side, lit by one point light; camera 1 sees only
ball ``a`` (albedo fitted), camera 2 only ball ``b`` (albedo known). From
camera 1 the light's intensity and ``a``'s albedo act only through their
product: undetermined. Camera 2 pins the intensity, and with it the albedo.
The "one view" fit is two exposures of camera 1 (the scene's own camera), so
both fits compare 2 x 16 x 12 pixels (1 sample each).
"""

from __future__ import annotations

import numpy as np
import pytest

import raytrax as rt

CAM1 = dict(position=(-1.5, 0.0, 4.0), look_at=(-1.5, 0.0, 0.0))
CAM2 = dict(position=(1.5, 0.0, 4.0), look_at=(1.5, 0.0, 0.0))
POS, INT, COL = "light[0].position", "light[0].intensity", "material.a.color"
TRUTH = {POS: (0.0, 3.0, 3.0), INT: (20.0, 20.0, 20.0), COL: (0.6, 0.5, 0.4)}
START = {POS: (1.0, 2.0, 4.0), INT: (12.0, 14.0, 16.0), COL: (0.3, 0.3, 0.3)}
SIGMA = 0.01  # the noise level the standard errors are computed for


def _scene(camera=CAM1):
    b = rt.SceneBuilder("physical", width=16, height=12, spp=1, max_depth=1)
    b.camera(fov=30, **camera)
    b.light(TRUTH[POS], intensity=TRUTH[INT])
    b.material("a", color=TRUTH[COL])
    b.material("b", color=(0.5, 0.5, 0.5))
    b.sphere((-1.5, 0.0, 0.0), 0.8, "a")
    b.sphere((1.5, 0.0, 0.0), 0.8, "b")
    return b.build()


@pytest.fixture(scope="module")
def views():
    scene = _scene()
    return scene, np.asarray(rt.render(scene)), np.asarray(rt.render(_scene(CAM2)))


def test_second_view_determines_what_one_view_cannot(views):
    scene, img1, img2 = views
    with pytest.warns(RuntimeWarning, match=r"does not determine.*light\[0\]\.intensity.*material\.a\.color"):
        # two exposures of the scene's own view (camera 1): still one view's information
        one = rt.fit(scene, [img1, img1], START, noise=SIGMA, max_steps=30, progress=False)
    assert np.all(np.isinf(one.stderr[INT])) and np.all(np.isinf(one.stderr[COL]))
    assert len(one.undetermined) == 3  # one direction per colour channel

    two = rt.fit(scene, [img1, img2], START, cameras=[None, CAM2], noise=SIGMA, max_steps=30, progress=False)
    assert two.converged, two.message
    assert two.undetermined == []
    for name in (POS, INT, COL):
        np.testing.assert_allclose(two.params[name], TRUTH[name], rtol=1e-3, atol=1e-4, err_msg=name)
        assert np.all(np.isfinite(two.stderr[name])) and np.all(two.stderr[name] > 0), name
    # the light's position, determined by either, is pinned better by two views than by
    # camera 1's pixels counted twice (the same number of pixels)
    assert np.all(two.stderr[POS] < 0.7 * one.stderr[POS]), (two.stderr[POS], one.stderr[POS])
    assert two.covariance is not None and two.covariance.shape == (9, 9)
    # the result's scene keeps its own camera
    np.testing.assert_array_equal(np.asarray(two.scene.camera.position), np.asarray(scene.camera.position))


def test_view_arguments_are_checked(views):
    scene, img1, img2 = views
    fit = dict(params=[INT], progress=False)
    with pytest.raises(ValueError, match=r"cameras: 3 cameras for 2 targets"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, CAM2, CAM1], **fit)
    with pytest.raises(ValueError, match=r"target: one image for 2 cameras; pass a list of targets"):
        rt.fit(scene, img1, cameras=[CAM1, CAM2], **fit)
    with pytest.raises(ValueError, match=r"target\[1\]: shape \(6, 8, 3\) does not match .* \(12, 16, 3\)"):
        rt.fit(scene, [img1, img2[::2, ::2]], cameras=[CAM1, CAM2], **fit)
    with pytest.raises(ValueError, match=r"target\[0\]: contains 1 non-finite"):
        bad = img1.copy()
        bad[0, 0, 0] = np.nan
        rt.fit(scene, [bad, img2], cameras=[CAM1, CAM2], **fit)
    with pytest.raises(ValueError, match=r"target: an empty list of views"):
        rt.fit(scene, [], **fit)
    with pytest.raises(TypeError, match=r"cameras\[1\]: expected a raytrax.Camera, a dict"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, (1.5, 0, 4)], **fit)
    with pytest.raises(ValueError, match=r"cameras\[1\]: unknown field\(s\) \['pos'\]"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, dict(pos=(1, 0, 4))], **fit)
    with pytest.raises(ValueError, match=r"cameras\[0\]\.position: expected shape \(3,\)"):
        rt.fit(scene, [img1, img2], cameras=[dict(position=(1, 0)), CAM2], **fit)
    with pytest.raises(ValueError, match=r"cameras\[1\]\.look_at: must differ"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, dict(position=(0, 0, 0), look_at=(0, 0, 0))], **fit)
    with pytest.raises(ValueError, match=r"weights: 1 weight arrays for 2 targets"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, CAM2], weights=[np.ones((12, 16))], **fit)
    with pytest.raises(ValueError, match=r"weights\[1\]: shape \(3, 3\) does not fit"):
        rt.fit(scene, [img1, img2], cameras=[CAM1, CAM2], weights=[None, np.ones((3, 3))], **fit)
    with pytest.raises(ValueError, match=r"camera\.fov cannot be fitted with cameras="):
        rt.fit(scene, [img1, img2], ["camera.fov"], cameras=[CAM1, CAM2], progress=False)
