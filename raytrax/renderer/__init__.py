"""Rendering: the public :func:`render` and :func:`edge_pairs` (:mod:`~raytrax.renderer.api`), its options,
tiling and device sharding (:mod:`~raytrax.renderer.tiles`), the Whitted integrator
(:mod:`~raytrax.renderer.whitted`) with its dead-ray compaction
(:mod:`~raytrax.renderer.compaction`), and edge mode's glue
(:mod:`~raytrax.renderer.edge_mode`)."""

from .api import edge_pairs, render
from .options import RAYS_PER_TILE, SUBTILE, RenderOptions

__all__ = ["RAYS_PER_TILE", "SUBTILE", "RenderOptions", "edge_pairs", "render"]
