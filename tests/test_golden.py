"""Golden test: renders of every scene file and plain and edge-mode gradients of the
edge scenes (those tests/test_edges.py checks against finite differences), compared
with the recorded reference ``tests/golden/golden.npz``.

The reference was computed by this code base (``python tests/golden/make_golden.py``),
in float64; restructuring the code must not move any value by more than
``TOL`` times the largest magnitude of its array (float64 rounding, from XLA fusing
the same arithmetic differently). A deliberate change of an image or gradient
re-records the reference in its own commit.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
from golden import cases

TOL = 1e-12
REF = np.load(pathlib.Path(__file__).with_name("golden") / "golden.npz")


def _close(got, ref, what):
    assert got.shape == ref.shape, f"{what}: shape {got.shape} != {ref.shape}"
    scale = max(1.0, float(np.abs(ref).max()))
    err = float(np.abs(got - ref).max()) if ref.size else 0.0
    assert np.all(np.isfinite(got)), f"{what}: non-finite values"
    assert err <= TOL * scale, f"{what}: max abs difference {err:.3e} > {TOL * scale:.3e}"


@pytest.mark.parametrize("name", cases.SCENES)
def test_render_matches_golden(name):
    _close(cases.render_case(name), REF[f"render/{name}"], f"render/{name}")


@pytest.mark.xdist_group(cases.GROUP)  # its gradients are shared with tests/test_edges.py
@pytest.mark.parametrize("edge", [False, True], ids=["plain", "edge"])
@pytest.mark.parametrize("name", cases.EDGE_SCENES)
def test_gradient_matches_golden(name, edge):
    got = cases.gradient_case(name, edge)
    prefix = f"grad/{name}/{'edge' if edge else 'plain'}/"
    want = {k[len(prefix) :] for k in REF.files if k.startswith(prefix)}
    assert set(got) == want, f"parameter names changed: {sorted(set(got) ^ want)}"
    for k, v in got.items():
        _close(v, REF[prefix + k], prefix + k)
