"""Figure helpers shared by the fitting examples (matplotlib, headless)."""

from __future__ import annotations

import os


def pyplot():
    """``matplotlib.pyplot`` with the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path):
    """Lay out, write ``path`` (PNG, 100 dpi) and close ``fig``; returns ``path``."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    pyplot().close(fig)
    return path


def image_grid(path, panels, rows=1, cell=(4.0, 3.6)):
    """Save ``panels``, a list of ``(title, linear RGB image)``, as a grid of ``rows``
    rows of sRGB images; returns ``path``."""
    from raytrax.imageio import to_display

    plt = pyplot()
    cols = -(-len(panels) // rows)
    fig, axes = plt.subplots(rows, cols, figsize=(cell[0] * cols, cell[1] * rows), squeeze=False)
    for ax, (title, img) in zip(axes.ravel(), panels):
        ax.imshow(to_display(img), interpolation="nearest")
        ax.set_title(title)
        ax.set_axis_off()
    return save(fig, path)
