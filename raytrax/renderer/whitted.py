"""The Whitted integrator: a fixed-depth unroll of reflection and refraction.

The shading itself (the classic and physical models, Fresnel, the children's
weights) is :mod:`raytrax.materials`'; light geometry is :mod:`raytrax.lights`'.

``render(scene)`` splits the image into tiles of pixels (``lax.map`` over tiles,
each under ``jax.checkpoint`` so reverse mode holds one tile's rays at a time).
Inside a tile, each camera sample carries up to ``branches`` specular branches:

* depth 0: camera rays are intersected and shaded (direct light at the hit);
  each hit spawns a reflected and a refracted child weighted by the material
  (Fresnel for dielectrics);
* the ``2 * b`` children of a sample are cut back to its ``branches`` heaviest
  (``lax.top_k`` on the channel-max throughput), so the work per depth is
  bounded by ``branches`` rays per sample and never grows as ``2^depth``;
* the samples with a live child (non-zero throughput) are packed and appended
  to the next depth's ray queue (:mod:`~raytrax.renderer.compaction`), which is
  processed in sub-tiles; the sub-tiles past the live count are skipped
  (``lax.cond``): paths that ended at a diffuse surface cost nothing more;
* at depth ``max_depth`` the specular children take the background instead
  (``max_depth = 0``: the camera rays alone, with no queue at all).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from .. import vec as V
from ..branching import any_in_batch
from ..camera import frame, rays_through
from ..intersect import closest_hit, occluded, occluder_counts, offset_scale
from ..lights import LIGHTS
from ..materials import CHILD_FIELDS, COLOUR_FIELDS, SHADING_MODELS, facing, interface, material_rows, refract
from ..scene import Scene
from ..textures import footprint_widths, hit_with_uv_shifts, needs_footprint, surface_color
from ..tracing import KEPT, tangent_seed
from . import compaction as C_
from .options import RenderOptions

# Reverse mode keeps only the inputs of each sub-tile's shading (and the values
# named here) and recomputes the rest: storing every intermediate of every
# bounce costs more in memory traffic than recomputing it.
SHADE_POLICY = jax.checkpoint_policies.save_only_these_names(KEPT, "raytrax_shadow")


def shade(scene: Scene, kinds, o, d, w, cw, spread, opts: RenderOptions, last: bool, sel=None):
    """Intersect and shade rays ``o, d (3, n)`` with throughput ``w (3, n)``.

    ``cw (n,)`` is each ray's cone width at its origin and ``spread`` (``(n,)`` or a
    scalar) how fast it grows per unit of distance (world units; the texture
    footprint at the hit is ``cw + spread t``). Returns the radiance they contribute ``(3, n)`` and their
    reflected and refracted children (origin, direction, throughput), the cone width
    at the hit and the children's spreads: a mirror of curvature ``k`` (1 / radius)
    spreads the reflected cone by ``2 k`` times its width (its normal turns by ``k``
    per unit of surface; the largest turn of a reflected direction is twice that, in
    the plane of incidence), a flat one leaves it as it is; the refracted cone keeps
    its spread (a curved lens's focusing is not modelled). ``sel (n,)`` (optional, no
    gradient): per ray, the one light whose contribution it carries (``l`` below
    the number of lights; no ambient, no background), or everything (``>= L``).
    """
    st = opts.settings
    mats = scene.materials
    env = scene.environment
    dt = o.dtype
    # The hit and (filtered procedural textures) how its uv moves as the ray shifts: the footprints' ray differentials.
    hit, uv_shifts = hit_with_uv_shifts(
        lambda o_: closest_hit(kinds, o_, d), o, d, needs_footprint(mats, st.filter_textures)
    )
    valid = hit.valid
    t = hit.t
    p = o + t[None] * d
    mat = hit.material

    model = SHADING_MODELS[st.shading]
    face = facing(d, hit.normal)
    n_s = face.n_s  # faces the incoming ray
    eps = offset_scale(p)
    p_out = p + eps[None] * n_s
    p_in = p - eps[None] * n_s

    cw_hit = cw + spread * t
    # Anisotropic box-filter widths in uv: the cone's ellipse on the surface (long along the view at grazing angles).
    wuv = jnp.zeros_like(hit.uv) if uv_shifts is None else footprint_widths(uv_shifts, d, hit.normal, cw_hit)
    names = ("color",) + model.fields
    if mats.kinds_present:
        names += ("tex_scale", "tex_color2", "tex_direction")
    if opts.split_material_read:  # two reads: under jax.vmap over colours only the second is batched
        rows = material_rows(mats, mat, CHILD_FIELDS) | material_rows(mats, mat, names)
    else:  # one read of every field (faster where nothing is batched)
        rows = material_rows(mats, mat, names[:1] + CHILD_FIELDS + names[1:])
    color = surface_color(mats, mat, hit.uv, wuv, st.filter_textures, rows)

    # --- direct light -----------------------------------------------------
    # Every light of every type, in registry order (raytrax.lights.LIGHTS).
    samples = [
        spec.sample(scene.light_sets[spec.field], j, p_out)
        for spec in LIGHTS
        for j in range(spec.count(scene.light_sets[spec.field]))
    ]
    L = len(samples)
    n = o.shape[1]
    local = jnp.zeros_like(o)

    def carries(l):  # (n,) rays that carry light l (l = L: ambient and background), or None: all
        return None if sel is None else (sel == l) | (sel >= L)

    if L:
        # One light at a time on (n,) / (3, n) arrays: no (3, L, n) broadcasts and no
        # reductions over short axes (XLA:CPU runs those, and their transposes, slowly).
        dist, ldir, cosl, lit = [], [], [], []
        for l, smp in enumerate(samples):
            dist.append(smp.distance)
            ldir.append(smp.direction)
            cosl.append(V.dot(n_s, ldir[l]))
            lit.append((cosl[l] > 0) & valid & (True if sel is None else carries(l)))
        M = mats.color.shape[0]

        def shadow(p0, dirn, tmax):
            if model.occlusion_only:
                return model.shadow(occluded(kinds, p0, dirn, tmax))
            return model.shadow(occluder_counts(kinds, p0, dirn, tmax, M))  # from (n, M) counts

        def no_shadow(p0, dirn, tmax):
            return model.no_shadow(p0.shape[1], M, dt)

        # The shadow rays of all lights as one query (one compiled search, larger
        # kernels), under a cond: skipped when no ray faces any light, and the result
        # is materialised once (XLA:CPU would otherwise fuse the occlusion tests into
        # each colour channel's shading).
        cat = (lambda xs: xs[0]) if L == 1 else (lambda xs: jnp.concatenate(xs, -1))
        any_lit = functools.reduce(jnp.logical_or, lit)
        sh_all = jax.lax.cond(
            any_in_batch(any_lit),
            shadow,
            no_shadow,
            cat([p_out] * L),
            cat(ldir),
            cat([x * (1.0 - 1e-6) for x in dist]),
        )
        sh_all = checkpoint_name(sh_all, "raytrax_shadow")
        acc = jnp.zeros_like(o)
        for l in range(L):
            sh = sh_all if L == 1 else sh_all[l * n : (l + 1) * n]
            smp = samples[l]
            acc = model.add_light(
                acc, rows, color, mats.transparency, sh, smp.strength, smp.falloff, cosl[l], ldir[l], n_s, d, lit[l]
            )
        local = model.finish(acc, rows, color)
    amb, bg = env.ambient[:, None], env.background[:, None]
    if sel is not None:  # lit[l] above leaves out the lights a ray does not carry
        env_on = carries(L).astype(dt)[None]  # pyright: ignore
        amb, bg = amb * env_on, bg * env_on
    local = model.ambient(local, amb, rows, color)

    # --- specular children -------------------------------------------------
    itf = interface(face, rows["ior"])
    tdir = refract(d, n_s, itf.eta, itf.cos_t)
    rdir = V.reflect(d, n_s)
    wr, wt = model.specular_weights(rows, itf)
    vm = valid[None]
    wr = jnp.where(vm, w * wr, 0.0)
    wt = jnp.where(vm, w * wt, 0.0)
    contrib = jnp.where(vm, w * local, w * bg)
    # After the last allowed specular interaction, specular children see the background.
    contrib = contrib + jnp.where(last, 1.0, 0.0).astype(dt) * (wr + wt) * bg
    spread_r = spread + 2.0 * cw_hit * hit.curvature
    return contrib, (p_out, rdir, wr, p_in, tdir, wt, cw_hit, spread_r, spread)


def ray_part(scene):
    """``scene`` (or a tree of the same structure, such as flags per leaf) without the
    leaves that never move a ray: the lights, the environment and
    :data:`raytrax.materials.COLOUR_FIELDS` (None there). The rays' origins, directions,
    throughputs and cones depend on the rest only, given that colours are read apart
    from the fields that decide a hit's children (``RenderOptions.split_material_read``)
    wherever they vary alone."""
    return eqx.tree_at(
        lambda s: (s.light_sets, s.environment, *(getattr(s.materials, f) for f in COLOUR_FIELDS)),
        scene,
        replace_fn=lambda _: None,
    )


def trace(scene: Scene, kinds, xy, spread, opts: RenderOptions, sel=None):
    """Radiance ``(3, n)`` of the camera rays through image positions ``xy (2, n)``
    (in pixels, :func:`raytrax.camera.rays_through`; ``sel (n,)``: see :func:`shade`).

    A wavefront over depth (a ``lax.scan``; every depth runs the same compiled
    body): the live samples form a prefix of a ray queue
    (:mod:`~raytrax.renderer.compaction`), shaded in sub-tiles of
    ``opts.subtile`` rays (a ``lax.scan`` over sub-tiles, each under a
    ``lax.cond`` that skips it past the live count). Each sample keeps the
    ``branches`` heaviest of its rays' reflected and refracted children. Depth 0
    makes each sub-tile's camera rays from its slice of ``xy``. With ``max_depth
    == 0`` only that depth exists: its sub-tiles are shaded in turn and their
    radiance is the output, with no queue, packing or depth loop (a smaller
    program, about twice as fast in reverse mode).
    """
    st = opts.settings
    B = st.branches
    n = xy.shape[1]
    dt = xy.dtype
    m = max(B, min(opts.subtile, B * n) // B * B)  # rays per sub-tile, whole samples
    ns = m // B  # samples per sub-tile at depth >= 1
    # A ray's state: origin, direction, throughput (3 each) and, where a texture reads
    # footprints, cone width and its spread (shade), as r rows.
    footprint = needs_footprint(scene.materials, st.filter_textures)
    r = 11 if footprint else 9
    seed = tangent_seed(scene, dt)
    n0 = -(-n // m) * m  # camera rays padded to whole sub-tiles
    xy0 = jnp.concatenate([xy, jnp.zeros((2, n0 - n), dt)], 1) if n0 > n else xy

    cam = frame(scene.camera, st.width, st.height)  # once, outside the loops

    def camera_rays(j):  # sub-tile j's camera rays (r, m) and sample ids (m,) (n: padding)
        start = j * m
        oc, dc = rays_through(
            cam, jax.lax.dynamic_slice(xy0, (jnp.zeros((), start.dtype), start), (2, m)), st.width, st.height
        )
        cone = [jnp.zeros((1, m), dt), jnp.full((1, m), spread, dt)] if footprint else []
        rays = jnp.concatenate([oc, dc, jnp.ones_like(oc), *cone])
        sid = start + jnp.arange(m, dtype=jnp.int32)
        return rays, jnp.where(sid < n, sid, n)

    def shade_rays(rays, last, extra):  # shade() of m rays (r, m) at depth ``last`` or not
        cw, sp = (rays[9], rays[10]) if footprint else (jnp.zeros((m,), dt), spread)
        return shade(scene, kinds, rays[0:3], rays[3:6], rays[6:9], cw, sp, opts, last, *extra)

    def light_of(sid):  # shade()'s ``sel`` of rays of samples ``sid`` (n: none), as extra arguments
        return () if sel is None else (jnp.take(sel, sid, mode="fill", fill_value=0),)

    if st.max_depth == 0:
        # Every sample is one camera ray, shaded once and never continued: no ray
        # queue, no depth loop, no packing of children and no scatter of radiance
        # (its sub-tiles' outputs are the radiance in sample order).
        @functools.partial(jax.checkpoint, policy=SHADE_POLICY)
        def shade_camera(rays, *extra):
            return shade_rays(rays, True, extra)[0]

        def camera_tile(_, j):
            rays, sid = camera_rays(j)
            return None, shade_camera(rays, *light_of(sid))

        k = n0 // m
        _, rad = jax.lax.scan(camera_tile, None, jnp.arange(k, dtype=jnp.int32))  # (k, 3, m)
        return jnp.moveaxis(rad, 1, 0).reshape(3, n0)[:, :n] + seed

    S = -(-n // ns)  # sub-tiles: enough for n samples of B rays (and n camera rays)
    cap = S * ns + m  # queue columns: every sub-tile, and a block written past the last live one
    # The rays as rows of a (2, r, B, cap) queue, their samples' ids in a (2, B, cap) queue
    # (n: none). Depth d >= 1 reads half d % 2 and writes the other half; depth 0 reads xy.
    # A gradient with respect to lights or colours alone leaves the queue without a
    # tangent (:func:`ray_part`; no tangent of every ray computed, stored and transposed
    # for nothing; under jax.vmap, not batched either).
    ray_seed = tangent_seed(ray_part(scene), dt)
    queue = (jnp.zeros((2, r, B, cap), dt) + ray_seed, jnp.full((2, B, cap), n, jnp.int32))

    def depth_body(carry, depth):
        q, cols, radiance = carry
        half = jax.lax.rem(depth, jnp.int32(2))
        last = depth == st.max_depth
        live_rays = jnp.where(depth == 0, n, cols * B)  # n camera rays, then B per queued sample

        # One sub-tile's shading and its children, packed: recomputed in reverse mode
        # from its rays (and the values SHADE_POLICY names), so that the residuals
        # stored per sub-tile are its input rays.
        @functools.partial(jax.checkpoint, policy=SHADE_POLICY)
        def sub_tile(rays, sid_t, *extra):
            contrib, kids = shade_rays(rays, last, extra)

            def results(g, children):  # g rays per sample in this sub-tile (1 at depth 0, else B)
                k = m // g
                sids = sid_t[:k]  # the sample of each (slot-major: slot 0 first)
                rad_k = contrib.reshape(3, g, k).sum(1)
                if not children:  # the last depth: no children are traced
                    block, bid, c = jnp.zeros((r, B, m), dt), jnp.zeros((m,), jnp.int32), jnp.zeros((), jnp.int32)
                else:
                    po, rd, wr, pi, td, wt, cwh, spr, spt = kids
                    # (r, 2g, k) candidates: the reflected children of the g slots, then the refracted
                    refl, refr = [po, rd, wr], [pi, td, wt]
                    if footprint:
                        refl, refr = refl + [cwh[None], spr[None]], refr + [cwh[None], spt[None]]
                    cands = jnp.concatenate(
                        [
                            jnp.concatenate([a.reshape(-1, g, k) for a in refl]),
                            jnp.concatenate([a.reshape(-1, g, k) for a in refr]),
                        ],
                        1,
                    )
                    kept = C_.pick(cands, C_.top_children(cands[6:9], B))  # (r, B, k)
                    alive = jnp.any(kept[6:9] > 0, (0, 1)) & (sids < n)
                    block, bid, c = C_.packed(alive, kept, sids, m)
                if k < m:  # radiance per sample, padded to m samples (id n: none)
                    rad_k = jnp.concatenate([rad_k, jnp.zeros((3, m - k), dt)], 1)
                    sids = jnp.concatenate([sids, jnp.full((m - k,), n, jnp.int32)])
                return rad_k, sids, block, bid, c

            # Depth 0 has one ray per sample; the last depth only adds radiance. The
            # branches return fixed-size results and the buffers are written after the
            # switch (buffers through a nested switch are copied by XLA).
            gs = (1,) if B == 1 else (1, B)
            fns = [functools.partial(results, g, c) for c in (True, False) for g in gs]
            branch = jnp.where(last, len(gs), 0) + (jnp.where(depth == 0, 0, 1) if B > 1 else 0)
            return jax.lax.switch(branch, fns)

        def tile_body(tc, j):
            def live(tc):
                q, cnt, rad = tc
                rays, sid_t = jax.lax.cond(depth == 0, camera_rays, lambda j: C_.read(q, half, j, ns, cols, n), j)
                rad_k, sids, block, bid, c = sub_tile(rays, sid_t, *light_of(sid_t))
                # radiance is accumulated as (n, 3) rows; the (m, 3) update built by a
                # loop fusion (a transposed copy would run as a slow standalone transpose)
                upd = jnp.stack([rad_k[0], rad_k[1], rad_k[2]], -1)
                rad = rad.at[sids].add(upd, mode="drop", unique_indices=True)
                return C_.append(q, 1 - half, cnt, block, bid), cnt + c, rad

            return jax.lax.cond(any_in_batch(j * m < live_rays), live, lambda tc: tc, tc), None

        # The next depth's queue is written over the previous depth's half (columns
        # past its count stay stale: the reader masks them).
        init = (q, jnp.zeros((), jnp.int32), radiance)
        (q, cnt, radiance), _ = jax.lax.scan(tile_body, init, jnp.arange(S, dtype=jnp.int32))
        return (q, cnt, radiance), None

    (*_, radiance), _ = jax.lax.scan(
        depth_body,
        (queue, jnp.asarray(0, jnp.int32), jnp.zeros((n, 3), dt) + seed),
        jnp.arange(st.max_depth + 1, dtype=jnp.int32),
    )
    return radiance.T
