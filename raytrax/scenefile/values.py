"""Readers of TOML values with key-path messages (``expected ..., got ...``), shared by the
parser; the limits and ranges themselves live in :mod:`raytrax.limits`."""

from __future__ import annotations

import difflib
import math

from .. import limits as L

# -----------------------------------------------------------------------------
# Validation helpers
# -----------------------------------------------------------------------------


class KeyProblem(Exception):
    """Internal: a problem at a key path; turned into a SceneError with the file name."""

    def __init__(self, path: str, msg: str):
        super().__init__(path, msg)
        self.path = path
        self.msg = msg


quote_key = L.toml_key  # a table key as a key path writes it (quoted unless bare)


def join(path: str, key: str) -> str:
    return f"{path}.{quote_key(key)}" if path else quote_key(key)


show = L.show_value  # how a found value is described in messages


def is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def num(v, path, *, lo=None, hi=None, lo_open=False, hi_open=False, what="a number") -> float:
    """A finite number (in ``[lo, hi]``, ends open as told), else a KeyProblem
    "expected ``what``, got ...". See :func:`in_range` for the shared ranges."""
    if not is_num(v):
        raise KeyProblem(path, f"expected {what}, got {show(v)}")
    x = float(v)
    if not math.isfinite(x):
        raise KeyProblem(path, f"expected a finite number, got {v!r}")
    if lo is not None and (x < lo or (lo_open and x == lo)) or hi is not None and (x > hi or (hi_open and x == hi)):
        raise KeyProblem(path, f"expected {what}, got {v!r}")
    return x


def in_range(v, path, rng: L.Range) -> float:
    """A number in the shared range ``rng`` (:mod:`raytrax.limits`)."""
    return num(v, path, lo=rng.lo, hi=rng.hi, lo_open=rng.lo_open, hi_open=rng.hi_open, what=rng.what)


def integer(v, path, *, lo=None, hi=None, what="an integer") -> int:
    if not isinstance(v, int) or isinstance(v, bool):
        raise KeyProblem(path, f"expected {what}, got {show(v)}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise KeyProblem(path, f"expected {what}, got {v}")
    return v


def vec(v, path, n=3, what=None) -> tuple:
    what = what or f"an array of {n} numbers"
    if not isinstance(v, list):
        raise KeyProblem(path, f"expected {what}, got {show(v)}")
    if len(v) != n:
        raise KeyProblem(path, f"expected {what}, got {show(v)}")
    return tuple(num(x, f"{path}[{i}]") for i, x in enumerate(v))


def rgb(v, path, rng: L.Range = L.RGB_NON_NEGATIVE) -> tuple:
    """An RGB triple: ``[r, g, b]`` or one number for grey, each in ``rng``
    (non-negative unless told; see :mod:`raytrax.limits`)."""
    if is_num(v):
        x = num(v, path)
        c = (x, x, x)
    elif isinstance(v, list) and len(v) == 3:
        c = tuple(num(x, f"{path}[{i}]") for i, x in enumerate(v))
    else:
        raise KeyProblem(path, f"expected {L.rgb_what(rng)}, got {show(v)}")
    msg = L.rgb_problem(c, rng, v if is_num(v) else None)
    if msg:
        raise KeyProblem(path, msg)
    return c


def matrix(v, path, rows, what):
    if not isinstance(v, list) or len(v) != rows:
        raise KeyProblem(path, f"expected {what}, got {show(v)}")
    return tuple(vec(r, f"{path}[{i}]") for i, r in enumerate(v))


def table(v, path, what=None) -> dict:
    if not isinstance(v, dict):
        raise KeyProblem(path, f"expected {what or 'a table'}, got {show(v)}")
    return v


def check_keys(table: dict, path: str, allowed, required=(), context: str = ""):
    allowed = list(allowed)
    for k in table:
        if k not in allowed:
            near = difflib.get_close_matches(k, allowed, n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            ctx = f"{context} takes" if context else "expected one of"
            raise KeyProblem(join(path, k) if path else quote_key(k), f"unknown key{hint}; {ctx}: {', '.join(allowed)}")
    for k in required:
        if k not in table:
            ctx = f" ({context} needs {', '.join(required)})" if context else ""
            raise KeyProblem(path or "(top level)", f"missing key {k!r}{ctx}")


def article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def did_you_mean(value: str, options) -> str:
    near = difflib.get_close_matches(value, list(options), n=1, cutoff=0.6)
    return f" (did you mean {near[0]!r}?)" if near else ""


def got(v) -> str:
    return repr(v) if isinstance(v, str) else show(v)
