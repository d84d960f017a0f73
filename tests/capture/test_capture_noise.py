"""Sensor noise: flat-field statistics match Poisson + read noise + rounding; saturation."""

import numpy as np
import pytest

from polarbssrdf.capture import (
    SensorNoise,
    expected_raw_mean,
    expected_raw_variance,
    radiance_from_raw,
    simulate_raw,
)


@pytest.mark.parametrize("radiance, black_level", [(1.0, 0.0), (0.01, 64.0)],
                         ids=["bright", "dark-with-black-level"])
def test_flat_field_mean_and_variance_match_the_model_within_3_sigma(radiance, black_level):
    noise = SensorNoise(electrons_per_radiance=2000.0, read_noise_electrons=2.5,
                        black_level_dn=black_level)
    rng = np.random.default_rng(7)
    flat = np.full((64, 64), radiance)
    samples = np.stack([simulate_raw(flat, noise, rng) for _ in range(8)]).astype(np.float64)
    count = samples.size
    mean, variance = samples.mean(), samples.var(ddof=1)
    model_mean = expected_raw_mean(radiance, noise)
    model_variance = expected_raw_variance(radiance, noise)
    # Standard errors of the sample mean and (near-Gaussian) sample variance.
    assert abs(mean - model_mean) < 3 * np.sqrt(model_variance / count)
    assert abs(variance - model_variance) < 3 * model_variance * np.sqrt(2 / (count - 1))
    # Shot noise dominates the bright field, read noise matters in the dark one.
    electrons = 2000.0 * radiance
    assert model_variance == pytest.approx(noise.gain ** 2 * (electrons + 6.25) + 1 / 12)


def test_quantization_clips_at_4095():
    # With a black level the ADC range ends before the full well: saturated pixels read 4095.
    noise = SensorNoise(electrons_per_radiance=2000.0, black_level_dn=16.0)
    raw = simulate_raw(np.full((16, 16), 100.0), noise, np.random.default_rng(0))
    assert raw.dtype == np.uint16 and noise.max_dn == 4095
    assert np.all(raw == 4095)
    ramp = np.linspace(0.0, 10.0, 256).reshape(16, 16)
    raw = simulate_raw(ramp, noise, np.random.default_rng(0))
    assert raw.max() == 4095 and raw.min() >= 0


def test_a_full_well_mapped_to_4095_reads_4095_minus_read_noise():
    noise = SensorNoise(electrons_per_radiance=2000.0, read_noise_electrons=2.5)
    raw = simulate_raw(np.full((16, 16), 100.0), noise, np.random.default_rng(0))
    assert raw.max() == 4095 and raw.min() >= 4095 - 3 * noise.gain * 2.5 - 0.5


def test_full_well_saturates_before_the_adc_when_the_gain_is_low():
    noise = SensorNoise(electrons_per_radiance=2000.0, full_well_electrons=10000.0,
                        gain_dn_per_electron=0.2, read_noise_electrons=2.0)
    raw = simulate_raw(np.full((32, 32), 50.0), noise, np.random.default_rng(1))
    assert raw.max() < 4095
    assert raw.mean() == pytest.approx(0.2 * 10000.0, abs=0.1)


def test_the_same_seed_gives_the_same_raw():
    noise = SensorNoise(electrons_per_radiance=500.0)
    radiance = np.random.default_rng(3).uniform(0, 2, (8, 8))
    first = simulate_raw(radiance, noise, np.random.default_rng(42))
    again = simulate_raw(radiance, noise, np.random.default_rng(42))
    other = simulate_raw(radiance, noise, np.random.default_rng(43))
    assert np.array_equal(first, again) and not np.array_equal(first, other)


def test_radiance_from_raw_inverts_the_mean_response():
    noise = SensorNoise(electrons_per_radiance=1500.0, black_level_dn=32.0)
    radiance = np.array([[0.0, 0.5], [1.0, 2.0]])
    assert np.allclose(radiance_from_raw(expected_raw_mean(radiance, noise), noise), radiance)
    assert radiance_from_raw(np.zeros((2, 2), np.uint16), noise).min() < 0


@pytest.mark.parametrize("kwargs, message", [
    (dict(electrons_per_radiance=-1.0), "electrons_per_radiance"),
    (dict(electrons_per_radiance=1.0, read_noise_electrons=-1.0), "read_noise_electrons"),
    (dict(electrons_per_radiance=1.0, bit_depth=20), "bit_depth"),
    (dict(electrons_per_radiance=1.0, gain_dn_per_electron=0.0), "gain_dn_per_electron"),
    (dict(electrons_per_radiance=float("nan")), "electrons_per_radiance"),
])
def test_bad_sensor_parameters_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SensorNoise(**kwargs)


@pytest.mark.parametrize("radiance, rng, message", [
    (np.full((4, 4), -1.0), np.random.default_rng(0), "negative intensities"),
    (np.full((4, 4), np.nan), np.random.default_rng(0), "NaN"),
    (np.ones((4, 4, 3)), np.random.default_rng(0), "2-D"),
    (np.ones((4, 4)), 42, "numpy.random.Generator"),
])
def test_bad_simulation_inputs_are_rejected(radiance, rng, message):
    with pytest.raises(ValueError, match=message):
        simulate_raw(radiance, SensorNoise(electrons_per_radiance=1.0), rng)
