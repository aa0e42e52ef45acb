"""Progress of a fit: a line per step or a tqdm bar, and the number formatting they share."""

from __future__ import annotations

import sys

import numpy as np


def _fmt(v, n=6):
    """A short text for a parameter value (a summary for arrays of more than ``n`` numbers)."""
    a = np.asarray(v)
    if a.size > n:
        return f"<{a.shape} array, mean {a.mean():.4g}>"
    if a.ndim == 0:
        return f"{float(a):.5g}"
    return "[" + " ".join(f"{float(x):.4g}" for x in a.ravel()) + "]"


class _Reporter:
    """Reports a fit's steps: a line per step (``progress=True``), a tqdm bar (``"bar"``) or nothing."""

    def __init__(self, progress, max_steps, names, stream=None):
        self.mode = progress
        self.bar = None
        self.stream = stream or sys.stdout
        if progress == "bar":
            from tqdm.auto import tqdm

            self.bar = tqdm(total=max_steps, desc="fit", unit="step", leave=True)

    def __call__(self, step, loss, values, extra=""):
        if not self.mode:
            return
        if self.bar is not None:
            if step > 0:
                self.bar.update(1)
            self.bar.set_postfix_str(f"loss={loss:.4g}")
            return
        vals = "  ".join(f"{n}={_fmt(v)}" for n, v in values.items())
        print(f"step {step:4d}  loss {loss:.6g}  {vals}{extra}", file=self.stream, flush=True)

    def close(self, message):
        if self.bar is not None:
            self.bar.close()
        if self.mode:
            print(f"fit: {message}", file=self.stream, flush=True)
