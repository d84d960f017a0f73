"""Camera spectral response from simulated narrow-band captures; filter transmittance; bands."""

import numpy as np
import pytest

from polarbssrdf.calibration import (calibrated_bands, estimate_response, filter_transmittance,
                                     second_difference_matrix)
from polarbssrdf.spectral import band_average, default_light, gaussian_curve, make_band, sample_curve

WAVELENGTHS = np.arange(400.0, 701.0, 5.0)
CENTRES = np.arange(420.0, 671.0, 10.0)  # the supplement's tunable filter: every 10 nm, 420-670 nm
COVERED = (WAVELENGTHS >= 420.0) & (WAVELENGTHS <= 670.0)


def true_responses():
    """Smooth RGB responses: a main lobe plus a weak secondary lobe per channel."""
    return {channel: gaussian_curve(c, f, p)(WAVELENGTHS) + 0.06 * gaussian_curve(c + 90, 60, p)(WAVELENGTHS)
            for channel, (c, f, p) in {"B": (460, 70, 0.8), "G": (535, 80, 1.0),
                                       "R": (605, 70, 0.9)}.items()}


def narrow_band_lights():
    """LED (CIE LED-B3) through a 12 nm FWHM tunable filter at each centre, arbitrary units."""
    led = sample_curve(default_light(), WAVELENGTHS)
    return np.array([250.0 * gaussian_curve(c, 12.0)(WAVELENGTHS) * led for c in CENTRES])


SPECTRALON = 0.99 - 0.02 * (WAVELENGTHS - 400.0) / 300.0


def simulate(responses, lights, noise, rng):
    """Camera values of the white target, trapezoid-integrated on a 1 nm grid, with relative noise."""
    fine = np.arange(400.0, 700.5, 1.0)
    values = np.empty((len(lights), len(responses)))
    for c, response in enumerate(responses.values()):
        integrand = (np.array([np.interp(fine, WAVELENGTHS, light) for light in lights])
                     * np.interp(fine, WAVELENGTHS, SPECTRALON) * np.interp(fine, WAVELENGTHS, response))
        values[:, c] = np.trapezoid(integrand, fine, axis=1)
    return values * (1.0 + noise * rng.standard_normal(values.shape))


def relative_rms(estimate, truth):
    return np.sqrt(np.mean((estimate - truth) ** 2)) / np.sqrt(np.mean(truth ** 2))


def test_smooth_response_is_recovered_from_noisy_narrow_band_captures():
    truth = true_responses()
    lights = narrow_band_lights()
    rng = np.random.default_rng(17)
    worst = 0.0
    for _ in range(4):
        measured = simulate(truth, lights, 0.01, rng)
        estimate = estimate_response(WAVELENGTHS, lights, SPECTRALON, measured)
        assert estimate.shape == (3, WAVELENGTHS.size)
        assert np.all(estimate >= 0)
        for c, response in enumerate(truth.values()):
            worst = max(worst, relative_rms(estimate[c, COVERED], response[COVERED]))
            # smooth: no oscillation beyond the truth's own curvature
            curvature = second_difference_matrix(WAVELENGTHS.size) @ estimate[c]
            assert np.abs(curvature).max() < 3 * np.abs(np.diff(response, 2)).max()
    assert worst < 0.03, worst


def test_response_scale_follows_the_light_and_the_reference():
    """Twice the light, same camera values -> half the response (absolute calibration)."""
    truth = true_responses()
    lights = narrow_band_lights()
    measured = simulate(truth, lights, 0.0, np.random.default_rng(0))
    single = estimate_response(WAVELENGTHS, lights, SPECTRALON, measured[:, 1])
    doubled = estimate_response(WAVELENGTHS, 2.0 * lights, SPECTRALON, measured[:, 1])
    np.testing.assert_allclose(doubled, single / 2.0, rtol=1e-6, atol=1e-9 * single.max())
    assert relative_rms(single[COVERED], truth["G"][COVERED]) < 0.01   # noise-free: ~exact


def test_filter_transmittance_is_the_ratio_of_spectra():
    rng = np.random.default_rng(2)
    transmittance = 0.05 + 0.9 * gaussian_curve(550.0, 40.0)(WAVELENGTHS)
    led = sample_curve(default_light(), WAVELENGTHS)
    incident = 1000.0 * (0.1 + led / led.max()) + 3.0
    dark = np.full(WAVELENGTHS.shape, 3.0)
    transmitted = (incident - dark) * transmittance + dark
    estimate, valid = filter_transmittance(WAVELENGTHS, incident + rng.normal(0, 0.1, incident.shape),
                                           transmitted, dark=dark)
    assert valid.all()
    np.testing.assert_allclose(estimate, transmittance, rtol=0.02, atol=1e-3)
    # where there is (almost) no light the ratio is undefined, not a huge number
    incident[:4] = dark[:4] + 1e-3
    estimate, valid = filter_transmittance(WAVELENGTHS, incident, transmitted, dark=dark)
    assert not valid[:4].any() and np.all(estimate[:4] == 0)


def test_bands_from_calibrated_curves_match_the_true_bands():
    truth = true_responses()
    lights = narrow_band_lights()
    measured = simulate(truth, lights, 0.01, np.random.default_rng(4))
    estimate = estimate_response(WAVELENGTHS, lights, SPECTRALON, measured)
    comb = 0.02 + 0.93 * (0.5 + 0.5 * np.cos(2 * np.pi * (WAVELENGTHS - 440.0) / 70.0)) ** 4
    bands = calibrated_bands(WAVELENGTHS, dict(zip(truth, estimate)), {"A": comb}, default_light())
    assert sorted(b.name for b in bands) == ["BA", "GA", "RA"]
    for band in bands:
        reference = make_band(band.name, WAVELENGTHS, (WAVELENGTHS, truth[band.name[0]]),
                              (WAVELENGTHS, comb), default_light())
        assert abs(band.centroid_nm - reference.centroid_nm) < 2.0
        # a skin-like reflectance averaged over the band agrees within 1%
        skin = 0.2 + 0.5 * (WAVELENGTHS - 400.0) / 300.0
        assert band_average(skin, band) == pytest.approx(band_average(skin, reference), rel=0.01)


def test_bad_spectral_inputs_are_clear_errors():
    lights = narrow_band_lights()
    with pytest.raises(ValueError, match="light spectra must be"):
        estimate_response(WAVELENGTHS, lights[:, :10], SPECTRALON, np.ones(len(lights)))
    with pytest.raises(ValueError, match="measurements must be"):
        estimate_response(WAVELENGTHS, lights, SPECTRALON, np.ones(len(lights) - 1))
    with pytest.raises(ValueError, match="must be >= 0"):
        estimate_response(WAVELENGTHS, -lights, SPECTRALON, np.ones(len(lights)))
    with pytest.raises(ValueError, match="no positive value"):
        filter_transmittance(WAVELENGTHS, np.zeros(WAVELENGTHS.size), np.zeros(WAVELENGTHS.size))
