"""The material table and the optics of a single interface.

A :class:`Materials` table stacks per-material arrays indexed by material id
(``color (M, 3)``, ``specular (M,)``...). What the fields mean depends on the
scene's shading model:

``classic`` (the seed raytracer's look)
    ``ambient_color * ambient * C * (1 - transparency)``
    ``+ sum_lights S * light * [(1 - transparency) * diffuse * C * max(n.l, 0)``
    ``+ specular * max(r.v, 0)^shininess]``
    ``+ reflectivity * traced(reflected) + transparency * traced(refracted)``,
    where ``C`` is the colour or texture, ``S`` the shadow transmission (each
    crossing of an occluder's surface multiplies by its transparency). Total
    internal reflection hands the refracted weight to the reflected ray.

``physical`` (radiometric, linear), with ``T = transparency``, ``R =
reflectivity`` (RGB), ``F`` the unpolarised Fresnel reflectance:
    ``(1 - T) (1 - R) C / pi * E_direct + [T F + (1 - T) R] L(reflected)``
    ``+ T (1 - F) eta^2 L(refracted)``. Pure materials are a diffuse (``R = T =
    0``), a mirror (``C = 0, R``), a smooth glass (``C = 0, T = 1, ior``); any
    mixture with ``C, R <= 1`` conserves energy.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from . import vec as V


class Materials(eqx.Module):
    """Per-material arrays (``M`` materials).

    - ``color (M, 3)``: diffuse colour (classic) / albedo (physical), linear RGB.
    - ``ambient``, ``diffuse``, ``specular``, ``shininess`` ``(M,)``: classic Phong terms.
    - ``reflectivity (M, 3)``: mirror weight / RGB reflectance.
    - ``transparency (M,)`` in [0, 1], ``ior (M,)`` >= 1 (exterior index is 1).
    - ``tex_kind (M,)`` int (0 none, 1 checker, 2 stripes, 3 image), ``tex_color2 (M, 3)``,
      ``tex_scale (M,)``, ``tex_direction (M, 2)``, ``tex_image (M,)`` int index into ``images``.
    - ``images``: tuple of ``(H, W, 3)`` linear RGB texel arrays (differentiable).
    """

    color: Float[Array, "M 3"]
    ambient: Float[Array, " M"]
    diffuse: Float[Array, " M"]
    specular: Float[Array, " M"]
    shininess: Float[Array, " M"]
    reflectivity: Float[Array, "M 3"]
    transparency: Float[Array, " M"]
    ior: Float[Array, " M"]
    tex_kind: Int[Array, " M"]
    tex_color2: Float[Array, "M 3"]
    tex_scale: Float[Array, " M"]
    tex_direction: Float[Array, "M 2"]
    tex_image: Int[Array, " M"]
    images: tuple
    kinds_present: tuple = eqx.field(static=True, default=())

    def __check_init__(self):
        m = self.color.shape[0]
        for name in (
            "ambient",
            "diffuse",
            "specular",
            "shininess",
            "transparency",
            "ior",
            "tex_kind",
            "tex_scale",
            "tex_image",
        ):
            if getattr(self, name).shape != (m,):
                raise ValueError(f"Materials.{name}: expected shape ({m},), got {getattr(self, name).shape}")
        for name in ("color", "reflectivity", "tex_color2"):
            if getattr(self, name).shape != (m, 3):
                raise ValueError(f"Materials.{name}: expected shape ({m}, 3), got {getattr(self, name).shape}")


def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a smooth dielectric interface.

    ``cos_i >= 0`` is the cosine of the incidence angle, ``eta = n_i / n_t``
    (index on the incident side over the transmitted side). Returns ``(F,
    cos_t, tir)``; ``F = 1`` under total internal reflection. NaN-free in value
    and gradient at normal and grazing incidence and at the critical angle.
    """
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t >= 1.0
    cos_t = V.safe_sqrt(1.0 - sin2_t)
    rs = V.safe_div(eta * cos_i - cos_t, eta * cos_i + cos_t)
    rp = V.safe_div(cos_i - eta * cos_t, cos_i + eta * cos_t)
    F = jnp.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))
    return F, cos_t, tir


def refract(d, n, eta, cos_t):
    """Snell's law in the seed report's vector form (Fig. 4).

    ``d`` unit incident direction, ``n`` unit normal facing against ``d``
    (``d.n <= 0``), ``eta = n_1 / n_2``, ``cos_t`` from :func:`fresnel_dielectric`:
    ``g = eta d - (eta (d.n) + cos_t) n``.
    """
    g = eta[None] * d - (eta * V.dot(d, n) + cos_t)[None] * n
    return V.normalize(g)


def material_rows(mats, mat, names):
    """The float material fields ``names`` at per-ray material ids ``mat (n,)``:
    ``{name: (n,) or (k, n)}``. One matrix product of the stacked ``(K, M)``
    table with a one-hot ``(M, n)``: a single materialised read (XLA:CPU would
    otherwise repeat per-field select chains inside every consumer), whose
    transpose is again one product instead of a scatter-add. Exact: one non-zero
    term per sum."""
    cols = [getattr(mats, nm) for nm in names]
    tab = jnp.concatenate([c[:, None] if c.ndim == 1 else c for c in cols], 1)  # (M, K)
    M = tab.shape[0]
    if M == 1:
        rows = jnp.broadcast_to(tab[0][:, None], (tab.shape[1],) + mat.shape)
    else:
        onehot = (mat[None, :] == jnp.arange(M, dtype=mat.dtype)[:, None]).astype(tab.dtype)  # (M, n)
        rows = jnp.dot(tab.T, onehot, precision=jax.lax.Precision.HIGHEST)  # (K, n)
    out, j = {}, 0
    for nm, c in zip(names, cols):
        if c.ndim == 1:
            out[nm] = rows[j]
            j += 1
        else:
            out[nm] = rows[j : j + c.shape[1]]
            j += c.shape[1]
    return out


# ----------------------------------------------------------------------------
# A surface hit seen from the incoming ray, and the dielectric interface there.
# ----------------------------------------------------------------------------


class Facing(NamedTuple):
    """The geometric normal turned towards the incoming ray: ``n_s (3, n)``,
    ``front (n,)`` (the ray arrives on the side the normal points to) and ``cos_i (n,)``."""

    n_s: jax.Array
    front: jax.Array
    cos_i: jax.Array


def facing(d, normal) -> Facing:
    """:class:`Facing` of rays ``d (3, n)`` at surfaces with outward ``normal (3, n)``."""
    cos_d = V.dot(d, normal)
    front = cos_d < 0
    return Facing(V.vsel(front, normal, -normal), front, jnp.abs(cos_d))


class Interface(NamedTuple):
    """A smooth dielectric interface crossed from the ray's side: relative index
    ``eta (n,)`` (incident over transmitted), Fresnel reflectance ``F``, ``cos_t`` and
    total internal reflection ``tir``."""

    eta: jax.Array
    F: jax.Array
    cos_t: jax.Array
    tir: jax.Array


def interface(f: Facing, ior) -> Interface:
    """The interface of a material of index ``ior (n,)`` in vacuum (index 1), entered
    where ``f.front`` and left otherwise."""
    eta = jnp.where(f.front, V.safe_div(1.0, ior), ior)
    F, cos_t, tir = fresnel_dielectric(f.cos_i, eta)
    return Interface(eta, F, cos_t, tir)


def never_specular(mats: Materials) -> bool:
    """Whether no material reflects or transmits: every transparency and reflectivity
    is a concrete zero (not a traced value: under ``jax.grad`` with respect to them,
    ``jax.vmap`` over them or inside a ``jax.jit`` that takes them as arguments they
    may be anything). Then every shading model gives every reflected and refracted
    child zero weight, and a render of any depth is that of depth 0 (the camera
    rays' hits, shaded and lit), which :func:`raytrax.render` compiles instead."""
    try:
        values = [np.asarray(x) for x in (mats.transparency, mats.reflectivity)]
    except jax.errors.TracerArrayConversionError:
        return False
    return not any(np.any(v != 0) for v in values)


def refracts_dominantly(transparency, reflectivity):
    """Which child a specular chain follows at a hit (used by the boundary terms): the
    refracted one where the material is at least as transparent as it is reflective
    (``transparency > 0`` and ``transparency >= reflectivity``), else the reflected one."""
    return (transparency > 0) & (transparency >= reflectivity)


# ----------------------------------------------------------------------------
# Shading models: how a hit's material turns light into outgoing radiance.
# ----------------------------------------------------------------------------


class ShadingModel:
    """One shading model (``classic`` or ``physical``, see the module docstring).

    The integrator calls, per shading point: :meth:`shadow` on each light's occluder
    counts, :meth:`add_light` once per light into an accumulator started at zero,
    :meth:`finish`, :meth:`ambient`, and :meth:`specular_weights` for the reflected and
    refracted children. ``fields``: the material table's columns it reads beyond
    ``color``, ``transparency``, ``reflectivity`` and ``ior``.
    """

    name: str = ""
    fields: tuple = ()
    # True: the shadow record is whether anything occludes (``shadow`` receives an
    # ``(n,)`` bool from an any-hit query); False: per-material occluder counts ``(n, M)``.
    occlusion_only: bool = False

    def shadow(self, counts):
        """The shadow record of a light from occluder counts ``(n, M)`` (or, with
        ``occlusion_only``, from whether the segment is occluded, ``(n,)`` bool)."""
        raise NotImplementedError

    def no_shadow(self, n: int, M: int, dtype):
        raise NotImplementedError

    def add_light(self, acc, rows, color, transparency_table, sh, strength, falloff, cosl, ldir, n_s, d, lit):
        raise NotImplementedError

    def finish(self, acc, rows, color):
        return acc

    def ambient(self, local, amb, rows, color):
        return local

    def specular_weights(self, rows, itf: Interface):
        """Weights ``(3, n)`` of the reflected and the refracted child."""
        raise NotImplementedError


class Classic(ShadingModel):
    """The seed raytracer's model: Phong terms per light with no falloff, shadows that
    let light through transparent occluders, ambient light, mirror and Snell weights."""

    name = "classic"
    fields = ("diffuse", "specular", "shininess", "ambient")

    def shadow(self, counts):
        return counts

    def no_shadow(self, n, M, dtype):
        return jnp.zeros((n, M), dtype)

    def add_light(self, acc, rows, color, transparency_table, sh, strength, falloff, cosl, ldir, n_s, d, lit):
        T = rows["transparency"]
        trans = jnp.ones_like(T)
        for m in range(sh.shape[1]):  # shadow transmission: each crossing multiplies by the occluder's transparency
            has = sh[:, m] > 0
            trans = trans * jnp.where(
                has, jnp.where(has, transparency_table[m], 1.0) ** jnp.where(has, sh[:, m], 1.0), 1.0
            )
        diff = rows["diffuse"] * (1.0 - T) * jnp.maximum(cosl, 0.0)
        rv = V.dot(V.reflect(-ldir, n_s), -d)
        spec = jnp.where(lit, rows["specular"] * V.safe_pow(rv, rows["shininess"]), 0.0)
        s = trans * jnp.where(lit, 1.0, 0.0)
        return acc + strength[:, None] * s[None] * (diff[None] * color + spec[None])

    def ambient(self, local, amb, rows, color):
        return local + amb * (rows["ambient"] * (1.0 - rows["transparency"]))[None] * color

    def specular_weights(self, rows, itf):
        T, R = rows["transparency"], rows["reflectivity"]
        tirf = itf.tir.astype(T.dtype)
        wr = R + (T * tirf)[None]
        wt = jnp.broadcast_to((T * (1.0 - tirf))[None], wr.shape)
        return wr, wt


class Physical(ShadingModel):
    """Radiometric: Lambertian ``albedo / pi`` times the irradiance of unshadowed
    lights, ideal mirrors, smooth dielectrics with exact Fresnel (``eta^2`` radiance
    scaling on refraction)."""

    name = "physical"
    fields = ()
    occlusion_only = True

    def shadow(self, counts):
        return counts

    def no_shadow(self, n, M, dtype):
        return jnp.zeros((n,), bool)

    def add_light(self, acc, rows, color, transparency_table, sh, strength, falloff, cosl, ldir, n_s, d, lit):
        vis = jnp.logical_not(sh) & lit
        g = jnp.where(vis, jnp.maximum(cosl, 0.0) * falloff, 0.0)
        return acc + strength[:, None] * g[None]

    def finish(self, acc, rows, color):
        T, R = rows["transparency"], rows["reflectivity"]
        return ((1.0 - T)[None] * (1.0 - R) * color * (1.0 / math.pi)) * acc

    def specular_weights(self, rows, itf):
        T, R = rows["transparency"], rows["reflectivity"]
        wr = (T * itf.F)[None] + (1.0 - T)[None] * R
        wt = jnp.broadcast_to((T * (1.0 - itf.F) * itf.eta * itf.eta)[None], wr.shape)
        return wr, wt


#: The shading models by name (a scene's ``shading``).
SHADING_MODELS: dict[str, ShadingModel] = {m.name: m for m in (Classic(), Physical())}


#: The material fields that decide a hit's children (their directions and weights, so
#: which rays are traced at the next depth).
CHILD_FIELDS = ("transparency", "reflectivity", "ior")

#: The material fields that only colour the light a hit sends back (its own shading):
#: the colour, every shading model's own terms, the pattern's second colour, scale and
#: direction, and the image textures' texels. Never a ray's direction or throughput.
COLOUR_FIELDS = (
    ("color",)
    + tuple(dict.fromkeys(f for m in SHADING_MODELS.values() for f in m.fields))
    + ("tex_color2", "tex_scale", "tex_direction", "images")
)
