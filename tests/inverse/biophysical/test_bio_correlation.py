"""The correlation length estimated from the albedo, against lattice Matérn fields of known length (NumPy only, a few s)."""

import numpy as np
import pytest

from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
from polarbssrdf.inverse.biophysical.correlation import (
    albedo_correlation_length,
    fitted_correlation_length,
    lattice_covariance,
    matern_correlation_shape,
)

N, H = 256, 0.5  # periodic grid (texels), texel size (mm)


def lattice_symbol(n=N):
    """The unit-spacing 5-point Laplacian's symbol on an n x n periodic grid."""
    theta = 2.0 * np.pi * np.fft.fftfreq(n)
    half = np.sin(theta / 2.0) ** 2
    return 4.0 * (half[:, None] + half[None, :])


def matern_spectrum(length_mm, order, n=N):
    """The lattice prior's power spectrum ``1 / (1 + l^2 lambda / h^2)^order`` (SpatialPrior's Q)."""
    return 1.0 / (1.0 + (length_mm / H) ** 2 * lattice_symbol(n)) ** order


def matern_sample(length_mm, order, rng, n=N):
    white = rng.standard_normal((n, n))
    field = np.real(np.fft.ifft2(np.fft.fft2(white) * np.sqrt(matern_spectrum(length_mm, order, n))))
    return field / field.std()


@pytest.mark.parametrize("order", [1, 2])
def test_the_shape_is_the_lattice_priors_correlation(order):
    """x^nu K_nu(x) against the inverse transform of the discrete prior's spectrum, lags 2-24 texels."""
    length = 3.0  # mm: 6 texels
    covariance = np.real(np.fft.ifft2(matern_spectrum(length, order)))[0, 2:25]
    distance = H * np.arange(2, 25)
    shape = matern_correlation_shape(distance, length, order)
    ratio = covariance / shape
    assert np.ptp(ratio) / np.mean(ratio) < 0.05, ratio


@pytest.mark.parametrize("length", [2.0, 4.0, 7.0])
def test_a_matern_fields_length_is_recovered(length):
    """Six independent fields (bands) on a 128 mm square; over ten seeds the estimate's spread
    is 4-10% for one pair of fields (the domain holds 18-64 lengths), and it sits up to 10% low
    at 7 mm (the mean removed over a finite domain lowers the long lags' covariance)."""
    rng = np.random.default_rng(3)
    valid = np.ones((N, N), bool)
    sizes = np.full((N, N, 2), H)
    fields = np.stack([matern_sample(length, 2, rng) for _ in range(6)])
    fields -= fields.mean(axis=(1, 2), keepdims=True)
    covariance = lattice_covariance(fields, valid, sizes)
    estimate, scale = fitted_correlation_length(*covariance)
    assert estimate == pytest.approx(length, rel=0.12)
    assert scale == pytest.approx(6.0, rel=0.25)  # six unit-variance fields, summed


def test_noise_at_and_next_to_a_texel_does_not_move_the_estimate():
    """White noise as strong as the field, and noise correlated 0.5 between neighbours (the
    resampling's), enter only lags 0 and 1, which the fit leaves out."""
    rng = np.random.default_rng(5)
    valid = np.ones((N, N), bool)
    sizes = np.full((N, N, 2), H)
    melanin, blood = matern_sample(4.0, 2, rng), matern_sample(4.0, 2, rng)
    white = rng.standard_normal((3, N, N))
    neighbours = 0.5 * (white + np.roll(white, 1, axis=2))  # horizontal lag-1 correlation
    mixing = np.array([[1.0, 0.2], [0.5, 0.8], [0.1, 1.0]])  # bands x chromophores
    clean = np.exp(np.log(0.3) + 0.05 * np.einsum("bc,cij->bij", mixing, np.stack([melanin, blood])))
    noisy = clean * np.exp(0.05 * (white + neighbours))
    length_clean, _ = albedo_correlation_length(clean, valid, sizes)
    length_noisy, figures = albedo_correlation_length(noisy, valid, sizes)
    assert length_clean == pytest.approx(4.0, rel=0.1)
    assert length_noisy == pytest.approx(length_clean, rel=0.05)
    assert figures["correlation_mm"] == pytest.approx(length_noisy, abs=1e-3) and not figures["at_bound"]


def test_no_pair_spans_a_gap_between_charts():
    """Two charts of opposite constant value: every pair within a chart has product +1; a pair
    across the gap (product -1) would pull a lag's covariance below 1."""
    valid = np.ones((64, 64), bool)
    valid[:, 30:34] = False
    fields = np.where(np.arange(64)[None, :] < 32, 1.0, -1.0)[None] * valid[None]
    distance, covariance, pairs = lattice_covariance(fields, valid, np.full((64, 64, 2), 1.0))
    assert covariance.size > 10 and np.allclose(covariance, 1.0)
    # distances are lags times the texel extent, in mm
    assert distance.min() == pytest.approx(2.0)


def test_a_map_too_small_to_tell_gets_the_default_length():
    from polarbssrdf.inverse.biophysical.prior import DEFAULT_CORRELATION_MM

    valid = np.zeros((16, 16), bool)
    valid[4:10, 4:10] = True  # 36 texels: no lag has 100 pairs
    rbar = np.full((3, 16, 16), 0.3)
    length, figures = albedo_correlation_length(rbar, valid, np.full((16, 16, 2), 1.0))
    assert length == DEFAULT_CORRELATION_MM and figures["lags"] == 0 and "default" in figures["note"]
    with pytest.raises(ValueError, match="too few"):
        fitted_correlation_length([1.0, 2.0], [1.0, 0.5], [100, 100])


def test_the_config_takes_fit_or_a_length():
    assert BiophysicalConfig(correlation_mm="fit").correlation_mm == "fit"
    assert BiophysicalConfig(correlation_mm=6.0).correlation_mm == 6.0
    for bad in ("fitted", -1.0, 0.0):
        with pytest.raises(ValueError, match="correlation_mm"):
            BiophysicalConfig(correlation_mm=bad)
