"""Fresnel equations (supplement eq. 2, T = 1 - R, eq. 12) against independent forms."""

import numpy as np
import pytest
from scipy.integrate import quad

from polarbssrdf.optics import (
    average_diffuse_fresnel_reflectance,
    brewster_angle,
    fresnel_mueller,
    fresnel_reflectance,
    fresnel_transmittance,
    plus_minus,
    reflection_phase_cosine,
)

ETAS = [1.1, 1.33, 1.4, 1.5, 1.8]


def amplitude_transmittances(cos_i, eta):
    """Power transmittances from the transmission *amplitudes* and the flux factor.

    T = (eta cos_t / cos_i) t^2 with t_s = 2 cos_i / (cos_i + eta cos_t) and
    t_p = 2 cos_i / (eta cos_i + cos_t): an independent route to R + T = 1.
    """
    cos_t = np.sqrt(1 - (1 - cos_i**2) / eta**2)
    t_s = 2 * cos_i / (cos_i + eta * cos_t)
    t_p = 2 * cos_i / (eta * cos_i + cos_t)
    factor = eta * cos_t / cos_i
    return factor * t_s**2, factor * t_p**2


@pytest.mark.parametrize("eta", ETAS)
def test_reflectance_plus_amplitude_transmittance_is_one(eta):
    cos_i = np.linspace(0.02, 1.0, 200)
    R_perp, R_par = fresnel_reflectance(cos_i, eta)
    T_perp, T_par = amplitude_transmittances(cos_i, eta)
    np.testing.assert_allclose(R_perp + T_perp, 1.0, atol=1e-12)
    np.testing.assert_allclose(R_par + T_par, 1.0, atol=1e-12)
    ours_perp, ours_par = fresnel_transmittance(cos_i, eta)
    np.testing.assert_allclose(ours_perp, T_perp, atol=1e-12)
    np.testing.assert_allclose(ours_par, T_par, atol=1e-12)


def test_printed_eq3_is_not_a_power_transmittance():
    """The supplement's eq. 3 (amplitude ratios squared) violates R + T = 1 (DESIGN errata)."""
    cos_i, eta = 0.8, 1.4
    cos_t = np.sqrt(1 - (1 - cos_i**2) / eta**2)
    printed_perp = (2 * cos_i / (cos_i + eta * cos_t)) ** 2
    R_perp, _ = fresnel_reflectance(cos_i, eta)
    assert abs(R_perp + printed_perp - 1.0) > 0.05


@pytest.mark.parametrize("eta", ETAS)
def test_brewster_angle(eta):
    theta_b = float(brewster_angle(eta))
    R_perp, R_par = fresnel_reflectance(np.cos(theta_b), eta)
    assert R_par < 1e-20
    assert R_perp > 1e-3
    # cos(delta) flips from -1 to +1 across Brewster's angle
    assert reflection_phase_cosine(np.cos(theta_b - 0.01), eta) == -1.0
    assert reflection_phase_cosine(np.cos(theta_b + 0.01), eta) == 1.0


@pytest.mark.parametrize("eta", ETAS)
def test_normal_incidence(eta):
    R_perp, R_par = fresnel_reflectance(1.0, eta)
    expected = ((eta - 1) / (eta + 1)) ** 2
    assert R_perp == pytest.approx(expected, rel=1e-12)
    assert R_par == pytest.approx(expected, rel=1e-12)
    T_plus, T_minus = plus_minus(*fresnel_transmittance(1.0, eta))
    assert T_plus == pytest.approx(1 - expected, rel=1e-12)
    assert T_minus == pytest.approx(0.0, abs=1e-15)


def test_grazing_and_total_internal_reflection():
    R_perp, R_par = fresnel_reflectance(0.0, 1.4)
    assert R_perp == pytest.approx(1.0) and R_par == pytest.approx(1.0)
    # from inside skin (eta = 1/1.4) beyond the critical angle everything is reflected
    critical = np.arcsin(1 / 1.4)
    R_perp, R_par = fresnel_reflectance(np.cos(critical + 0.05), 1 / 1.4)
    assert R_perp == 1.0 and R_par == 1.0


def test_transmission_minus_is_negative():
    T_plus, T_minus = plus_minus(*fresnel_transmittance(np.linspace(0.05, 0.99, 50), 1.4))
    assert np.all(T_minus < 0) and np.all(T_plus > 0)


@pytest.mark.parametrize("eta", ETAS)
def test_average_diffuse_fresnel_reflectance_matches_integral(eta):
    """Eq. 12 (Egan's fit) against 2 int R(theta) cos sin dtheta, inside and outside."""

    def hemispherical(relative_eta, breakpoints=None):
        def integrand(theta):
            R_perp, R_par = fresnel_reflectance(np.cos(theta), relative_eta)
            return (R_perp + R_par) * np.cos(theta) * np.sin(theta)

        return quad(integrand, 0, np.pi / 2, limit=200, points=breakpoints)[0]

    inside = hemispherical(1 / eta, [np.arcsin(1 / eta)])
    outside = hemispherical(eta)
    assert float(average_diffuse_fresnel_reflectance(eta)) == pytest.approx(inside, rel=0.01)
    # Egan's fit for eta < 1 is coarser (4.4% at 1/1.1)
    assert float(average_diffuse_fresnel_reflectance(1 / eta)) == pytest.approx(outside, rel=0.05)


@pytest.mark.parametrize("variant", ["scalar_spectral_polarized", "llvm_ad_mono_polarized"])
def test_fresnel_mueller_matches_mitsuba(variant):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(variant)

    def first(value):
        return float(value) if isinstance(value, float) else float(dr.ravel(value)[0])

    for eta in ETAS:
        for cos_i in np.linspace(0.05, 1.0, 23):
            cos_i = float(cos_i)
            R_perp, R_par = fresnel_reflectance(cos_i, eta)
            ours = fresnel_mueller(R_perp, R_par, reflection_phase_cosine(cos_i, eta),
                                   Matrix=dr.scalar.Matrix4f)
            theirs = mi.mueller.specular_reflection(mi.Float(cos_i), mi.Float(eta))
            T_perp, T_par = fresnel_transmittance(cos_i, eta)
            ours_t = fresnel_mueller(T_perp, T_par, 1.0, Matrix=dr.scalar.Matrix4f)
            theirs_t = mi.mueller.specular_transmission(mi.Float(cos_i), mi.Float(eta))
            for i in range(4):
                for j in range(4):
                    assert float(ours[i, j]) == pytest.approx(first(theirs[i, j]), abs=2e-6)
                    assert float(ours_t[i, j]) == pytest.approx(first(theirs_t[i, j]), abs=2e-6)


@pytest.mark.parametrize("eta", ETAS)
def test_normal_incidence_reflectance_is_eq2_at_zero_angle(eta):
    from polarbssrdf.optics.fresnel import normal_incidence_reflectance

    R_perp, R_par = fresnel_reflectance(1.0, eta)
    assert normal_incidence_reflectance(eta) == pytest.approx(R_perp, rel=1e-12)
    assert normal_incidence_reflectance(eta) == pytest.approx(R_par, rel=1e-12)
