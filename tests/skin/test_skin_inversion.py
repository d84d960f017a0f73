"""Inversion (eq. 41): forward then inverse round trips over the Table 2 ranges."""

import numpy as np
import pytest

from polarbssrdf.skin.inversion import BOUNDS, PARAMETER_NAMES, fit_spectrum, invert_bands, invert_spectra
from polarbssrdf.skin.model import band_reflectance, reflectance_spectra
from polarbssrdf.skin.parameters import table2_ranges
from polarbssrdf.spectral import default_bands

WL = np.arange(400.0, 701.0, 10.0)


def _random_parameters(n, seed):
    rng = np.random.default_rng(seed)
    ranges = table2_ranges()
    truth = {name: rng.uniform(*ranges[name], n) for name in PARAMETER_NAMES}
    span = np.array([ranges[name][1] - ranges[name][0] for name in PARAMETER_NAMES])
    return truth, span, rng


def _errors(result, truth, span):
    """|recovered - true| / (Table 2 range), one column per parameter."""
    return np.stack([np.abs(getattr(result, n) - truth[n]) for n in PARAMETER_NAMES], axis=-1) / span


def test_table2_ranges_inside_search_bounds():
    for name, (lo, hi) in table2_ranges().items():
        assert BOUNDS[name][0] < lo and hi < BOUNDS[name][1]


def test_noise_free_spectra_round_trip():
    truth, span, _ = _random_parameters(300, 1)
    spectra = reflectance_spectra(*(truth[n] for n in PARAMETER_NAMES), WL)
    result = invert_spectra(spectra, WL)
    err = _errors(result, truth, span)
    assert np.all(err < 0.10), err.max(axis=0)  # required: within 10% of the range
    assert np.all(err < 0.01), err.max(axis=0)  # achieved: far better
    assert np.all(result.rmse < 1e-5)
    np.testing.assert_allclose(result.predicted, spectra, atol=1e-5)


def test_noise_free_bands_round_trip():
    truth, span, _ = _random_parameters(2000, 2)
    bands = default_bands()
    values = band_reflectance(*(truth[n] for n in PARAMETER_NAMES), bands)
    result = invert_bands(values, bands)
    err = _errors(result, truth, span)
    assert np.all(err < 0.10), err.max(axis=0)
    assert np.all(result.rmse < 1e-5)


def test_noisy_spectra_report(capsys):
    # 1% multiplicative noise: melanin and epidermal blood stay well determined;
    # eumelanin ratio and dermal blood are weakly determined inside the narrow
    # Table 2 ranges (reported, bounded loosely).
    truth, span, rng = _random_parameters(400, 3)
    spectra = reflectance_spectra(*(truth[n] for n in PARAMETER_NAMES), WL)
    noisy = spectra * (1.0 + 0.01 * rng.standard_normal(spectra.shape))
    result = invert_spectra(noisy, WL)
    err = _errors(result, truth, span)
    median = np.median(err, axis=0)
    with capsys.disabled():
        print("\n1% noise, spectra: median |error| / Table 2 range:",
              dict(zip(PARAMETER_NAMES, np.round(median, 3))))
    assert median[0] < 0.05 and median[2] < 0.05  # C_m, C_h_out
    assert np.all(result.rmse < 0.01)  # the fit explains the data to the noise level
    assert np.median(result.rmse) == pytest.approx(0.01 * np.sqrt(np.mean(spectra**2)), rel=0.3)


def test_shapes_inputs_and_errors():
    truth, _, _ = _random_parameters(6, 4)
    spectra = reflectance_spectra(*(truth[n].reshape(2, 3) for n in PARAMETER_NAMES), WL)
    before = spectra.copy()
    result = invert_spectra(spectra, WL)
    np.testing.assert_array_equal(spectra, before)  # input untouched
    assert result.C_m.shape == result.rmse.shape == (2, 3) and result.predicted.shape == spectra.shape
    with pytest.raises(ValueError, match="samples"):
        invert_spectra(spectra[..., :-1], WL)
    with pytest.raises(ValueError, match="finite"):
        invert_spectra(np.full((1, WL.size), np.nan), WL)
    fitted = fit_spectrum(WL, spectra[0, 0])
    assert set(fitted) == set(PARAMETER_NAMES) | {"rmse"}
    assert fitted["C_m"] == pytest.approx(truth["C_m"][0], rel=1e-3)


@pytest.mark.parametrize("samples", ["bands", "spectra"])
def test_tabulated_model_of_the_lm_steps_matches_the_exact_model(samples):
    from polarbssrdf.skin.inversion import _MODELS, _model_key
    from polarbssrdf.skin.layers import chromophore_basis
    from polarbssrdf.skin.model import band_chromophore_basis

    basis = band_chromophore_basis(default_bands()) if samples == "bands" else chromophore_basis(WL)
    model = _MODELS[_model_key(basis, 0.75, 0.25, 1.4)]
    rng = np.random.default_rng(5)
    lo = np.array([BOUNDS[n][0] for n in PARAMETER_NAMES])
    hi = np.array([BOUNDS[n][1] for n in PARAMETER_NAMES])
    p = lo + (hi - lo) * rng.uniform(size=(3000, 4))
    value, jac = model.value_and_jacobian(p)
    np.testing.assert_allclose(value, model(p), atol=2e-8)  # interpolation error << any noise
    fd = model.finite_difference_jacobian(p[:300])
    scale = np.abs(fd).max(axis=(0, 1))
    assert np.all(np.abs(jac[:300] - fd).max(axis=(0, 1)) < 1e-3 * scale)


@pytest.mark.parametrize("projected", [False, True])
def test_the_start_table_evaluated_layer_by_layer_is_the_model_on_the_grid(projected):
    """``_Model.on_grid`` (the epidermis once per C_m, beta_m, C_h_out; the dermis once per
    C_h_in) gives the exact model on every grid point, in the grid's order, with a quadrature's
    projection and without: to the bit before the projection, to rounding after it (its
    matrix product runs in other blocks); on an uneven grid, so a transposed axis would show."""
    from polarbssrdf.skin.inversion import _MODELS, _model_key
    from polarbssrdf.skin.quadrature import spectral_quadrature

    quadrature = spectral_quadrature(default_bands(), "integral")
    model = _MODELS[_model_key(quadrature.basis, 0.7, 0.2, 1.45, quadrature.weights if projected else None)]
    axes = (np.geomspace(0.002, 0.4, 5), np.linspace(0.0, 1.0, 3), np.linspace(0.0, 0.25, 4),
            np.geomspace(0.002, 0.25, 7))
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 4)
    tabulated = model.on_grid(axes, chunk=50)  # blocks that do not divide the grid
    assert tabulated.shape == (420, 6 if projected else quadrature.basis["eumelanin"].shape[-1])
    if projected:
        np.testing.assert_allclose(tabulated, model(grid), rtol=1e-13, atol=0)
    else:
        np.testing.assert_array_equal(tabulated, model(grid))
