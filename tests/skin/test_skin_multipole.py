"""Multipole slab totals and profiles (eq. 9-12, 42) against adding-doubling
(iadpython), the pmcx dipole, and analytic identities."""

import sys
from pathlib import Path

import numpy as np
import pytest

from polarbssrdf.skin import multipole as mp
from polarbssrdf.skin.twolayer import inverse_hankel, radial_energy
sys.path.insert(0, str(Path(__file__).parent))
from skin_iad_reference import slab_rt  # noqa: E402

ETAS = (1.33, 1.4, 1.5)


def test_diffuse_fresnel_reflectance():
    assert abs(float(mp.diffuse_fresnel_reflectance(1.0))) < 1e-12  # matched boundary
    values = mp.diffuse_fresnel_reflectance(np.array([1.1, 1.3, 1.4, 1.5]))
    assert np.all(np.diff(values) > 0)
    assert 0.45 < float(mp.diffuse_fresnel_reflectance(1.4)) < 0.6  # internal diffuse reflectance
    assert 0.0 < float(mp.diffuse_fresnel_reflectance(1 / 1.4)) < 0.15  # external
    # Egan's fit (eq. 12) approximates the exact 2 C_1 within 0.1% over skin-like indices
    etas = np.linspace(1.3, 1.6, 7)
    np.testing.assert_allclose(mp.egan_diffuse_fresnel_reflectance(etas), mp.diffuse_fresnel_reflectance(etas),
                               rtol=1e-3)


def test_fresnel_moments_against_direct_quadrature():
    from scipy.integrate import quad

    from polarbssrdf.optics.fresnel import fresnel_reflectance

    for eta in (0.7, 1.0, 1.33, 1.4, 1.5, 2.0):
        f = lambda mu: 0.5 * sum(fresnel_reflectance(mu, 1.0 / eta))  # noqa: E731
        points = [np.sqrt(1 - eta**-2)] if eta > 1 else None
        c1 = quad(lambda mu: f(mu) * mu, 0, 1, points=points, limit=200)[0]
        c2 = quad(lambda mu: f(mu) * mu * mu, 0, 1, points=points, limit=200)[0]
        got = mp.fresnel_moments(eta)
        assert got[0] == pytest.approx(c1, abs=1e-7) and got[1] == pytest.approx(c2, abs=1e-7)
        A = mp.internal_reflection_parameter(eta)
        c_phi, c_e = mp.exitance_coefficients(eta)
        assert A == pytest.approx((1 - c_e) / (2 * c_phi), rel=1e-12)  # partial-current boundary condition
    assert mp.exitance_coefficients(1.0) == pytest.approx((0.25, 0.5), abs=1e-12)
    with pytest.raises(ValueError):
        mp.fresnel_moments(6.0)


@pytest.mark.parametrize("eta", ETAS)
@pytest.mark.parametrize("albedo", [0.99, 0.995, 0.999])
def test_semi_infinite_matches_adding_doubling(albedo, eta):
    reference, _, _ = slab_rt(albedo, 1.0e5, eta)
    ours, trans = mp.slab_reflectance_transmittance(1.0 - albedo, albedo, eta, np.inf)
    assert trans == 0.0
    assert ours == pytest.approx(reference, rel=0.02)


@pytest.mark.parametrize("eta", ETAS)
@pytest.mark.parametrize("albedo", [0.95, 0.97])
def test_semi_infinite_albedo_095_to_097_within_2_percent(albedo, eta):
    # The requirement (albedo >= 0.95, eta 1.33-1.5: 2% relative). The
    # paper's dipole is +8.8% off at albedo 0.95, eta 1.5; the exact-moment
    # boundary, fluence + flux exitance and extended-source depth bring it to
    # within 1.3% (see polarbssrdf/skin/multipole.py).
    reference, _, _ = slab_rt(albedo, 1.0e5, eta)
    ours, _ = mp.slab_reflectance_transmittance(1.0 - albedo, albedo, eta, np.inf)
    assert ours == pytest.approx(reference, rel=0.02)


@pytest.mark.parametrize("eta", (1.33, 1.5))
def test_classical_dipole_is_off_at_albedo_095(eta):
    # documents why the paper's dipole was replaced: its total (alpha'/2 form of
    # eq. 42 with Egan's F_dr) against adding-doubling at albedo 0.95
    reference, _, _ = slab_rt(0.95, 1.0e5, eta)
    r = np.concatenate([[0.0], np.geomspace(1e-5, 80.0, 6000)])
    classical = radial_energy(r, mp.classical_dipole_profile(r, 0.05, 0.95, eta))
    assert abs(classical / reference - 1) > (0.005 if eta == 1.33 else 0.08)


@pytest.mark.parametrize("eta", (1.33, 1.5))
@pytest.mark.parametrize("albedo", [0.99, 0.999])
@pytest.mark.parametrize("tau", [4.0, 6.0, 8.0])
def test_slab_4_to_8_mfp_matches_adding_doubling(albedo, eta, tau):
    # thickness in mm with sigma_t' = 1/mm equals the optical thickness
    R_ad, _, T_ad_total = slab_rt(albedo, tau, eta)
    R, T = mp.slab_reflectance_transmittance(1.0 - albedo, albedo, eta, tau)
    assert R == pytest.approx(R_ad, rel=0.03)
    assert T == pytest.approx(T_ad_total, rel=0.05)  # both include the unscattered beam (issue: 8%)


@pytest.mark.parametrize("tau", [0.1, 0.5, 1.0, 2.0])
@pytest.mark.parametrize("eta", (1.33, 1.5))
def test_thin_slab_close_to_adding_doubling(tau, eta):
    # eq. 11 as printed gives R = 0.28 instead of 0.07 at 0.1 mfp; the source
    # depths of the truncated first-collision density keep the thin-slab totals
    # within 3.3% (R) and 3.2% (T).
    R_ad, _, T_ad_total = slab_rt(0.99, tau, eta)
    R, T = mp.slab_reflectance_transmittance(0.01, 0.99, eta, tau)
    assert R == pytest.approx(R_ad, rel=0.05) and T == pytest.approx(T_ad_total, rel=0.05)


@pytest.mark.parametrize("incidence", ["collimated", "diffuse"])
def test_thin_slabs_non_negative_and_energy_conserving(incidence):
    tau = np.geomspace(0.1, 10.0, 40)[:, None, None]
    albedo = np.array([0.3, 0.6, 0.9, 0.99, 0.9999])[None, :, None]
    eta = np.array([1.0, 1.2, 1.4, 1.6])[None, None, :]
    sigma_t = 2.0  # 1/mm
    d = tau / sigma_t
    for eta_top, eta_bottom in ((eta, eta), (eta, 1.0), (1.0, eta)):
        R, T = mp.slab_totals((1 - albedo) * sigma_t, albedo * sigma_t, d, eta_top, eta_bottom, incidence=incidence)
        assert R.shape == (40, 5, 4)
        assert np.all(R >= 0) and np.all(T >= 0)
        assert np.all(R + T <= 1.0 + 1e-12)
        _, strength, unscattered = mp.source_depth_and_strength((1 - albedo) * sigma_t, albedo * sigma_t, d, incidence)
        assert np.all(R + T <= strength + unscattered + 1e-12)
    # vanishing slab: a matched one passes everything; one in air acts as two
    # Fresnel faces, R = Rs / (1 + Rs), T = 1 / (1 + Rs)
    R0, T0 = mp.slab_totals(0.1, 5.0, 1e-9, 1.0, 1.0, incidence=incidence)
    assert R0 < 2e-3 and T0 > 0.997  # (exact moments: F_dr(1) = 0)
    if incidence == "collimated":
        rs = ((1.4 - 1) / 2.4) ** 2
        R0, T0 = mp.slab_reflectance_transmittance(0.1, 5.0, 1.4, 1e-9)
        assert R0 == pytest.approx(rs / (1 + rs), rel=1e-6) and T0 == pytest.approx(1 / (1 + rs), rel=1e-6)


def test_pole_sum_converges_to_closed_form():
    sa, ss, d = np.array([0.05, 0.5, 2.0]), np.array([5.0, 7.0, 3.0]), np.array([0.25, 0.4, 1.0])
    R, T = mp.slab_totals(sa, ss, d, 1.4, 1.0)
    R_ball, T_ball = mp.ballistic_totals(sa, ss, d, 1.4, 1.0)
    R_poles, T_poles = mp.slab_totals_poles(sa, ss, d, 1.4, 1.0, n_poles=60)
    np.testing.assert_allclose(R_poles, R - R_ball, rtol=1e-9)
    np.testing.assert_allclose(T_poles, T - T_ball, rtol=1e-9)
    # the dipole (n = 0) of a semi-infinite layer: flux (eq. 42 with alpha'/2)
    # and fluence terms of the real and the virtual source, source at
    # z_e = ln(1 + sigma_tr / sigma_t') / sigma_tr
    R_inf, _ = mp.slab_totals(0.1, 2.0, np.inf, 1.4, 1.0)
    albedo, st = 2.0 / 2.1, 2.1
    sigma_tr = np.sqrt(3 * 0.1 * st)
    D = 1 / (3 * st)
    zb = 2 * mp.internal_reflection_parameter(1.4) * D
    c_phi, c_e = mp.exitance_coefficients(1.4)
    e_real = st / (st + sigma_tr)  # e^{-sigma_tr z_e}
    e_virtual = e_real * np.exp(-2 * sigma_tr * zb)
    expected = albedo / 2 * (c_e * (e_real + e_virtual) + c_phi * (e_real - e_virtual) / (D * sigma_tr))
    assert R_inf == pytest.approx(expected, rel=1e-12)


def _radial_grid():
    return np.concatenate([[0.0], np.geomspace(1e-5, 60.0, 4000)])


@pytest.mark.parametrize("sa, ss, d, eta_top, eta_bottom", [
    (0.5, 7.0, 0.25, 1.4, 1.0), (2.0, 6.0, 0.25, 1.0, 1.4), (0.05, 3.0, 1.0, 1.33, 1.33), (0.3, 5.0, 0.1, 1.4, 1.0),
])
def test_profile_energy_equals_closed_form_totals(sa, ss, d, eta_top, eta_bottom):
    r = _radial_grid()
    R_prof, T_prof = mp.slab_profiles(r, sa, ss, d, eta_top, eta_bottom)
    R, T = mp.slab_totals(sa, ss, d, eta_top, eta_bottom)
    R_ball, T_ball = mp.ballistic_totals(sa, ss, d, eta_top, eta_bottom)
    assert radial_energy(r, R_prof) + R_ball == pytest.approx(R, rel=0.005)
    assert radial_energy(r, T_prof) + T_ball == pytest.approx(T, rel=0.005)


@pytest.mark.parametrize("sa, ss, eta", [(0.02, 2.5, 1.4), (0.5, 4.0, 1.33), (2.0, 3.0, 1.5)])
def test_dipole_energy(sa, ss, eta):
    r = _radial_grid()
    prof = mp.dipole_profile(r, sa, ss, eta)
    total, _ = mp.slab_totals(sa, ss, np.inf, eta, 1.0)
    assert radial_energy(r, prof) == pytest.approx(total, rel=0.005)
    # the classical dipole against its own closed-form total alpha'/2 (e^{-s l} + e^{-s (l + 2 z_b)})
    st, s = sa + ss, np.sqrt(3 * sa * (sa + ss))
    f = mp.egan_diffuse_fresnel_reflectance(eta)
    zb = 2 * (1 + f) / (1 - f) / (3 * st)
    classical = ss / st / 2 * (np.exp(-s / st) + np.exp(-s * (1 / st + 2 * zb)))
    assert radial_energy(r, mp.classical_dipole_profile(r, sa, ss, eta)) == pytest.approx(classical, rel=0.005)


@pytest.mark.parametrize("mua, musp, eta", [(0.01, 1.0, 1.4), (0.1, 2.5, 1.33), (1.0, 5.0, 1.5)])
def test_classical_dipole_equals_pmcx_cwfluxdiffusion_times_albedo(mua, musp, eta):
    pmcx_utils = pytest.importorskip("pmcx.utils")
    r = np.geomspace(0.01, 20.0, 50)
    reff = float(mp.egan_diffuse_fresnel_reflectance(eta))
    det = np.stack([r, np.zeros_like(r), np.zeros_like(r)], axis=1).astype(float)
    flux = np.asarray(pmcx_utils.cwfluxdiffusion(mua, musp, reff, [0.0, 0.0, 0.0], det)).ravel()
    ours = mp.classical_dipole_profile(r, mua, musp, eta)
    np.testing.assert_allclose(ours, flux * musp / (mua + musp), rtol=1e-10)


def test_hankel_transform_of_totals_is_the_profile():
    sa, ss, d = 0.5, 6.0, 0.25
    r = np.geomspace(1e-3, 8.0, 120)
    k = np.arange(0.0, 600.0, 0.02)
    R_k, T_k = mp.slab_totals(sa, ss, d, 1.4, 1.0, k=k)
    R_ball, T_ball = mp.ballistic_totals(sa, ss, d, 1.4, 1.0)
    R_prof, T_prof = mp.slab_profiles(r, sa, ss, d, 1.4, 1.0)
    np.testing.assert_allclose(inverse_hankel(k, R_k - R_ball, r), R_prof, atol=1e-5 * R_prof.max())
    np.testing.assert_allclose(inverse_hankel(k, T_k - T_ball, r), T_prof, atol=1e-5 * T_prof.max())


def test_broadcasting_and_limits():
    sa = np.array([[0.01], [0.1], [1.0]])
    ss = np.array([1.0, 2.0, 5.0, 10.0])
    R, T = mp.slab_reflectance_transmittance(sa, ss, 1.4, 0.5)
    assert R.shape == T.shape == (3, 4)
    # more absorption, less light out
    assert np.all(np.diff(R, axis=0) < 0) and np.all(np.diff(T, axis=0) < 0)
    # thick slab -> semi-infinite
    R_thick, T_thick = mp.slab_reflectance_transmittance(0.1, 2.0, 1.4, 60.0)
    R_inf, T_inf = mp.slab_reflectance_transmittance(0.1, 2.0, 1.4, np.inf)
    assert R_thick == pytest.approx(R_inf, rel=1e-9) and T_thick < 1e-10 and T_inf == 0.0
    # inputs are not modified
    sa_copy = sa.copy()
    mp.slab_totals(sa, ss, 0.3, 1.4, 1.0)
    np.testing.assert_array_equal(sa, sa_copy)
    with pytest.raises(ValueError, match="incidence"):
        mp.slab_totals(0.1, 1.0, 1.0, 1.4, 1.4, incidence="oblique")


def test_extended_source_depths():
    st = np.array([1.0, 5.0, 20.0])[:, None]
    s = np.sqrt(3 * np.array([0.01, 0.5, 3.0])[None, :] * st)  # albedo 0.99 .. 0.85 of st = 20
    for d in (0.01, 0.3, 2.0, 50.0):
        z_r, z_t = mp.collimated_source_depths(st, s, d)
        mean, _ = mp.collimated_source_depths(st, 0.0, d)  # the mean depth of the truncated density
        assert np.all(0 < z_r) and np.all(z_r <= mean + 1e-12) and np.all(z_t >= mean - 1e-12) and np.all(z_t < d)
    # semi-infinite: e^{-s z_R} = sigma_t' / (sigma_t' + s); no absorption: the mean depth 1/sigma_t'
    z_inf, _ = mp.collimated_source_depths(st, s, np.inf)
    np.testing.assert_allclose(np.exp(-s * z_inf), st / (st + s), rtol=1e-12)
    z0, _ = mp.collimated_source_depths(2.0, 0.0, np.inf)
    assert z0 == pytest.approx(0.5)
    # the far-face depth is the one whose e^{s z} is the mean of e^{s z} over the truncated density
    d, st1, s1 = 0.7, 4.0, 1.5
    z = np.linspace(0, d, 200001)
    density = st1 * np.exp(-st1 * z)
    mean_far = np.trapezoid(density * np.exp(s1 * z), z) / np.trapezoid(density, z)
    mean_near = np.trapezoid(density * np.exp(-s1 * z), z) / np.trapezoid(density, z)
    z_r, z_t = mp.collimated_source_depths(st1, s1, d)
    assert np.exp(s1 * z_t) == pytest.approx(mean_far, rel=1e-8)
    assert np.exp(-s1 * z_r) == pytest.approx(mean_near, rel=1e-8)


def test_energy_guard_is_rarely_active():
    tau = np.geomspace(0.1, 10.0, 30)[:, None, None]
    albedo = np.array([0.5, 0.9, 0.99])[None, :, None]
    eta = np.array([1.33, 1.4, 1.5])[None, None, :]
    for incidence in ("collimated", "diffuse"):
        guard = mp.energy_guard((1 - albedo) * 2, albedo * 2, tau / 2, eta, eta, incidence)
        assert np.all(guard == 1.0)  # skin-like slabs in air: never needed
    guard = mp.energy_guard(0.0002, 1.9998, np.geomspace(0.05, 5, 50), 1.0, 1.0, "diffuse")
    assert np.all(guard <= 1.0) and guard.min() > 0.99
