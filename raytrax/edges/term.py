"""The boundary term: finding edge crossings between neighbouring samples,
classifying and locating them, cutting edge pieces, measuring jumps, and the
silhouette quadrature (the method is described in :mod:`raytrax.edges`)."""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import vec as V
from ..branching import any_in_batch, run_or_zeros
from ..chunks import equal_chunks, map_chunks, map_worklist
from ..intersect import prepare
from ..masks import any_true, count_true, pack_map, prefix_count, true_indices
from ..tracing import join_live, split_live, zero_batched_as
from .events import DEPTH, MISS, SHADOW, Events, edge_value
from .prims import Prims, build_prims, split_ids
from .records import face_group, object_key, pack_records, packed_rows, records, unpack_records, widen

BISECTION_STEPS = 14  # edge point between two samples: 2^-14 of their spacing
END_STEPS = 8  # end of an edge piece inside its strip: 2^-8 of the spacing
NEWTON_STEPS = 3  # following an edge to the neighbouring row
CHUNK = 512  # events solved per step of the (skippable) chunk loop
QUAD_SAMPLES = 2  # inside samples of a sphere's silhouette row replaced by a quadrature
QUAD_NODES = 6  # its Gauss-Legendre nodes in sqrt(distance)
IMAGE_CHUNK = 1024  # crossings per chunk of the boundary term (:func:`edge_image`)


@dataclasses.dataclass(frozen=True)
class EdgeOptions:
    """Static options of the boundary term: ``samples`` per pixel side (``n``),
    ``budget``, the most sample pairs with an edge between them (``None``:
    :func:`default_budget`; rounded up to whole chunks, it also bounds the pairs
    whose records differ at all), ``depth``, the chain levels
    followed (the render's ``max_depth + 1``), and ``devices``, over how many of
    ``jax.devices()`` the grid's records and the events are split."""

    samples: int = 4
    budget: int | None = None
    depth: int = 1
    devices: int = 1


def default_budget(samples: int, n: int) -> int:
    """The default ``edge_budget`` of ``samples`` grid samples, ``n`` per pixel side: a
    quarter of the samples, at least 4096 and, beyond 65536, at most the larger of
    65536 and ``samples / (2 n)``. The pairs with an edge between them grow with the
    edges' length in sample spacings (``n`` per pixel), not with the image's area, so
    a large grid needs a smaller share."""
    return max(4096, min(samples // 4, max(1 << 16, samples // (2 * n))))


def _pair_samples(pair, S, Gw):
    """The two samples (flat grid indices) of sample pairs ``pair`` and whether the
    pair is horizontal, on a grid of ``S`` samples in rows of ``Gw``. Pairs are numbered
    as the flat grid's neighbours: first ``p, p + 1`` for ``p < S - 1`` (horizontal; the
    numbers ``p`` at the end of a row are not pairs), then ``q, q + Gw`` for
    ``q = p - (S - 1) < S - Gw`` (vertical)."""
    horiz = pair < S - 1
    a = jnp.where(horiz, pair, pair - (S - 1))
    return a, a + jnp.where(horiz, 1, Gw), horiz


def at_level(x, level):
    """``x (D, E)`` at each event's ``level (E,)``."""
    return jnp.take_along_axis(x, level[None], 0)[0]


def _pieces(p0, p1, width, height):
    """Split the segments ``p0 -> p1 (2, E)`` at pixel boundaries (at most one per
    axis): pixel ids ``(3, E)`` and length fractions ``(3, E)`` of the three pieces."""

    def cross(c0, c1):
        has = jnp.floor(c0) != jnp.floor(c1)
        tau = V.safe_div(jnp.floor(jnp.maximum(c0, c1)) - c0, c1 - c0)
        return jnp.where(has, jnp.clip(tau, 0.0, 1.0), 1.0)

    cx, cy = cross(p0[0], p1[0]), cross(p0[1], p1[1])
    taus = [jnp.zeros_like(cx), jnp.minimum(cx, cy), jnp.maximum(cx, cy), jnp.ones_like(cx)]
    pix, wts = [], []
    for j in range(3):
        pix.append(_pixel_of(p0 + (0.5 * (taus[j] + taus[j + 1]))[None] * (p1 - p0), width, height))
        wts.append(taus[j + 1] - taus[j])
    return jnp.stack(pix), jnp.stack(wts)


def _meet_at_angle(P: Prims, ns, a, b):
    """Whether primitives ``a`` and ``b (E,)`` are both polygons whose planes are not
    parallel (so that where one's edge lies on the other, the two meet there)."""
    if not P.pn.shape[1]:  # no polygon
        return jnp.zeros(a.shape, bool)
    is_a, _, pa = split_ids(P, ns, a)
    is_b, _, pb = split_ids(P, ns, b)
    cos = jnp.abs(jnp.sum(P.pn[:, pa] * P.pn[:, pb], 0))
    return ~is_a & ~is_b & (cos < 1.0 - 1e-6)


def _pixel_of(x, width, height):
    """Row-major pixel id ``(E,)`` of image positions ``x (2, E)`` (clipped to the image)."""
    px = jnp.clip(jnp.floor(x[0]).astype(jnp.int32), 0, width - 1)
    py = jnp.clip(jnp.floor(x[1]).astype(jnp.int32), 0, height - 1)
    return py * width + px


def find_edges(scene, width, height, eo: EdgeOptions, radiance_at, check: bool = True):
    """The edge crossings of the sample grid and what :func:`edge_image` needs to
    turn them into the boundary term (steps 1-5 of :mod:`raytrax.edges`, none of
    which is differentiated: ``scene`` is used without gradient); a budget that holds
    this grid's edges (the larger of the number of edge crossings and the number of
    sample pairs whose records differ at all; while the budget used holds them, no
    budget below the crossings does; past it, at least what is needed); whether
    the budget used is exceeded (with ``check``, the default, that is a runtime
    error raised inside the program, on every device of a sharded finder; without,
    the caller checks this flag); and the silhouette quadrature's rays
    (step 6), or ``None`` in a scene without spheres. The crossings are a dict of
    ``K = budget`` (rounded up to whole chunks) entries: ``events``
    (:class:`~raytrax.edges.Events`), edge points ``xs (2, K)``, ``ok (K,)``, the
    coefficients ``coef (3, K)`` of ``g``, and the pixels ``pix (3, K)`` and length
    fractions ``wts (3, K)`` of each crossing's piece. Kept apart from
    :func:`edge_image` so that, called outside ``jax.jit``, the two compile as
    separate programs (XLA:CPU's compile time grows faster than the program).

    ``radiance_at(xy (2, M), light (M,), need (M,)) -> (M, 3)``: radiance of camera
    rays through image positions ``xy`` (per ray, that light's contribution alone,
    or everything at index ``L``), treated as a constant; only the rays ``need``
    marks must be traced (the others may be zero). The
    jump ``f_minus - f_plus`` is measured by probe rays just on either side of the
    edge point (``1/256`` of the sample spacing away for visibility edges, 0.03
    pixel for shadow edges), where the probes see the same as the two samples
    (else the crossing adds nothing).

    The quadrature is returned, not evaluated, so that the caller traces its rays
    with the sample grid's in one differentiable pass: a dict of (no gradient)
    ``xy (2, K, Q)`` image positions (the crossings with a non-zero weight first),
    ``w (K, Q)`` weights and ``pixel (K,)`` flat pixel indices; its contribution
    to the image is ``sum_q w f(xy)`` added at ``pixel``, minus its own value.
    """
    n = eo.samples
    D = eo.depth
    Gw, Gh = width * n, height * n
    S = Gw * Gh
    h = 1.0 / n
    sg = jax.lax.stop_gradient(scene)
    kinds = prepare(sg)
    P_sg, off = build_prims(sg)
    ns = off["ns"]

    def rec_at(x, devices=1, compact=False):
        return records(sg, kinds, off, P_sg, x, width, height, D, devices, compact)

    dt = scene.dtype
    jj, ii = jnp.meshgrid(jnp.arange(Gw), jnp.arange(Gh), indexing="xy")
    xy = jnp.stack([(jj.ravel().astype(dt) + 0.5) / n, (ii.ravel().astype(dt) + 0.5) / n])
    # The grid's records are compact (int16 ids where they fit): compared as they are,
    # widened to int32 where gathered for the packed pairs and events.
    with jax.named_scope("edge_records"):
        R = rec_at(xy, eo.devices, compact=True)
    L = R.first.shape[1]
    npairs = Gh * (Gw - 1) + (Gh - 1) * Gw

    def okey(g):
        return object_key(P_sg, ns, g)

    nslot = 1 + 4 * L
    budget = eo.budget if eo.budget is not None else default_budget(S, n)
    budget = min(budget, npairs * nslot)
    nc, C = equal_chunks(budget, CHUNK, eo.devices)
    K = nc * C
    # The pairs whose two samples' records differ anywhere (a hit, a branch or an
    # occluder at any level), packed at the front: a few per cent of the pairs
    # (those that straddle an edge). One pass over the grid's records; the rest of
    # the pairing runs on at most Kp packed pairs, not on every pair of the grid.
    # On the flat grid (rows of samples, one after the other): each sample against
    # the next (horizontal pairs, but for a row's last sample) and against the one a
    # row below (vertical pairs).
    differ_h = jnp.zeros((S - 1,), bool)
    differ_v = jnp.zeros((S - Gw,), bool)
    for x in (R.hit, R.refr, R.first, R.last):
        g = x.reshape((-1, S))
        for r in range(g.shape[0]):
            differ_h = differ_h | (g[r, :-1] != g[r, 1:])
            differ_v = differ_v | (g[r, :-Gw] != g[r, Gw:])
    differ_h = differ_h & (jnp.arange(S - 1, dtype=jnp.int32) % Gw != Gw - 1)
    differ = jnp.concatenate([differ_h, differ_v])
    Kp = min(K, npairs)
    cand, _, n_differ = pack_map(differ, Kp, dtype=jnp.int32)  # pair numbers (_pair_samples' order)
    ca, cb, ch = _pair_samples(cand, S, Gw)
    valid = jnp.arange(Kp, dtype=jnp.int32) < n_differ

    def sides(x):  # (..., S) -> (..., Kp) at the first and at the second sample of each pair
        return widen(x[..., ca]), widen(x[..., cb])

    ha, hb = sides(R.hit)
    ra, rb = sides(R.refr)
    same_r = ra == rb
    fa_all, fb_all = sides(R.first)  # (D, L, Kp)
    la_all, lb_all = sides(R.last)
    # Visibility: the first chain level whose hits differ, after a common prefix.
    pre = valid
    vis_act = jnp.zeros((Kp,), bool)
    lv = jnp.zeros((Kp,), jnp.int32)
    for lvl in range(D):
        other = ha[lvl] != hb[lvl]
        new = pre & other
        vis_act = vis_act | new
        lv = jnp.where(new, lvl, lv)
        pre = pre & ~other & same_r[lvl]
    act = [vis_act]
    # Shadows: per light, the first level (same hit, common prefix) whose shadow
    # records differ; slots for light k, candidate occluder j (last / first occluder
    # of either sample's shadow segment), each distinct occluding object once.
    ls = []
    for k in range(L):
        pre = valid
        found = jnp.zeros((Kp,), bool)
        lk = jnp.zeros((Kp,), jnp.int32)
        for lvl in range(D):
            eqh = ha[lvl] == hb[lvl]
            dif = (
                pre
                & eqh
                & (ha[lvl] >= 0)
                & ~found
                & ((fa_all[lvl, k] != fb_all[lvl, k]) | (la_all[lvl, k] != lb_all[lvl, k]))
            )
            lk = jnp.where(dif, lvl, lk)
            found = found | dif
            pre = pre & eqh & same_r[lvl]
        ls.append(lk)
        recv = okey(at_level(ha, lk))
        cands = [
            at_level(la_all[:, k], lk),
            at_level(fa_all[:, k], lk),
            at_level(lb_all[:, k], lk),
            at_level(fb_all[:, k], lk),
        ]
        keys = [okey(c) for c in cands]
        # A mesh is one occluder: its shadow's edge is its outline seen from the light,
        # which the faces next to it share (a closed mesh's front and back faces).
        # Another face of a mesh already taken is skipped where that one changes
        # between the two samples (then it is the one whose edge is crossed).
        groups = [face_group(off, c)[0] for c in cands]
        changes = [cands[0] != cands[2], cands[1] != cands[3], cands[2] != cands[0], cands[3] != cands[1]]
        mine = []
        for j in range(4):
            new = found & (cands[j] >= 0) & (keys[j] != recv)
            for i in range(j):
                new = new & (keys[j] != keys[i]) & ~(mine[i] & changes[i] & (groups[j] == groups[i]))
            mine.append(new)
        act += mine
    act = jnp.stack(act, 1)  # (Kp, nslot)
    per_pair = jnp.sum(act, 1, dtype=jnp.int32)
    count = count_true(act)
    # Events in pair-major order, compacted in two steps (the pairs with an event,
    # then their slots).
    has = per_pair > 0
    p_idx, _, n_has = pack_map(has, K)
    sub = act[p_idx] & (jnp.arange(K) < n_has.astype(p_idx.dtype))[:, None]
    flat = true_indices(sub.ravel(), K)
    flat = flat.astype(jnp.int32)
    live = jnp.arange(K) < count
    pair = p_idx.astype(jnp.int32)[flat // nslot]  # among the packed pairs
    slot = flat % nslot
    ea, eb, eh = ca[pair], cb[pair], ch[pair]
    vis = slot == 0
    k_ev = jnp.maximum(slot - 1, 0) // 4
    j_ev = jnp.maximum(slot - 1, 0) % 4
    if L:
        level = jnp.where(vis, lv[pair], jnp.stack(ls)[k_ev, pair])
    else:
        level = lv[pair]
    chain, refr = widen(R.hit[:, ea]), R.refr[:, ea]
    A = at_level(chain, level)
    B = widen(R.hit[level, eb])
    if L:
        fa, la = widen(R.first[level, k_ev, ea]), widen(R.last[level, k_ev, ea])
        fb, lb = widen(R.first[level, k_ev, eb]), widen(R.last[level, k_ev, eb])
        occ = jnp.where(j_ev == 0, la, jnp.where(j_ev == 1, fa, jnp.where(j_ev == 2, lb, fb)))
    else:
        fa = la = fb = lb = occ = jnp.zeros_like(A)
    inputs = {
        "live": live,
        "vis": vis,
        "level": level,
        "chain": chain,
        "refr": refr,
        "A": A,
        "B": B,
        "occ": occ,
        "k": k_ev,
        "fa": fa,
        "la": la,
        "fb": fb,
        "lb": lb,
        "xa": xy[:, ea],
        "xb": xy[:, eb],
        "eh": eh,
        "ea": ea,
        "eb": eb,
        "far": jnp.full_like(ea, -1),
    }

    def solve(c, R):
        """Everything about one chunk of ``C`` events that needs no gradient (``R``:
        the grid's records)."""
        zeros = jnp.zeros_like(c["A"])
        A, B, xa, xb, eh, vis = c["A"], c["B"], c["xa"], c["xb"], c["eh"], c["vis"]

        def mk(typ, p1, p2, sign):
            return Events(typ, c["level"], c["chain"], c["refr"], p1, p2, c["k"], sign)

        def cat(*evs):
            return Events(*(jnp.concatenate(f, -1) for f in zip(*evs)))

        def G(ev, x, feature=False):
            return edge_value(sg, P_sg, ns, ev, x, width, height, feature)

        # One loop, one compiled copy of G on E positions per step: steps 0-5 classify
        # every event (which edge function separates the two samples? is the occluder
        # hit by one shadow segment and missed by the other?), the next steps bisect
        # for the edge point between the two samples, and the last evaluates t_A - t_B
        # there (``vals[n_cls]``), which tells a contact from a silhouette (classify).
        ev_d = mk(zeros + DEPTH, A, B, zeros)
        ev_s = mk(zeros + SHADOW, A, c["occ"], zeros)
        evs = [mk(zeros + MISS, A, B, zeros), mk(zeros + MISS, B, A, zeros), ev_d, ev_d, ev_s, ev_s]
        n_cls = len(evs)
        ev_cls = Events(*(jnp.stack(f) for f in zip(*evs)))
        x_cls = jnp.stack([xb, xa, xa, xb, xa, xb])

        def classify(vals, final=False):
            mAb, mBa = vals[0], vals[1]
            case1 = (A >= 0) & (mAb > 0)
            case2 = ~case1 & (B >= 0) & (mBa > 0)
            # Depth crossings: t_A - t_B changes sign between the samples (two surfaces
            # crossing, or a crease of a convex solid).
            up = (vals[2] <= 0) & (vals[3] >= 0)
            down = (vals[2] >= 0) & (vals[3] <= 0)
            cross = (A >= 0) & (B >= 0) & (up | down)
            if final:
                # A contact: a polygon's silhouette edge lies on the other polygon's
                # plane, which it meets at an angle (a box resting on the floor): at
                # the located edge point t_A - t_B vanishes too (within 1/256 of its
                # change between the samples). Lifting the solid reveals what lies
                # under it, which neither sample sees; sinking it only moves the line
                # where the two meet. The crossing is taken as the depth crossing,
                # which gives the sinking side's derivative. (Parallel faces, such as
                # the tops of two boxes side by side, never meet: their edge stays a
                # silhouette; so does a sphere's, whose depth beside the silhouette is
                # not a crossing.)
                at_edge = jnp.abs(vals[n_cls]) <= jnp.abs(vals[3] - vals[2]) / 256.0
                contact = (case1 | case2) & cross & at_edge & _meet_at_angle(P_sg, ns, A, B)
                owner_b = case2  # whose silhouette the edge is (a contact's too)
                case1 = case1 & ~contact
                case2 = case2 & ~contact
            case3 = ~case1 & ~case2 & cross
            typ_v = jnp.where(case1 | case2, MISS, DEPTH)
            ok_v = case1 | case2 | case3
            ma, mb = vals[4], vals[5]
            ok_s = (c["occ"] >= 0) & ((ma <= 0) != (mb <= 0))
            ev = mk(
                jnp.where(vis, typ_v, SHADOW),
                jnp.where(vis, jnp.where(case2, B, A), A),
                jnp.where(vis, B, c["occ"]),
                jnp.where(vis, jnp.where(case2 | (case3 & ~up), -1, 1), jnp.where(ma <= 0, 1, -1)),
            )
            ok = c["live"] & jnp.where(vis, ok_v, ok_s)
            # The silhouettes (a contact's too) and whose they are (the second
            # sample's side: owner_b).
            silh = vis & ((typ_v == MISS) | contact) if final else vis & (typ_v == MISS)
            return ev, ok, case2, owner_b if final else case2, silh

        last = n_cls + BISECTION_STEPS

        def step(i, st):
            vals, lo, hi = st
            fin = i == last
            cls = i < n_cls
            keep = cls | fin  # the steps that store G in ``vals`` (the others bisect)
            j = jnp.where(fin, n_cls, jnp.minimum(i, n_cls - 1))  # the slot written
            ev_b = classify(vals)[0]
            k = jnp.where(fin, 2, j)  # the event evaluated (2: the depth event)
            ev_i = Events(*(jnp.where(keep, fc[k], fb) for fc, fb in zip(ev_cls, ev_b)))
            mid = 0.5 * (lo + hi)
            gv = G(ev_i, jnp.where(cls, x_cls[jnp.minimum(j, n_cls - 1)], xa + mid[None] * (xb - xa)))
            neg = ev_b.sign.astype(dt) * gv <= 0  # pyright: ignore
            vals = vals.at[j].set(jnp.where(keep, gv, vals[j]))  # pyright: ignore
            return vals, jnp.where(~keep & neg, mid, lo), jnp.where(~keep & ~neg, mid, hi)

        with jax.named_scope("edge_locate"):
            vals, lo, hi = jax.lax.fori_loop(
                0,
                last + 1,
                step,
                (jnp.zeros((n_cls + 1,) + A.shape, dt), jnp.zeros(A.shape, dt), jnp.ones(A.shape, dt)),
            )
        ev, ok, case2, owner_b, silh = classify(vals, final=True)
        sgn = ev.sign.astype(dt)
        ev2 = cat(ev, ev)
        sgn2 = jnp.concatenate([sgn, sgn])

        def g2(x):
            return sgn2 * G(ev2, x)

        # Both copies of each bracket: the second is differentiated along y below, and
        # below the two copies follow the edge to either side.
        lo, hi = jnp.concatenate([lo, lo]), jnp.concatenate([hi, hi])
        xa2, xb2 = jnp.concatenate([xa, xa], 1), jnp.concatenate([xb, xb], 1)
        xs2 = xa2 + (0.5 * (lo + hi))[None] * (xb2 - xa2)
        tang = jnp.concatenate([jnp.zeros_like(xa).at[0].set(1.0), jnp.zeros_like(xa).at[1].set(1.0)], 1)
        _, gxy = jax.jvp(g2, (xs2,), (tang,))
        E = A.shape[0]
        gx, gy = gxy[:E], gxy[E:]
        xs = xs2[:, :E]
        den = jnp.abs(gx) + jnp.abs(gy)
        ok = ok & (den > 0) & jnp.isfinite(den)
        ga = jnp.where(eh, gx, gy)  # along the pair
        gc = jnp.where(eh, gy, gx)  # across
        # The jump, measured on either side of the edge point. Probes sit 1/256 of the
        # sample spacing from a visibility edge (camera rays are exact there). The
        # renderer offsets shadow rays from the surface (by 1e-4 of the scene's scale),
        # which moves its shadow edges by ~1e-3 pixel; shadow probes keep 0.03 pixel
        # (at most 0.45 of the spacing) from the edge, on both sides of that edge.
        frac = jnp.where(vis, 1.0 / 256.0, jnp.maximum(1.0 / 256.0, jnp.minimum(0.45, 0.03 * n)))
        u = (xb - xa) * frac[None]
        # A sphere's silhouette: the radiance beside it is f_s + a sqrt(distance); the
        # inside probe is extrapolated to the edge with ``a``, fitted from it and two
        # more rays 1/16 and 1/4 of the spacing inside (phi h: the first inside
        # sample's distance from the edge; step 6 of the module docstring).
        sil = vis & (ev.typ == MISS) & (ev.p1 < ns) & (c["far"] < 0)
        in_b = case2  # the sphere is on the second sample's side
        t_s = 0.5 * (lo[:E] + hi[:E])
        phi = jnp.clip(jnp.where(in_b, 1.0 - t_s, t_s), 1e-6, 1.0)
        step_in = jnp.where(in_b[None], xb - xa, xa - xb)
        inner = jnp.concatenate([xs + step_in / 16.0, xs + step_in / 4.0], 1)

        # The piece of edge this crossing stands for: up to the neighbouring rows
        # (columns) on either side, cut where the edge ends or what lies on either
        # side of it changes (records at the edge, beside it, differ from the probes').
        # One loop: step 0 takes the records beside the edge point itself (the
        # probes') and its feature, step 1 looks a whole row (column) away on either
        # side, the remaining steps bisect for the end where that failed.
        along = jnp.stack([eh, ~eh]).astype(dt)
        across = 1.0 - along
        tdir = across - V.safe_div(gc, ga)[None] * along  # the edge's direction per unit across

        def dup(x):
            return jnp.concatenate([x, x], -1)

        sided = jnp.concatenate([-jnp.ones_like(sgn), jnp.ones_like(sgn)]) * h
        # A silhouette's far side: the side of the first crossing of its chain where
        # its primitive is not (the near side may show a third primitive first).
        # A mesh's shadow: its edge is located face by face from the side in the shadow
        # (``inside``: the first sample's side) to the lit side (the far side).
        inside_a = ev.sign > 0
        mesh_sh = ~vis & face_group(off, c["occ"])[1]
        far_e = jnp.where(silh, jnp.where(c["far"] >= 0, c["far"], jnp.where(owner_b, 0, 1)), -1)
        far_e = jnp.where(mesh_sh, jnp.where(c["far"] >= 0, c["far"], jnp.where(inside_a, 1, 0)), far_e)

        # Per side (2E: each event's piece before and after its edge point), gathered
        # in batches of ``m`` sides: steps 0 and 1 run on every side, the bisection
        # (steps 2...) only on the sides where step 1 failed, packed at the front.
        side = {
            "x": dup(xs),
            "t": dup(tdir),
            "u": dup(u),
            "a": dup(along),
            "ga": dup(ga),
            "s": sgn2,
            "ev": ev2,
            "lv": dup(c["level"]),
            "k": dup(c["k"]),
            "vis": dup(vis),
            "ea": dup(c["ea"]),
            "eb": dup(c["eb"]),
            "far": dup(far_e),
        }
        m = max(1, E // 4)
        okd = dup(ok)
        nfull = -(-(2 * E) // m)
        n0 = -(-E // m)  # step 0's batches: both sides of an event start at its edge point

        def follow(sd, mid):
            """Follow the edge from ``x + mid t`` along the pair direction (chord-Newton
            steps in one loop); returns the last point evaluated, whether ``g`` vanishes
            there, its feature, and the records just beside it (minus, plus)."""
            a, ga = sd["a"], sd["ga"]

            def newton(_, st):
                x, _, _, _ = st
                gv, f = G(sd["ev"], x, feature=True)
                gv = sd["s"] * gv
                return x - V.safe_div(gv, ga)[None] * a, x, jnp.abs(gv) <= 0.05 * h * jnp.abs(ga), f

            z = jnp.zeros(ga.shape, bool)
            x0 = sd["x"] + mid[None] * sd["t"]
            _, x1, conv, f = jax.lax.fori_loop(0, NEWTON_STEPS + 1, newton, (x0, x0, z, jnp.zeros(ga.shape, jnp.int32)))
            r = rec_at(jnp.concatenate([x1 - sd["u"], x1 + sd["u"]], 1))  # minus side, plus side
            return x1, conv, f, r

        def seen(sd, x, r):
            """Does the pair of grid samples around ``x`` (a point of the edge on a
            sample row or column) see the same on either side as the probes there
            (records ``r``)? If not (it straddles another edge too), that row has no
            crossing of this edge, and the rows beside it cover its piece."""
            a = sd["a"]
            k = x.shape[1]
            t = x * n - 0.5  # grid coordinates
            ca = jnp.floor(jnp.where(a > 0, t, jnp.round(t))).astype(jnp.int32)
            inside = (
                (ca[0] >= 0)
                & (ca[1] >= 0)
                & (ca[0] + a[0].astype(jnp.int32) < Gw)
                & (ca[1] + a[1].astype(jnp.int32) < Gh)
            )
            ia = jnp.clip(ca[1], 0, Gh - 1) * Gw + jnp.clip(ca[0], 0, Gw - 1)
            ib = jnp.clip(ia + jnp.where(a[0] > 0, 1, Gw), 0, S - 1)
            at = jax.tree_util.tree_map(lambda v: widen(v[..., jnp.concatenate([ia, ib])]), R)
            og = jax.tree_util.tree_map(lambda v: widen(v[..., jnp.concatenate([sd["ea"], sd["eb"]])]), R)
            # Compared with the event's own pair of grid samples on what makes this
            # event: the chain prefix, the hit at its level and, for a shadow edge, its
            # light's occluders there.
            lv2 = jnp.tile(sd["lv"], 2)
            same = jnp.ones(lv2.shape, bool)
            pre = jnp.ones(lv2.shape, bool)
            for q in range(D):
                pre = pre & ((q >= lv2) | ((at.hit[q] == og.hit[q]) & (at.refr[q] == og.refr[q])))
            hit_at = at_level(at.hit, lv2)
            same = pre & (hit_at == at_level(og.hit, lv2))
            if L:
                k2, ar = jnp.tile(sd["k"], 2), jnp.arange(2 * k)
                same = same & (
                    jnp.tile(sd["vis"], 2)
                    | (
                        (at.first[lv2, k2, ar] == og.first[lv2, k2, ar])
                        & (at.last[lv2, k2, ar] == og.last[lv2, k2, ar])
                    )
                )
            far = sd["far"]
            # A crossing found beyond a third primitive (far >= 0): the neighbouring
            # pair finds it too where it sees the same beyond the edge (its far sample)
            # and something else on the near side.
            same_far = jnp.where(far == 0, same[:k], same[k:])
            differs = hit_at[:k] != hit_at[k:]
            if L:
                occ_k = [(at.first[lv2, k2, ar][i], at.last[lv2, k2, ar][i]) for i in (slice(0, k), slice(k, None))]
                sh_differs = ~differs & ((occ_k[0][0] != occ_k[1][0]) | (occ_k[0][1] != occ_k[1][1]))
                differs = jnp.where(sd["vis"], differs, sh_differs)
            sec_ok = same_far & differs & pre[:k] & pre[k:]
            return ~inside | jnp.where(far >= 0, sec_ok, same[:k] & same[k:])

        nr = packed_rows(D, L)

        def rows(a):
            """The integer state ``(3 + 2 nr, ..)`` as its rows: full, lost, feature,
            and the packed records on the minus and on the plus side."""
            return a[0], a[1], a[2], a[3 : 3 + nr], a[3 + nr :]

        def item(i, st):
            """Work item ``i``: step 0 on batch ``i`` of the first ``E`` sides (``i < n0``;
            both sides of an event start from the records and feature at its edge point),
            step 1 on batch ``i - n0`` of all sides (``i < n0 + nfull``), then bisection
            step ``j % END_STEPS`` on batch ``j // END_STEPS`` (``j = i - n0 - nfull``) of
            the sides that still need it. The state
            of every side is two arrays, ``(2, 2E)`` floats (the bracket ``lo, hi``)
            and ``(2E, 3 + 2 nr)`` integers (per side, ``full``, ``lost``, the feature, and
            the packed records beside the edge point on the minus and the plus side: a
            side's integers are one row, so that a batch is read and written as rows),
            each read and written as one gather and one scatter."""
            fl, it, order, cnt = st
            first = i < n0 + nfull
            j = i - n0 - nfull
            step = jnp.where(i < n0, 0, jnp.where(first, 1, 2 + j % END_STEPS))
            b = jnp.where(i < n0, i, jnp.where(first, i - n0, j // END_STEPS))

            def sides_to_bisect():
                # After step 1 (which alone writes ``full`` and ``lost``): the sides whose
                # piece ends inside its strip, packed. A crossing that adds nothing
                # needs no piece.
                full_s, lost_s, _, _, _ = rows(it.T)
                need = ~((full_s != 0) | (lost_s != 0)) & okd
                src, _, cnt = pack_map(need, 2 * E)
                return src, cnt.astype(src.dtype)

            order, cnt = jax.lax.cond(i == n0 + nfull, sides_to_bisect, lambda: (order, cnt))
            pos = b * m + jnp.arange(m)
            idx = jnp.where(first, jnp.minimum(pos, 2 * E - 1), order[jnp.minimum(pos, 2 * E - 1)])
            valid = jnp.where(step == 0, pos < E, jnp.where(first, pos < 2 * E, pos < cnt))

            def run(st):
                fl, it = st
                sd = jax.tree_util.tree_map(lambda v: v[..., idx], side)
                col_f, col_i = fl[:, idx], it[idx].T
                lo_i, hi_i = col_f[0], col_f[1]
                full_i, lost_i, feat_i, old_m, old_p = rows(col_i)
                mid = jnp.where(step == 0, 0.0, jnp.where(step == 1, hi_i, 0.5 * (lo_i + hi_i)))
                x, conv, f, r = follow(sd, mid)
                pr = pack_records(r)
                rm, rp = pr[:, :m], pr[:, m:]
                f_ref = jnp.where(step == 0, f, feat_i)
                v = conv & (f == f_ref) & jnp.all(rm == old_m, 0) & jnp.all(rp == old_p, 0)
                nb = seen(sd, x, r)
                s0, s1, sb = step == 0, step == 1, step > 1
                new_i = jnp.concatenate(
                    [
                        jnp.stack(
                            [
                                jnp.where(s1, (v & nb).astype(jnp.int32), full_i),
                                jnp.where(s1, (v & ~nb).astype(jnp.int32), lost_i),
                                jnp.where(s0, f, feat_i),
                            ]
                        ),
                        jnp.where(s0, rm, old_m),
                        jnp.where(s0, rp, old_p),
                    ]
                )
                new_f = jnp.stack([jnp.where(sb & v, mid, lo_i), jnp.where(sb & ~v, mid, hi_i)])
                # Only the batch's real slots are written (padding slots are dropped);
                # step 0's integer state goes to both sides of its events (each side
                # keeps its own bracket).
                wi = jnp.where(valid, idx, 2 * E)
                wi2 = jnp.concatenate([wi, jnp.where(valid & s0, idx + E, 2 * E)])
                return fl.at[:, wi].set(new_f, mode="drop"), it.at[wi2].set(
                    jnp.concatenate([new_i, new_i], 1).T, mode="drop"
                )

            fl, it = jax.lax.cond(any_true(valid), run, lambda st: st, (fl, it))
            return fl, it, order, cnt

        with jax.named_scope("edge_follow"):
            fl, it, _, _ = jax.lax.fori_loop(
                0,
                n0 + nfull + END_STEPS * nfull,
                item,
                (
                    jnp.stack([jnp.zeros_like(sided), sided]),
                    jnp.zeros((2 * E, 3 + 2 * nr), jnp.int32),
                    jnp.zeros((2 * E,), int),  # jax's default integer, as pack_map's src
                    jnp.zeros((), int),
                ),
            )
        lo, hi = fl[0], fl[1]
        full_s, lost_s, _, pk_m, pk_p = rows(it.T)
        full, lost = full_s != 0, lost_s != 0
        r_m, r_p = unpack_records(pk_m[:, :E], D, L), unpack_records(pk_p[:, :E], D, L)
        lvl = c["level"]
        pre_m = pre_p = jnp.ones_like(ok)
        for q in range(D):
            before = q < lvl
            pre_m = pre_m & (~before | ((r_m.hit[q] == c["chain"][q]) & (r_m.refr[q] == c["refr"][q])))
            pre_p = pre_p & (~before | ((r_p.hit[q] == c["chain"][q]) & (r_p.refr[q] == c["refr"][q])))
        hm, hp = at_level(r_m.hit, lvl), at_level(r_p.hit, lvl)
        strict = (hm == A) & jnp.where(vis, hp == B, hp == A)
        # Beside a primitive's own silhouette the other side may show a third
        # primitive (a mesh's face seen edge-on between a crease and the outline):
        # the jump there is measured as it is, and the crossing beyond it is located
        # as a new event (``spawn``, run by a later chunk of the same loop), between
        # that probe and the far sample.
        relaxed = jnp.where(owner_b, (hp == B) & (hm != B), (hm == A) & (hp != A))
        jump_ok = pre_m & pre_p & jnp.where(silh, relaxed, strict)
        if L:
            ar = jnp.arange(E)
            sh = (
                (r_m.first[lvl, c["k"], ar] == c["fa"])
                & (r_m.last[lvl, c["k"], ar] == c["la"])
                & (r_p.first[lvl, c["k"], ar] == c["fb"])
                & (r_p.last[lvl, c["k"], ar] == c["lb"])
            )
            occ = c["occ"]
            rf = [r_m.first[lvl, c["k"], ar], r_p.first[lvl, c["k"], ar]]
            rl = [r_m.last[lvl, c["k"], ar], r_p.last[lvl, c["k"], ar]]
            f_in, l_in = jnp.where(inside_a, rf[0], rf[1]), jnp.where(inside_a, rl[0], rl[1])
            f_out, l_out = jnp.where(inside_a, rf[1], rf[0]), jnp.where(inside_a, rl[1], rl[0])
            # A mesh face's edge: the probe inside its shadow has it as an occluder, the
            # other not (it may still be in the shadow of the mesh's next face, whose
            # edge is located next, between that probe and the far sample).
            relaxed_s = (hm == A) & (hp == A) & ((f_in == occ) | (l_in == occ)) & (f_out != occ) & (l_out != occ)
            jump_ok = jump_ok & (vis | sh | (mesh_sh & relaxed_s))
            f_far, l_far = jnp.where(inside_a, c["fb"], c["fa"]), jnp.where(inside_a, c["lb"], c["la"])
            grp = face_group(off, occ)[0]
            nxt_l = (l_out != l_far) & (l_out >= 0) & (face_group(off, l_out)[0] == grp)
            nxt_f = (f_out != f_far) & (f_out >= 0) & (face_group(off, f_out)[0] == grp)
            sec_s = mesh_sh & ok & jump_ok & (nxt_l | nxt_f)
            occ2 = jnp.where(nxt_l, l_out, f_out)
        else:
            sec_s = jnp.zeros_like(vis)
            occ2 = f_out = l_out = c["occ"]
        # The probes (minus and plus side) and, beside a sphere's silhouette, the two
        # inner rays: traced after every chunk is solved (below), in large batches.
        probe = jnp.stack([xs - u, xs + u] + (list(jnp.moveaxis(inner.reshape(2, 2, E), 1, 0)) if ns else []), 1)

        ext = jnp.where(full, 0.5 * h, jnp.where(lost, h, jnp.abs(0.5 * (lo + hi))))
        e_m, e_p = ext[:E], ext[E:]
        pix, wts = _pieces(xs - e_m[None] * tdir, xs + e_p[None] * tdir, width, height)
        # Rows and columns share each edge by the weight |g_a|^4 / (g_x^4 + g_y^4): each
        # direction takes the edges it crosses steeply, where one crossing stands for a
        # piece of edge at most ~1.2 sample spacings long (a crossing of a shallow edge
        # stands for a long piece, along which the jump may change).
        m = jnp.maximum(jnp.abs(gx), jnp.abs(gy))
        a4, c4 = V.safe_div(ga, m) ** 4, V.safe_div(gc, m) ** 4
        wgt = V.safe_div(V.safe_div(a4, a4 + c4), jnp.abs(ga))  # weight / |g_a|
        cbase = -jnp.sign(ga) * wgt * (e_m + e_p)  # times the jump: the coefficient of g
        sec_v = ok & jump_ok & silh & jnp.where(owner_b, hm != A, hp != B)
        # Where the next crossing lies: beyond the probe on the second sample's side
        # (a silhouette owned by the first sample, a shadow whose inside is there), or
        # on the first's.
        to_b = jnp.where(vis, ~owner_b, inside_a)
        out = {
            "sec": sec_v | sec_s,
            "sec_A": jnp.where(vis & owner_b, A, jnp.where(vis, hp, A)),
            "sec_B": jnp.where(vis & owner_b, hm, B),
            "sec_occ": jnp.where(vis, c["occ"], occ2),
            "sec_fa": jnp.where(to_b, f_out, c["fa"]),
            "sec_la": jnp.where(to_b, l_out, c["la"]),
            "sec_fb": jnp.where(to_b, c["fb"], f_out),
            "sec_lb": jnp.where(to_b, c["lb"], l_out),
            "sec_xa": jnp.where(to_b[None], xs + u, xa),
            "sec_xb": jnp.where(to_b[None], xb, xs - u),
            "sec_far": far_e,
            "typ": ev.typ,
            "p1": ev.p1,
            "p2": ev.p2,
            "sign": ev.sign,
            "xs": xs,
            "cbase": cbase,
            "pix": pix,
            "wts": wts,
            "ok": ok,
            "probe": probe,
            "in_b": in_b,
            "sil": sil,
            "jump_ok": jump_ok,
        }
        if ns:
            # A sphere's silhouette: the first QUAD_SAMPLES inside samples of the row (at
            # t = k + phi spacings from the edge) are replaced by the integral of the
            # samples' derivative over [0, QUAD_SAMPLES - 1/2 + phi], by Gauss-Legendre
            # in u = sqrt(t): the 1/sqrt(t) singularity becomes smooth in u, and what
            # grows like sqrt(t - t_k) after a terminator's kink piecewise smooth. The
            # rows' weights and piece lengths are the edge term's; it goes to the inside
            # sample's pixel (a shift of at most QUAD_SAMPLES samples).
            T = QUAD_SAMPLES - 0.5 + phi
            xi, wi = (jnp.asarray(v, dt) for v in np.polynomial.legendre.leggauss(QUAD_NODES))
            xi, wi = 0.5 * (xi + 1.0), 0.5 * wi
            tq = T[None] * xi[:, None] ** 2  # (Q, E)
            wq = 2.0 * T[None] * (xi * wi)[:, None]
            tk = jnp.arange(QUAD_SAMPLES, dtype=dt)[:, None] + phi[None]
            ww = jnp.concatenate([wq, -jnp.ones_like(tk)])
            x0 = jnp.where(in_b[None], xb, xa)  # the first inside sample, exactly on the grid
            qx = jnp.concatenate(
                [
                    xs[:, None, :] + tq[None] * step_in[:, None, :],
                    x0[:, None, :] + (tk - phi[None])[None] * step_in[:, None, :],
                ],
                1,
            )  # (2, Q+K, E)
            scale = (V.safe_div(a4, a4 + c4) * (e_m + e_p) * h)[None]
            qw = jnp.where((ok & sil & jump_ok)[None] & jnp.isfinite(scale), ww * scale, 0.0)
            out["qx"], out["qw"], out["pin"] = qx, qw, _pixel_of(x0, width, height)
        return out

    over = (count > budget) | (n_differ > Kp)

    def solve_or_skip(c, const):
        R, exceeded = const
        out = run_or_zeros(any_true(c["live"]), solve, c, R)
        # The budget's check, in every chunk and so on every device of a sharded
        # finder: a check outside the sharded map would stop one device while the
        # others wait for it at their next collective, which aborts the process.
        # On what the boundary term reads (``ok``) and on the quadrature's weights, which
        # the grid's image reads (a jitted render with no derivative computes no
        # boundary term; with a sphere it still traces the quadrature's rays).
        if check:
            msg = (
                f"edge_gradients: more sample pairs straddle an edge than edge_budget={budget}; "
                "pass a larger edge_budget to render (raytrax.edge_pairs gives what a scene needs)"
            )
            for name in ("ok", "qw"):
                if name in out:
                    out[name] = eqx.error_if(out[name], exceeded, msg)
        return out

    # The events are packed at the front: the chunks are dealt to the devices in turn.
    def spawn(c, out):
        """The crossings found beyond a third primitive (see ``solve``): the same pair
        of grid samples' chain, between the probe that saw it and the far sample."""
        sec = out["sec"]
        ent = dict(c)
        ent.update(
            live=sec,
            occ=out["sec_occ"],
            fa=out["sec_fa"],
            la=out["sec_la"],
            fb=out["sec_fb"],
            lb=out["sec_lb"],
            A=out["sec_A"],
            B=out["sec_B"],
            xa=out["sec_xa"],
            xb=out["sec_xb"],
            far=out["sec_far"],
        )
        return sec, ent

    def solve_split(c, const):
        """``solve_or_skip``'s outputs, and apart what only ``spawn`` reads (not kept)."""
        out = solve_or_skip(c, const)
        return {k: v for k, v in out.items() if not k.startswith("sec")}, {
            k: v for k, v in out.items() if k.startswith("sec")
        }

    res, inputs, n_lost = map_worklist(
        solve_split,
        spawn,
        jax.lax.stop_gradient(inputs),
        jnp.minimum(count, K),
        nc,
        C,
        devices=eo.devices,
        const=(R, over),
    )
    vis, k_ev, level, chain, refr = inputs["vis"], inputs["k"], inputs["level"], inputs["chain"], inputs["refr"]
    # The jumps: the probes of every event traced in one chunked pass, skipping the
    # chunks past the live events (a shadow edge's jump is that of its light's
    # contribution alone: index k; visibility edges and the inner rays carry
    # everything, index L). f = f_s + A sqrt(q) + B q at the inside distances q = 1/256
    # (the probe), 1/16 and 1/4 of the spacing: A by elimination of f_s and B.
    probe = res["probe"]  # (2, P, K)
    npr = probe.shape[1]
    which = jnp.where(vis, L, k_ev)
    sel = jnp.stack([which, which] + [jnp.full_like(which, L)] * (npr - 2), 1).ravel()  # event-major
    # Only the rays whose radiance is used are traced, packed at the front: the two
    # probes of a crossing whose probes see what defines it (jump_ok), and the inner
    # rays of those beside a sphere's silhouette.
    used = res["ok"] & res["jump_ok"]
    need = jnp.stack([used, used] + [used & res["sil"]] * (npr - 2), 1).ravel()
    src, dst, n_rays = pack_map(need, K * npr, dtype=jnp.int32)
    xy_p = jnp.moveaxis(probe, 1, 2).reshape(2, K * npr)[:, src]
    with jax.named_scope("edge_probes"):
        traced = radiance_at(xy_p, sel[src], jnp.arange(K * npr, dtype=jnp.int32) < n_rays)
    fl = jnp.where(need[:, None], traced[jnp.minimum(dst, K * npr - 1)], 0.0).reshape(K, npr, 3)
    in_b, sil = res["in_b"][:, None], res["sil"][:, None]
    f0 = jnp.where(in_b, fl[:, 1], fl[:, 0])
    f1, f2 = (fl[:, 2], fl[:, 3]) if ns else (f0, f0)
    q0, q1, q2 = 1.0 / 256.0, 1.0 / 16.0, 1.0 / 4.0
    a_fit = ((f1 - f0) * (q2 - q0) - (f2 - f0) * (q1 - q0)) / (
        (math.sqrt(q1) - math.sqrt(q0)) * (q2 - q0) - (math.sqrt(q2) - math.sqrt(q0)) * (q1 - q0)
    )
    a_fit = jnp.where(sil & jnp.isfinite(a_fit), a_fit, 0.0)
    fin = f0 - a_fit * math.sqrt(q0)  # the inside probe extrapolated to the edge
    fm = jnp.where(in_b, fl[:, 0], fin)
    fp = jnp.where(in_b, fin, fl[:, 1])
    df = jnp.where(res["jump_ok"][:, None], fm - fp, 0.0)
    # (3, K), channel-major as edge_image reads it (built per channel: no transpose kernel)
    coef = jnp.stack([df[:, j] * res["cbase"] for j in range(3)])
    coef = jnp.where(res["ok"][None] & jnp.isfinite(coef), coef, 0.0)
    quad = None
    if "qx" in res:
        live_q = jnp.any(res["qw"] != 0, 0)
        # The crossings with a quadrature first, each group in its order (a stable
        # argsort of ~live_q, as a prefix count and a scatter).
        r = prefix_count(live_q)
        ar = jnp.arange(live_q.shape[0], dtype=jnp.int32)
        pos = jnp.where(live_q, r - 1, r[-1] + ar - r)
        order = jnp.zeros_like(ar).at[pos].set(ar, unique_indices=True)
        quad = {
            "xy": jnp.moveaxis(res["qx"][:, :, order], 1, 2),  # (2, K, Q)
            "w": res["qw"][:, order].T,  # (K, Q)
            "pixel": res["pin"][order],
        }
    found = {
        "events": Events(res["typ"], level, chain, refr, res["p1"], res["p2"], k_ev, res["sign"]),
        "xs": res["xs"],
        "ok": res["ok"],
        "coef": coef,
        "pix": res["pix"],
        "wts": res["wts"],
    }
    # The crossings found beyond a third primitive take slots of the budget too.
    spawned = count_true(inputs["live"], jnp.int32) - jnp.minimum(count, K).astype(jnp.int32) + n_lost
    need = jnp.maximum(count.astype(jnp.int32), n_differ.astype(jnp.int32)) + spawned
    return jax.lax.stop_gradient(found), need, over, jax.lax.stop_gradient(quad)


def edge_image(scene, width, height, found):
    """The boundary term of the crossings ``found`` (:func:`find_edges`) as an
    ``(height, width, 3)`` image whose *value* is zero and whose derivative with
    respect to ``scene`` is the edge contribution: ``sum coef * g(x_s, theta)`` over
    the crossings, split between the pixels their pieces cover.

    The value is zeros, computed from nothing: only the derivative evaluates ``g``
    (a ``jax.custom_jvp`` whose rule is the JVP of :func:`term_image` along the
    leaves of ``scene`` that have a tangent), so a gradient pays for the boundary
    term's linearisation and its transpose, not for a forward evaluation of it."""
    return _derivative_only(width, height, scene, found)


def _zero_image(width, height, scene, found):
    """Zeros ``(height, width, 3)``, batched under ``jax.vmap`` wherever ``scene`` or
    ``found`` is: the value of :func:`edge_image` and of its JVP rule must be batched
    alike, and as the derivative is."""
    return jnp.zeros((height, width, 3), scene.dtype) + zero_batched_as((scene, found["xs"]), scene.dtype)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _derivative_only(width, height, scene, found):
    return _zero_image(width, height, scene, found)


@functools.partial(_derivative_only.defjvp, symbolic_zeros=True)
def _derivative_only_jvp(width, height, primals, tangents):
    scene, found = primals
    zero = _zero_image(width, height, scene, found)
    tdef, on, live, live_t, dead = split_live(scene, tangents[0])
    if not live:
        return zero, jnp.zeros_like(zero)

    def of_live(*live):
        return term_image(join_live(tdef, on, live, dead), width, height, found)

    _, t = jax.jvp(of_live, tuple(live), tuple(live_t))
    return zero, t


def term_image(scene, width, height, found):
    """``sum coef * g(x_s, theta)`` over the crossings ``found``, split between the
    pixels their pieces cover: ``(height, width, 3)``, differentiable in ``scene``
    (:func:`edge_image` takes its derivative only).

    The crossings are evaluated in chunks of at most :data:`IMAGE_CHUNK`; a chunk
    without a crossing that adds anything is skipped (the live crossings are packed
    at the front, so the cost follows the edges present, not the budget)."""
    P, off = build_prims(scene)
    dt = scene.dtype
    K = found["ok"].shape[0]
    nc, C = equal_chunks(K, IMAGE_CHUNK)

    def term(c):
        # g at the (fixed) edge point, with the live scene (every chain level computed:
        # no conditional in what reverse mode transposes).
        ev = c["events"]
        g = ev.sign.astype(dt) * edge_value(scene, P, off["ns"], ev, c["xs"], width, height, skip=False)
        g = jnp.where(c["ok"], g, 0.0)  # pyright: ignore
        return c["coef"] * g[None]  # (3, C)

    def chunk(c):
        return run_or_zeros(any_in_batch(c["ok"]), term, c, remat=True)

    args = {"events": found["events"], "xs": found["xs"], "ok": found["ok"], "coef": found["coef"]}
    terms = map_chunks(chunk, args, K, nc, C)  # (3, K)
    img = jnp.zeros((3, height * width), terms.dtype)
    for j in range(3):
        img = img.at[:, found["pix"][j]].add(terms * found["wts"][j][None])
    return jnp.moveaxis(img.reshape(3, height, width), 0, -1)
