"""Record the golden reference (``tests/golden/golden.npz``) that ``tests/test_golden.py``
compares against: small float64 renders of every scene file in ``scenes/``, and plain and
edge-mode gradients of a smooth-weighted image mean with respect to every named parameter
of the edge scenes, at those files' own settings (``golden/cases.py``).

Run it only when an image or a gradient is *meant* to change, and say why in the commit:

    python tests/golden/make_golden.py
"""

from __future__ import annotations

import os
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
from golden.cases import compute_all  # noqa: E402

if __name__ == "__main__":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    out = pathlib.Path(__file__).with_name("golden.npz")
    arrays = compute_all()
    tmp = out.with_suffix(".tmp.npz")
    import numpy as np

    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, out)
    print(f"wrote {out} ({len(arrays)} arrays)")
