"""Two-layer skin: eq. 47 totals, eq. 15 profile, spectra of the Table 2 skins,
against adding-doubling (iadpython)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from polarbssrdf.skin import chromophores as ch
from polarbssrdf.skin.layers import dermis_absorption, epidermis_absorption
from polarbssrdf.skin.model import band_reflectance, reflectance_spectra, skin_reflectance_spectrum
from polarbssrdf.skin.multipole import slab_totals
from polarbssrdf.skin.parameters import TABLE2
from polarbssrdf.skin.twolayer import (
    layer_totals,
    radial_energy,
    two_layer_profile,
    two_layer_total,
    two_layer_total_fast,
    two_layer_total_from_coefficients,
)
from polarbssrdf.spectral import default_bands

sys.path.insert(0, str(Path(__file__).parent))
from skin_iad_reference import two_layer_reflectance  # noqa: E402


def _coefficients(params, wl):
    return (epidermis_absorption(wl, params.C_m, params.beta_m, params.C_h_out, params.gamma),
            ch.epidermis_reduced_scattering(wl),
            dermis_absorption(wl, params.C_h_in, params.gamma),
            ch.dermis_reduced_scattering(wl))


def test_geometric_series_closed_form():
    rng = np.random.default_rng(0)
    R_f, T_f, R_b, T_b, R_in = rng.uniform(0.05, 0.6, (5, 100))
    series = R_f + sum(T_f * R_in * (R_b * R_in) ** n * T_b for n in range(200))
    np.testing.assert_allclose(two_layer_total(R_f, T_f, R_b, T_b, R_in), series, rtol=1e-12)


def test_fast_kernel_equals_layer_by_layer_reference():
    rng = np.random.default_rng(1)
    n = 2000
    args = (rng.uniform(0.01, 8, n), rng.uniform(1, 12, n), rng.uniform(0.01, 8, n), rng.uniform(1, 12, n),
            rng.uniform(0.02, 1.0, n), rng.uniform(1.3, 1.6, n), rng.uniform(1.3, 1.6, n))
    reference = two_layer_total_from_coefficients(*args)
    np.testing.assert_allclose(two_layer_total_fast(*args), reference, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(two_layer_total_fast(*args, dtype=np.float32), reference, rtol=2e-4, atol=1e-6)
    assert np.all((reference > 0) & (reference < 1))


def test_spectra_equal_coefficient_path():
    wl = np.arange(400.0, 701.0, 10.0)
    p = TABLE2[("cheek", "II")]
    expected = two_layer_total_from_coefficients(*_coefficients(p, wl), p.thickness_mm, p.eta)
    np.testing.assert_allclose(skin_reflectance_spectrum(p, wl), expected, rtol=1e-12)
    batch = reflectance_spectra(np.full((2, 3), p.C_m), p.beta_m, p.C_h_out, p.C_h_in, wl, eta=p.eta)
    assert batch.shape == (2, 3, wl.size)
    np.testing.assert_allclose(batch[1, 2], expected, rtol=1e-12)


@pytest.mark.parametrize("key", sorted(TABLE2))
def test_table2_spectra_match_adding_doubling(key):
    p = TABLE2[key]
    wl = np.arange(420.0, 681.0, 20.0)
    sa_o, ss_o, sa_i, ss_i = _coefficients(p, wl)
    reference = np.array([
        two_layer_reflectance(ss_o[i] / (ss_o[i] + sa_o[i]), (ss_o[i] + sa_o[i]) * p.thickness_mm,
                              ss_i[i] / (ss_i[i] + sa_i[i]), p.eta)
        for i in range(wl.size)
    ])
    ours = skin_reflectance_spectrum(p, wl)
    assert np.max(np.abs(ours - reference)) < 0.04


def test_table2_spectra_look_like_skin():
    wl = np.array([450.0, 550.0, 650.0])
    for region in ("forehead", "cheek"):
        at_450 = []
        for skin_type in ("I", "II", "III", "IV"):
            R = skin_reflectance_spectrum(TABLE2[(region, skin_type)], wl)
            assert R[2] > R[0] + 0.05  # rises from blue to red
            assert R[2] > R[1]  # hemoglobin absorbs in the green, not in the red
            at_450.append(R[0])
        assert np.all(np.diff(at_450) < 0), f"{region}: darker types must reflect less at 450 nm: {at_450}"


def test_splitting_a_thick_medium_reproduces_the_semi_infinite_layer():
    for sa, ss in ((0.05, 2.0), (0.5, 6.0), (0.01, 5.0)):
        d = 15.0 / (sa + ss)
        split = two_layer_total_from_coefficients(sa, ss, sa, ss, d, 1.4)
        whole, _ = slab_totals(sa, ss, np.inf, 1.4, 1.0)
        assert split == pytest.approx(whole, rel=0.01)


@pytest.mark.parametrize("key, wavelength", [(("forehead", "I"), 460.0), (("cheek", "IV"), 560.0),
                                             (("cheek", "III"), 650.0)])
def test_two_layer_profile_energy_matches_eq47(key, wavelength):
    p = TABLE2[key]
    coeffs = [float(c[0]) for c in _coefficients(p, np.array([wavelength]))]
    r = np.concatenate([[0.0], np.geomspace(1e-4, 40.0, 500)])
    profile = two_layer_profile(r, *coeffs, p.thickness_mm, p.eta)
    total = two_layer_total_from_coefficients(*coeffs, p.thickness_mm, p.eta)
    assert radial_energy(r, profile) == pytest.approx(float(total), rel=0.005)
    assert np.all(profile > -1e-8 * profile.max())  # positive up to the inverse transform's noise


def test_layer_totals_fields_and_band_models():
    t = layer_totals(0.5, 6.0, 0.05, 3.0, 0.25, 1.4)
    for value in (t.R_out_f, t.T_out_f, t.R_out_b, t.T_out_b, t.R_in):
        assert 0 < float(value) < 1
    bands = default_bands()
    params = TABLE2[("forehead", "II")]
    effective = band_reflectance(params.C_m, params.beta_m, params.C_h_out, params.C_h_in, bands, "effective",
                                 eta=params.eta)
    exact = band_reflectance(params.C_m, params.beta_m, params.C_h_out, params.C_h_in, bands, "exact", eta=params.eta)
    integral = band_reflectance(params.C_m, params.beta_m, params.C_h_out, params.C_h_in, bands, eta=params.eta)
    assert effective.shape == exact.shape == integral.shape == (6,)
    # the default is the band integral: the quadrature against the 5 nm trapezoid rule, which
    # is itself within about 0.5% of the converged integral (tests/skin/test_skin_quadrature.py)
    np.testing.assert_allclose(integral, exact, rtol=1e-2)
    # band-effective coefficients approximate the band average of the spectrum;
    # worst in the red bands that straddle the 580-600 nm hemoglobin edge (~0.026)
    assert np.max(np.abs(effective - exact)) < 0.03
    assert np.max(np.abs(effective - exact)[:4]) < 0.01
    with pytest.raises(ValueError, match="method"):
        band_reflectance(0.1, 0.1, 0.1, 0.1, bands, "median")


def test_array_api_validates_fractions():
    wl = np.array([500.0, 600.0])
    with pytest.raises(ValueError, match="beta_m"):
        reflectance_spectra(0.1, np.array([0.5, 1.2]), 0.1, 0.1, wl)
    with pytest.raises(ValueError, match="C_h_in"):
        band_reflectance(0.1, 0.1, 0.1, np.array([[-0.01]]), default_bands())
    with pytest.raises(ValueError, match="C_m \\+ C_h_out"):
        reflectance_spectra(0.8, 0.5, 0.3, 0.1, wl)
    with pytest.raises(ValueError, match="thickness_mm"):
        reflectance_spectra(0.1, 0.5, 0.1, 0.1, wl, thickness_mm=0.0)
