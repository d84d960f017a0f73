"""Chromophore spectra, the vendored hemoglobin table, parameter validation."""

import importlib.resources
import math

import numpy as np
import pytest

from polarbssrdf.skin import chromophores as ch
from polarbssrdf.skin.layers import dermis_absorption, epidermis_absorption
from polarbssrdf.skin.parameters import TABLE2, SkinParameters


def test_vendored_table_is_package_data_with_provenance():
    resource = importlib.resources.files("polarbssrdf.skin") / "data" / ch.HEMOGLOBIN_CSV
    text = resource.read_text(encoding="utf-8")
    assert "Prahl" in text and text.startswith("#")
    wl, oxy, deoxy = ch.hemoglobin_extinction_table()
    assert wl[0] == 400 and wl[-1] == 700 and np.all(np.diff(wl) == 5)
    # Soret band of oxyhemoglobin near 415 nm; isosbestic crossing near 500 and 800 (here 500-590)
    assert wl[np.argmax(oxy)] == 415
    assert np.all(oxy > 0) and np.all(deoxy > 0)


def test_hemoglobin_absorption_units():
    # mu_a [1/mm] = ln(10) eps [1/(cm M)] * 150 g/L / 64500 g/mol / 10, at a tabulated wavelength
    _, oxy, _ = ch.hemoglobin_extinction_table()
    expected = math.log(10) * 523100 * 150 / 64500 / 10
    assert ch.oxyhemoglobin_absorption(415.0) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(280.1, rel=1e-3)  # whole blood at the Soret peak, ~2800 /cm
    # linear interpolation between table points
    mid = ch.deoxyhemoglobin_absorption(402.5)
    assert mid == pytest.approx(0.5 * (ch.deoxyhemoglobin_absorption(400.0) + ch.deoxyhemoglobin_absorption(405.0)))


def test_melanin_and_baseline_formulas():
    wl = np.array([400.0, 500.0, 700.0])
    np.testing.assert_allclose(ch.eumelanin_absorption(wl), 6.6e10 * wl**-3.33)
    np.testing.assert_allclose(ch.pheomelanin_absorption(wl), 2.9e14 * wl**-4.75)
    np.testing.assert_allclose(ch.baseline_absorption(wl), 0.0244 + 8.53 * np.exp(-(wl - 154) / 66.2))
    # melanins absorb much more in the blue than in the red
    assert ch.eumelanin_absorption(400.0) / ch.eumelanin_absorption(700.0) > 6
    assert ch.pheomelanin_absorption(400.0) / ch.pheomelanin_absorption(700.0) > 14


def test_scattering_decreases_with_wavelength_and_epidermis_thickness_in_mfp():
    wl = np.arange(400.0, 701.0, 10.0)
    epi = ch.epidermis_reduced_scattering(wl)
    assert np.all(np.diff(epi) < 0)
    np.testing.assert_allclose(ch.dermis_reduced_scattering(wl), 0.5 * epi)
    # the 0.25 mm epidermis spans about 1.1-3.1 reduced mean free paths (scattering alone)
    tau = 0.25 * epi
    assert 1.0 < tau.min() and tau.max() < 3.3


def test_layer_absorption_mixing_rules():
    wl = np.array([450.0, 560.0, 650.0])
    zero = epidermis_absorption(wl, 0.0, 0.5, 0.0)
    np.testing.assert_allclose(zero, ch.baseline_absorption(wl))
    pure_blood = dermis_absorption(wl, 1.0, gamma=1.0)
    np.testing.assert_allclose(pure_blood, ch.oxyhemoglobin_absorption(wl))
    # broadcasting texels x wavelengths, linear in C_m
    c_m = np.array([[0.0], [0.1], [0.2]])
    sa = epidermis_absorption(wl, c_m, 1.0, 0.0)
    assert sa.shape == (3, 3)
    np.testing.assert_allclose(sa[2] - sa[1], sa[1] - sa[0])


@pytest.mark.parametrize(
    "field, value",
    [("C_m", -0.1), ("C_m", 1.2), ("beta_m", 1.5), ("C_h_out", -1e-3), ("C_h_in", 2.0), ("gamma", -0.5),
     ("thickness_mm", 0.0), ("thickness_mm", -1.0), ("C_m", float("nan"))],
)
def test_parameters_reject_bad_values_naming_the_field(field, value):
    kwargs = dict(C_m=0.05, beta_m=0.5, C_h_out=0.05, C_h_in=0.05)
    kwargs[field] = value
    with pytest.raises(ValueError, match=field):
        SkinParameters(**kwargs)


def test_parameters_volume_fractions_and_table2():
    with pytest.raises(ValueError, match="C_m \\+ C_h_out"):
        SkinParameters(C_m=0.7, beta_m=0.5, C_h_out=0.4, C_h_in=0.1)
    assert len(TABLE2) == 8
    for params in TABLE2.values():  # all Table 2 means validate
        assert 0.01 < params.C_m < 0.1 and 1.35 < params.eta < 1.55


def test_wavelengths_outside_data_range_raise():
    for bad in ([399.0, 500.0], [650.0, 700.5], [np.nan]):
        with pytest.raises(ValueError, match="400-700 nm"):
            ch.oxyhemoglobin_absorption(np.array(bad))
    with pytest.raises(ValueError, match="400-700"):
        epidermis_absorption(380.0, 0.1, 0.5, 0.1)


@pytest.mark.parametrize(
    "body, line",
    [
        ("wavelength_nm,oxy,deoxy\n400,1,2\n", 1),
        ("# c\nwavelength_nm,oxyhemoglobin,deoxyhemoglobin\n400,1,2\n405,1\n", 4),
        ("wavelength_nm,oxyhemoglobin,deoxyhemoglobin\n400,1,2\n405,x,2\n", 3),
        ("wavelength_nm,oxyhemoglobin,deoxyhemoglobin\n400,1,2\n400,1,2\n", 3),
        ("wavelength_nm,oxyhemoglobin,deoxyhemoglobin\n400,1,2\n405,-1,2\n", 3),
    ],
)
def test_malformed_extinction_csv_names_the_line(tmp_path, body, line):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(ValueError, match=f"line {line}"):
        ch.read_extinction_csv(path)
