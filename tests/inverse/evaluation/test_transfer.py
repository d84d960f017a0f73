"""The displacement's transfer curve: gain and correlation per octave of spatial scale."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from polarbssrdf.inverse.evaluation.transfer import OCTAVES, displacement_transfer, masked_low_pass

T = 192


@pytest.fixture(scope="module")
def truth():
    """Relief at every scale (white noise and smooth fields of 2 and 8 texels), on a disk."""
    rng = np.random.default_rng(17)
    # a filtered unit white noise has variance 1 / (4 pi sigma^2): each field is of unit spread
    field = sum(amplitude * gaussian_filter(rng.standard_normal((T, T)), sigma) * np.sqrt(4 * np.pi * sigma ** 2)
                for amplitude, sigma in ((0.02, 0.5), (0.05, 2.0), (0.1, 8.0)))
    rows, cols = np.mgrid[:T, :T]
    mask = (rows - T / 2) ** 2 + (cols - T / 2) ** 2 < (0.45 * T) ** 2
    return field, mask


def test_a_scaled_copy_has_that_gain_at_every_scale(truth):
    field, mask = truth
    curve = displacement_transfer(0.6 * field, field, mask, texel_mm=0.5)
    assert len(curve) == OCTAVES
    for band in curve:
        assert band["gain"] == pytest.approx(0.6, abs=1e-9) and band["correlation"] == pytest.approx(1.0)
    assert curve[0]["sigma_mm"] == [0.0, 0.5] and curve[-1]["sigma_mm"] == [4.0, 8.0]


def test_a_smoothed_copy_loses_the_fine_scales_and_keeps_the_coarse(truth):
    field, mask = truth
    curve = displacement_transfer(masked_low_pass(field, mask, 3.0), field, mask, texel_mm=1.0)
    gains = [band["gain"] for band in curve]
    assert gains[0] < 0.1 and gains[1] < 0.3
    assert gains[-1] > 0.7
    assert all(a <= b + 0.05 for a, b in zip(gains, gains[1:]))  # rises with scale


def test_noise_shows_as_correlation_not_gain(truth):
    """White noise added to the truth leaves the gain near 1 at every scale (it is
    uncorrelated with the truth) and takes the correlation down where it dominates."""
    field, mask = truth
    noisy = field + 0.05 * np.random.default_rng(3).standard_normal(field.shape)
    curve = displacement_transfer(noisy, field, mask, texel_mm=1.0)
    assert all(abs(band["gain"] - 1.0) < 0.15 for band in curve)
    assert curve[0]["correlation"] < 0.7 < curve[-1]["correlation"]
    # what is off the mask does not leak in
    outside = np.where(mask, noisy, 100.0)
    again = displacement_transfer(outside, field, mask, texel_mm=1.0)
    for band, other in zip(curve, again):
        assert other["gain"] == pytest.approx(band["gain"], rel=1e-6)
