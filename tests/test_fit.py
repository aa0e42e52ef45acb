"""raytrax.fit: the examples' fits at small size recover the truth, and fits that
cannot work fail with clear messages.

All fits here share two scene structures at one size (32 x 24), so each
compiled step (start check, Levenberg-Marquardt step, BFGS step) is compiled
once per structure and reused.
"""

from __future__ import annotations

import importlib.util
import pathlib
import warnings

import numpy as np
import pytest

import raytrax as rt

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"
W, H = 32, 24


def _load(name):
    spec = importlib.util.spec_from_file_location(f"_example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


lights = _load("fit_light_positions")
ior = _load("fit_refractive_index")


@pytest.mark.parametrize("solver, steps", [("levenberg_marquardt", 40), ("bfgs", 80)])
def test_light_positions_recovered(solver, steps):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # not converging would warn
        res, err = lights.run(W, H, steps=steps, solver=solver, verbose=False)
    assert res.converged, res.message
    # started ~2.9 units away; within 1% of the scene's size
    assert np.all(np.asarray(lights.errors(res.initial_params)) > 2.5)
    assert max(err) < 0.01 * lights.SCENE_SIZE, (err, res.message)
    assert res.loss_history[-1] < 1e-6 * res.loss_history[0]
    assert len(res.loss_history) == res.steps + 1 == len(res.param_history)
    fitted = rt.parameters(res.scene)
    for n in lights.NAMES:
        np.testing.assert_allclose(np.asarray(fitted[n]), res.params[n], atol=1e-5)


@pytest.mark.parametrize("solver, steps", [("levenberg_marquardt", 60), ("bfgs", 60)])
def test_refractive_index_recovered(solver, steps):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res, err = ior.run(W, H, steps=steps, solver=solver, verbose=False)
    assert res.converged, res.message
    assert float(res.initial_params[ior.NAME]) == pytest.approx(1.2)
    assert err < 1e-3, (float(res.params[ior.NAME]), res.message)


def test_target_of_another_size_is_refused():
    scene = lights.make_scene(W, H)
    target = np.zeros((18, 24, 3), np.float32)
    # names both shapes, and the render option that makes them agree
    with pytest.raises(ValueError, match=r"\(18, 24, 3\).*\(24, 32, 3\).*render_kwargs=dict\(width=24, height=18\)"):
        rt.fit(scene, target, lights.NAMES, progress=False)


def test_parameter_without_effect_is_refused():
    # light 1 below the floor lights nothing the camera sees: no gradient at all
    scene = lights.make_scene(W, H)
    target = rt.render(scene)
    start = lights.make_scene(W, H, lights=[lights.TRUE_LIGHTS[0], (2.5, -3.0, -1.0)])
    with pytest.raises(ValueError, match=r"light\[1\]\.position have no effect") as e:
        rt.fit(start, target, lights.NAMES, progress=False)
    assert "light[0].position" not in str(e.value)


def test_clear_errors_before_any_compilation():
    scene = ior.make_scene(W, H)
    target = np.zeros((H, W, 3), np.float32)
    with pytest.raises(ValueError, match="unknown parameter 'material.glass.iro'.*did you mean 'material.glass.ior'"):
        rt.fit(scene, target, ["material.glass.iro"], progress=False)
    with pytest.raises(ValueError, match="outside its bounds"):
        rt.fit(scene, target, {"material.glass.ior": 1.2}, bounds={"material.glass.ior": (1.3, 2.0)}, progress=False)
    bad = target.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        rt.fit(scene, bad, [ior.NAME], progress=False)
    with pytest.raises(ValueError, match="unknown solver"):
        rt.fit(scene, target, [ior.NAME], solver="levenberg", progress=False)
    with pytest.raises(ValueError, match="needs a minimiser"):
        rt.fit(scene, target, [ior.NAME], loss=lambda a, b: ((a - b) ** 2).sum(), progress=False)
    with pytest.raises(ValueError, match="every weight is zero"):
        rt.fit(scene, target, [ior.NAME], weights=np.zeros((H, W), bool), progress=False)
    with pytest.raises(ValueError, match="selector must return whole array leaves"):
        rt.fit(scene, target, lambda s: s.materials.ior[1], progress=False)


def test_selector_progress_and_step_budget(capsys):
    """A selector over the scene pytree, the per-step progress lines, and a fit
    that runs out of steps (warns, converged=False, best point returned)."""
    scene = lights.make_scene(W, H)
    target = rt.render(scene)
    start = lights.make_scene(W, H, lights=list(lights.start_positions().values()))
    res = rt.fit(start, target, lambda s: s.lights.position, max_steps=40, check=False)
    out = capsys.readouterr().out
    assert "step    0  loss" in out and "lights.position=" in out and "fit: converged" in out
    # Light positions move shadow edges: the fit says in one line that its gradient leaves them out.
    assert "rt.fit: plain AD gradients; the edges that lights.position move" in out
    assert list(res.params) == ["lights.position"]
    np.testing.assert_allclose(
        res.params["lights.position"], np.asarray(lights.TRUE_LIGHTS), atol=0.01 * lights.SCENE_SIZE
    )
    with pytest.warns(RuntimeWarning, match="did not converge within max_steps=3"):
        short = rt.fit(start, target, lambda s: s.lights.position, max_steps=3, progress="bar", check=False)
    assert not short.converged and short.steps == 3
    assert short.loss == min(short.loss_history)
