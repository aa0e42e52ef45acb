"""Edge events: a pair of neighbouring samples whose records differ, the chain they
share, and the edge function ``G(x)`` that separates them."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .. import vec as V
from ..branching import any_in_batch
from ..camera import rays_through
from .prims import Prims, first_t, miss, specular_step

MISS, DEPTH, SHADOW = 0, 1, 2


class Events(NamedTuple):
    typ: jax.Array  # (E,) MISS, DEPTH or SHADOW
    level: jax.Array  # (E,) chain level of the edge (0: seen directly)
    chain: jax.Array  # (D, E) primitives of the shared chain (levels < level are used)
    refr: jax.Array  # (D, E) the chain refracts (else reflects) at that level
    p1: jax.Array  # (E,) primitive missed (MISS), A (DEPTH), receiver (SHADOW)
    p2: jax.Array  # (E,) B (DEPTH), occluder (SHADOW)
    light: jax.Array  # (E,) light index (SHADOW)
    sign: jax.Array  # (E,) +-1: g = sign * G is <= 0 on the first sample's side


def chain_ray(scene, P: Prims, ns, ev: Events, xy, width, height, skip=True):
    """The ray at each event's chain level, for image positions ``xy (2, E)``.
    ``skip``: a level that no event of the batch reaches is skipped (a
    conditional); else every level is computed and selected."""
    o, d = rays_through(scene.camera, xy, width, height)
    if ev.chain.shape[0] <= 1:
        return o, d

    # One compiled level, scanned over the chain: its ray is materialised between
    # levels (unrolled, XLA:CPU fuses each level's ray into every use of it, and the
    # work grows geometrically with the depth). A level that no event of the batch
    # reaches is skipped (most edges are seen directly or through one or two
    # surfaces, where the chain has as many levels as the render's depth).
    def level(od, args):
        ids, refr, lv = args
        go = lv < ev.level

        def step(o, d):
            o2, d2, _ = specular_step(P, ns, ids, refr, o, d)
            return V.vsel(go, o2, o), V.vsel(go, d2, d)

        if not skip:
            return step(*od), None
        return jax.lax.cond(any_in_batch(go), step, lambda o, d: (o, d), *od), None

    lvs = jnp.arange(ev.chain.shape[0] - 1, dtype=ev.level.dtype)
    (o, d), _ = jax.lax.scan(level, (o, d), (ev.chain[:-1], ev.refr[:-1], lvs))
    return o, d


def edge_value(scene, P: Prims, ns, ev: Events, xy, width, height, feature=False, skip=True):
    """``G(x)`` of each event at image positions ``xy (2, E)`` (before ``sign``), and
    with ``feature=True`` also the feature of :func:`miss` (0 for depth crossings).
    ``skip``: as :func:`chain_ray`'s (pass ``False`` where ``G`` is differentiated:
    the conditional costs more to compile and transpose than the levels it skips)."""
    o, d = chain_ray(scene, P, ns, ev, xy, width, height, skip)
    ta = first_t(P, ns, ev.p1, o, d)
    tb = first_t(P, ns, ev.p2, o, d)
    if scene.n_lights:
        shadow = ev.typ == SHADOW
        p = o + ta[None] * d
        li = jnp.clip(ev.light, 0, P.light.shape[1] - 1)
        L = P.light[:, li]
        toward = V.vsel(P.ldir[li], V.normalize(-L), V.normalize(L - p))
        o2 = V.vsel(shadow, p, o)
        d2 = V.vsel(shadow, toward, d)
    else:  # no light, no shadow edge
        o2, d2 = o, d
    m, f = miss(P, ns, jnp.where(ev.typ == MISS, ev.p1, ev.p2), o2, d2)
    depth = ev.typ == DEPTH
    G = jnp.where(depth, ta - tb, m)
    return (G, jnp.where(depth, 0, f)) if feature else G
