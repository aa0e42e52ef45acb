"""Single-interface optics against closed forms: Snell's law (the seed report's
vector form), unpolarised Fresnel reflectance, total internal reflection."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from raytrax import fresnel_dielectric as _fresnel_dielectric
from raytrax import refract as _refract

# jit: one compilation per input shape instead of one per primitive op (cheaper on CPU)
fresnel_dielectric = jax.jit(_fresnel_dielectric)
refract = jax.jit(_refract)

N_GLASS = 1.5


def _fresnel_reference(n1, n2, theta_i):
    """Textbook Fresnel equations in terms of the indices (independent of the
    ``eta`` parametrisation used by raytrax): reflectance R and transmittance T
    (the latter from the *transmission* amplitudes, so ``R + T = 1`` is a real
    check of energy conservation)."""
    ci = np.cos(theta_i)
    st = n1 / n2 * np.sin(theta_i)
    ct = np.sqrt(1.0 - st * st)
    rs = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)
    rp = (n2 * ci - n1 * ct) / (n2 * ci + n1 * ct)
    ts = 2 * n1 * ci / (n1 * ci + n2 * ct)
    tp = 2 * n1 * ci / (n2 * ci + n1 * ct)
    k = (n2 * ct) / (n1 * ci)
    return 0.5 * (rs**2 + rp**2), 0.5 * k * (ts**2 + tp**2), ct


def _F(cos_i, eta):
    F, cos_t, tir = fresnel_dielectric(jnp.asarray(cos_i, jnp.float64), jnp.asarray(eta, jnp.float64))
    return np.asarray(F), np.asarray(cos_t), np.asarray(tir)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4), (1.33, 1.0)])
def test_normal_incidence_reflectance(n1, n2):
    F, cos_t, tir = _F(np.array([1.0]), np.array([n1 / n2]))
    assert F[0] == pytest.approx(((n1 - n2) / (n1 + n2)) ** 2, rel=1e-12)
    assert cos_t[0] == pytest.approx(1.0, abs=1e-12)
    assert not tir[0]


def test_glass_normal_incidence_is_four_percent():
    F, _, _ = _F(np.array([1.0, 1.0]), np.array([1 / 1.5, 1.5]))
    np.testing.assert_allclose(F, [0.04, 0.04], rtol=1e-12)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 1.33), (2.4, 1.0)])
def test_fresnel_matches_textbook_and_conserves_energy(n1, n2):
    crit = math.asin(n2 / n1) if n1 > n2 else math.pi / 2
    theta = np.linspace(0.0, crit * (1 - 1e-6), 200)
    R_ref, T_ref, ct_ref = _fresnel_reference(n1, n2, theta)
    F, cos_t, tir = _F(np.cos(theta), np.full_like(theta, n1 / n2))
    assert not tir.any()
    np.testing.assert_allclose(F, R_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cos_t, ct_ref, rtol=1e-9, atol=1e-9)
    # energy: reflected + transmitted (from the transmission amplitudes) = 1
    np.testing.assert_allclose(F + T_ref, 1.0, atol=1e-9)
    assert np.all((F >= 0) & (F <= 1))


def test_brewster_angle_p_reflectance_vanishes():
    n1, n2 = 1.0, 1.5
    tb = math.atan(n2 / n1)
    F, _, _ = _F(np.array([math.cos(tb)]), np.array([n1 / n2]))
    # at Brewster's angle only the s-polarised half reflects: F = Rs / 2
    ci = math.cos(tb)
    ct = math.sqrt(1 - (n1 / n2 * math.sin(tb)) ** 2)
    rs = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)
    assert F[0] == pytest.approx(0.5 * rs * rs, rel=1e-10)


def test_grazing_incidence_reflects_everything():
    F, cos_t, tir = _F(np.array([0.0, 1e-9]), np.array([1 / 1.5, 1 / 1.5]))
    assert np.all(np.isfinite(F))
    np.testing.assert_allclose(F, 1.0, atol=1e-6)


def test_critical_angle_total_internal_reflection():
    eta = N_GLASS  # from inside glass to air
    theta_c = math.asin(1.0 / eta)
    below = np.array([theta_c - 1e-4, theta_c - 0.05, 0.3])
    above = np.array([theta_c + 1e-4, theta_c + 0.05, 1.2, math.pi / 2])
    Fb, ctb, tirb = _F(np.cos(below), np.full(3, eta))
    Fa, cta, tira = _F(np.cos(above), np.full(4, eta))
    assert not tirb.any() and tira.all()
    assert np.all(Fb < 1.0)
    np.testing.assert_array_equal(Fa, 1.0)
    assert np.all(np.isfinite(cta)) and np.all(np.isfinite(ctb))
    # approaching the critical angle from below, F -> 1 continuously
    Fc, _, _ = _F(np.array([math.cos(theta_c - 1e-7)]), np.array([eta]))
    assert Fc[0] > 0.99


def test_fresnel_gradient_finite_at_normal_grazing_and_critical():
    eta = N_GLASS
    cos_c = math.sqrt(1 - 1 / eta**2)  # cos of the critical angle
    cs = jnp.asarray([1.0, 0.0, cos_c, cos_c + 1e-12, 0.5], jnp.float64)

    def f(c, e):
        return jnp.sum(_fresnel_dielectric(c, e)[0])

    g = jax.jit(jax.grad(f, argnums=(0, 1)))
    g_c, g_e = g(cs, jnp.full((5,), eta, jnp.float64))
    assert np.all(np.isfinite(np.asarray(g_c))) and np.all(np.isfinite(np.asarray(g_e)))
    g_c2, g_e2 = g(cs, jnp.full((5,), 1 / eta, jnp.float64))
    assert np.all(np.isfinite(np.asarray(g_c2))) and np.all(np.isfinite(np.asarray(g_e2)))


def _refract_batch(theta, n1, n2):
    """Incident directions in the x-z plane at angles ``theta`` to the normal +z,
    travelling downwards (``d.n < 0``); returns d, n, g, eta."""
    k = theta.shape[0]
    d = np.stack([np.sin(theta), np.zeros(k), -np.cos(theta)])
    nrm = np.tile(np.array([[0.0], [0.0], [1.0]]), (1, k))
    # rotate the whole setup about z by varying azimuths so x is not special
    phi = np.linspace(0.0, 2 * np.pi, k, endpoint=False)
    rot = lambda v: np.stack([np.cos(phi) * v[0] - np.sin(phi) * v[1], np.sin(phi) * v[0] + np.cos(phi) * v[1], v[2]])
    d = rot(d)
    eta = np.full(k, n1 / n2)
    _, cos_t, tir = fresnel_dielectric(jnp.asarray(np.cos(theta)), jnp.asarray(eta))
    g = refract(jnp.asarray(d), jnp.asarray(nrm), jnp.asarray(eta), cos_t)
    return d, nrm, np.asarray(g), np.asarray(tir)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 1.33)])
def test_snell_law_vector_form(n1, n2):
    crit = math.asin(n2 / n1) if n1 > n2 else math.pi / 2
    theta = np.linspace(0.0, crit * 0.999, 64)
    d, nrm, g, tir = _refract_batch(theta, n1, n2)
    assert not tir.any()
    np.testing.assert_allclose(np.linalg.norm(g, axis=0), 1.0, atol=1e-12)
    cos_t = -(g * nrm).sum(0)
    assert np.all(cos_t > 0)  # transmitted ray continues through the surface
    sin_i = np.linalg.norm(np.cross(d.T, nrm.T), axis=1)
    sin_t = np.linalg.norm(np.cross(g.T, nrm.T), axis=1)
    np.testing.assert_allclose(n1 * sin_i, n2 * sin_t, atol=1e-12)
    # g lies in the plane of incidence and on the same side of the normal as d
    plane_n = np.cross(d.T, nrm.T)
    np.testing.assert_allclose((g.T * plane_n).sum(1), 0.0, atol=1e-12)
    tang_d = d - (d * nrm).sum(0) * nrm
    tang_g = g - (g * nrm).sum(0) * nrm
    assert np.all((tang_d * tang_g).sum(0) >= -1e-15)


def test_refract_normal_incidence_goes_straight():
    d, nrm, g, _ = _refract_batch(np.array([0.0]), 1.0, 1.5)
    np.testing.assert_allclose(g[:, 0], d[:, 0], atol=1e-15)


def test_refract_in_and_out_of_slab_restores_direction():
    """Entering glass and leaving it through a parallel face gives back the
    original direction (what the seed's refractive sphere relies on)."""
    theta = np.linspace(0.0, 1.4, 16)
    d, nrm, g, _ = _refract_batch(theta, 1.0, 1.5)
    cos_in = -(g * nrm).sum(0)  # leaving through the bottom face: its facing normal is +z as well
    _, cos_t, tir = fresnel_dielectric(jnp.asarray(cos_in), jnp.asarray(np.full(16, 1.5)))
    assert not np.asarray(tir).any()
    g2 = np.asarray(refract(jnp.asarray(g), jnp.asarray(nrm), jnp.asarray(np.full(16, 1.5)), cos_t))
    np.testing.assert_allclose(g2, d, atol=1e-12)
