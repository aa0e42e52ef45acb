"""Several views of one scene fitted at once: targets, cameras and weights, checked.

A fit with ``V`` views compares ``V`` renders (one per camera, all the size of
the render) with ``V`` targets. Inside, the views are stacked along the image
height into one ``(V * H, W, 3)`` image, so the residual, the loss, the
weights, the Jacobian and the standard errors are those of all views together
(one least-squares problem); blurring (the robust search's levels) stays
within each view.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..camera import Camera
from ._setup import _check_target_and_weights

_CAMERA_FIELDS = ("position", "look_at", "up", "fov")


def _as_camera(scene, cam, i, dtype):
    """The ``i``-th view's camera, checked: a :class:`raytrax.Camera`, or a dict of some
    of its fields (the others the scene's camera's); ``None`` stays ``None`` (the
    scene's own camera)."""
    base = scene.camera
    if cam is None:
        return None  # the scene's camera, fitted values included
    if isinstance(cam, Camera):
        vals = {f: np.asarray(getattr(cam, f), np.float64) for f in _CAMERA_FIELDS}
    elif isinstance(cam, dict):
        unknown = [k for k in cam if k not in _CAMERA_FIELDS]
        if unknown:
            raise ValueError(
                f"cameras[{i}]: unknown field(s) {unknown}; expected some of {list(_CAMERA_FIELDS)} "
                "(the others are the scene's camera's)"
            )
        vals = {f: np.asarray(cam.get(f, getattr(base, f)), np.float64) for f in _CAMERA_FIELDS}
    else:
        raise TypeError(
            f"cameras[{i}]: expected a raytrax.Camera, a dict of camera fields "
            f"(position, look_at, up, fov) or None (the scene's camera), got {type(cam).__name__}"
        )
    for f in _CAMERA_FIELDS:
        want = () if f == "fov" else (3,)
        if vals[f].shape != want:
            raise ValueError(f"cameras[{i}].{f}: expected shape {want}, got {vals[f].shape}")
        if not np.all(np.isfinite(vals[f])):
            raise ValueError(f"cameras[{i}].{f}: expected finite values, got {vals[f]}")
    fwd = vals["look_at"] - vals["position"]
    if not np.any(fwd != 0):
        raise ValueError(f"cameras[{i}].look_at: must differ from cameras[{i}].position")
    if np.linalg.norm(np.cross(fwd, vals["up"])) <= 1e-12 * np.linalg.norm(fwd) * np.linalg.norm(vals["up"]):
        raise ValueError(f"cameras[{i}].up: must not be parallel to the viewing direction")
    if not 0.0 < float(vals["fov"]) < 180.0:
        raise ValueError(f"cameras[{i}].fov: expected a field of view in (0, 180) degrees, got {float(vals['fov'])}")
    return Camera(*(jnp.asarray(vals[f], dtype) for f in _CAMERA_FIELDS))


def _resolve_views(scene, target, cameras, weights, names):
    """-> (targets, cameras, weights): lists of one entry per view, or ``cameras is None``
    for a plain one-image fit (``targets`` and ``weights`` then hold the one image
    and the ``weights`` argument)."""
    if isinstance(target, (list, tuple)):
        # a list of images (views), not one image written as nested lists
        many = not target or any(np.ndim(t) >= 3 for t in target)
    else:
        many = np.ndim(target) == 4
    if cameras is None and not many:
        return [target], None, [weights]
    if many:
        targets = list(target) if isinstance(target, (list, tuple)) else list(np.asarray(target))
    else:
        if not isinstance(cameras, (list, tuple)) or len(cameras) != 1:
            n = len(cameras) if isinstance(cameras, (list, tuple)) else "several"
            raise ValueError(
                f"target: one image for {n} cameras; pass a list of targets, one per camera "
                "(target=[image_0, image_1, ...])"
            )
        targets = [target]
    if not targets:
        raise ValueError("target: an empty list of views; expected one (H, W, 3) image per view")
    v = len(targets)
    if cameras is None:
        cams = [None] * v  # several images of the scene's own view
    elif not isinstance(cameras, (list, tuple)):
        raise TypeError(
            f"cameras: expected a list of one camera per target (raytrax.Camera, a dict of camera "
            f"fields, or None for the scene's camera), got {type(cameras).__name__}"
        )
    elif len(cameras) != v:
        raise ValueError(f"cameras: {len(cameras)} cameras for {v} targets; expected one camera per target")
    else:
        cams = list(cameras)
    if any(c is not None for c in cams):
        on_camera = [n for n in names if n == "camera" or n.startswith("camera.")]
        if on_camera:
            raise ValueError(
                f"params: {', '.join(on_camera)} cannot be fitted with cameras= (each view has its own "
                "camera); fit the scene's camera with one target, or leave cameras=None"
            )
    dtype = scene.dtype
    cams = [_as_camera(scene, c, i, dtype) for i, c in enumerate(cams)]
    if isinstance(weights, (list, tuple)):
        if len(weights) != v:
            raise ValueError(f"weights: {len(weights)} weight arrays for {v} targets; expected one per target")
        ws = list(weights)
    else:
        ws = [weights] * v
    return targets, cams, ws


def _stack_views(targets, weights, shape):
    """Check each view's target and weights against the render's ``shape`` (messages
    name the view: ``target[1]: ...``) and stack them along the height: -> NumPy
    ``(V * H, W, 3)`` target and weights (summing to 1)."""
    ts, ws = [], []
    for i, (t, w) in enumerate(zip(targets, weights)):
        t_a, w_a = _check_target_and_weights(t, w, shape, f"[{i}]")
        ts.append(t_a)
        ws.append(w_a)
    w = np.concatenate(ws, axis=0)
    return np.concatenate(ts, axis=0), w / w.sum()
