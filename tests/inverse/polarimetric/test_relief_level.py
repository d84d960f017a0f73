"""The relief's level: set by its prior, with the spread of the level no view measures.

A constant height over a chart tilts no normal, so the data do not see it
(tests/geometry/test_geometry_height.py); the fit puts each chart at the magnitude prior's
level, mean 0, and the relief's std adds the truth's unknown mean over the chart.
"""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from polarbssrdf.inverse.polarimetric.relief_level import (
    chart_labels,
    chart_level_variance,
    relief_at_prior_level,
)


def _two_charts(size=96):
    valid = np.zeros((size, size), bool)
    valid[4:60, 6:90] = True
    valid[66:92, 10:50] = True
    return valid


def test_each_chart_is_set_to_mean_zero_and_keeps_its_relief():
    rng = np.random.default_rng(1)
    valid = _two_charts()
    labels, count = chart_labels(valid)
    assert count == 2
    height = rng.normal(size=valid.shape) + np.where(labels == 1, 0.3, -0.2)
    height[~valid] = 7.0
    levelled = relief_at_prior_level(height, valid)
    for chart in (1, 2):
        inside = labels == chart
        assert levelled[inside].mean() == pytest.approx(0.0, abs=1e-12)
        shift = height[inside] - levelled[inside]
        np.testing.assert_allclose(shift, shift[0], atol=1e-12)  # one constant per chart
    np.testing.assert_array_equal(levelled[~valid], 7.0)


def _field(rng, shape, correlation_texels, std):
    """A Gaussian random field: white noise blurred by a Gaussian of ``correlation_texels``
    (not the Matérn of synth's truth), scaled to ``std``."""
    field = gaussian_filter(rng.normal(size=shape), correlation_texels, mode="wrap")
    return std * field / field.std()


@pytest.mark.parametrize("correlation", [1.0, 5.0])
def test_the_level_variance_is_the_spread_of_the_charts_mean(correlation):
    """Over 300 fields the chart's mean (its level, which the fit sets to 0) spreads as the
    batch-means estimate of one field says: the estimate's mean within 25% of the mean's
    variance, and 2 estimated std cover the level in 90-99% of the fields."""
    rng = np.random.default_rng(17)
    valid = np.zeros((160, 160), bool)
    valid[8:150, 12:140] = True
    inside = valid
    levels, estimates = [], []
    for _ in range(300):
        height = _field(rng, valid.shape, correlation, 0.1)
        levels.append(height[inside].mean())
        estimates.append(chart_level_variance(height, valid)[inside][0])
    levels, estimates = np.array(levels), np.array(estimates)
    assert np.mean(estimates) == pytest.approx(np.mean(levels ** 2), rel=0.25)
    coverage = np.mean(np.abs(levels) < 2 * np.sqrt(estimates))
    assert 0.90 <= coverage <= 0.99
    assert np.all(chart_level_variance(height, valid)[~valid] == 0.0)


def test_a_chart_too_small_for_blocks_has_its_reliefs_spread_as_its_level_spread():
    valid = np.zeros((40, 40), bool)
    valid[10:13, 5:30] = True  # 3 texels tall: no block is half on the chart
    height = np.random.default_rng(4).normal(size=valid.shape)
    variance = chart_level_variance(height, valid)
    assert variance[valid][0] == pytest.approx(np.var(height[valid]), rel=1e-12)
