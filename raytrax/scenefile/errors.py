"""The one error type of scene files and descriptions."""

from __future__ import annotations


class SceneError(ValueError):
    """A scene file (or a scene description) is invalid; the message says where and why."""


# LIMITS (upper bounds beyond which a value is rejected as absurd), the defaults and
# the value ranges live in raytrax.limits, shared with SceneBuilder; LIMITS is the
# same dict object, so changing an entry here changes it for the builder too.
