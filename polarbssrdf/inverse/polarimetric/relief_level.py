"""The level of the recovered relief: what the views cannot see, set by the prior, with its spread.

The views see the displacement only through its slopes (supplement eq. 25), and the
slopes are differences within a chart (one-sided at its edge,
:func:`polarbssrdf.geometry.height.chart_neighbour_index`): a constant height added to
a chart tilts no normal and changes no data term. Of the priors, the magnitude prior
(eq. 33, ``mean(H^2)``, weak by design) sees it, and the Laplacian prior (eq. 34) at the
chart's edge, where it ties the relief to the base mesh
(:func:`~polarbssrdf.inverse.polarimetric.regularizers.displacement_laplacian`). The
truth's relief does not vanish at the edge (0.087 mm rms there on the demo face), so the
level that tie and the optimizer's path leave is off by 0.007-0.042 mm on the test
captures (0.020 mm rms over six), about the relief std's size (bench/RESULTS.md).

So the level is set by the magnitude prior alone, after the fit:

1. each chart's relief is shifted to that prior's level, mean 0 over the chart
   (:func:`relief_at_prior_level`), which leaves every normal as it is (0.013 mm rms
   from the truth's level over the same six captures);
2. its error is then the truth's own mean over the chart, which no view measures: its
   variance is estimated from the relief's variation at the chart's scale, by the method
   of batch means (:func:`chart_level_variance`; Künsch, Ann. Statist. 17, 1989, for
   blocks of a stationary field), its bias from neighbouring blocks' correlation
   extrapolated away, and added to every texel's variance of the relief.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

BLOCKS_PER_SIDE = 4
"""Blocks along a chart's longer side for :func:`chart_level_variance`: the block means
must be nearly independent (blocks wider than the relief's correlation), and there must
be enough of them to estimate their spread (about a dozen on the demo face)."""

MINIMUM_BLOCKS = 4
"""Fewer well-filled blocks than this: the chart is too small to tell its level's spread
from the relief's, and the level counts as unknown as a texel's relief."""


def chart_labels(valid):
    """``(labels, count)``: the charts of a texture, its 4-connected regions of valid texels
    (the neighbours eq. 25's differences and eq. 34's Laplacian use), numbered from 1."""
    return ndimage.label(np.asarray(valid, bool))


def relief_at_prior_level(height, valid):
    """``height`` (T, T) mm with each chart's mean set to 0 (module docstring, item 1);
    texels off the charts unchanged."""
    height = np.array(height, np.float64)
    labels, count = chart_labels(valid)
    if count == 0:
        return height
    means = ndimage.mean(height, labels, np.arange(1, count + 1))
    on_chart = labels > 0
    height[on_chart] -= means[labels[on_chart] - 1]
    return height


def _batch_means_variance(values, inside, blocks_per_side):
    """Variance of the mean of ``values`` over ``inside`` by batch means with blocks of
    ``1 / blocks_per_side`` of its longer side, or None with fewer than
    :data:`MINIMUM_BLOCKS` blocks at least half inside."""
    size = int(np.ceil(max(inside.shape) / blocks_per_side))
    means, counts = [], []
    for row in range(0, inside.shape[0], size):
        for col in range(0, inside.shape[1], size):
            block = inside[row:row + size, col:col + size]
            if block.sum() >= 0.5 * size * size:
                means.append(values[row:row + size, col:col + size][block].mean())
                counts.append(block.sum())
    if len(means) < MINIMUM_BLOCKS:
        return None
    return float(np.var(means, ddof=1) * np.mean(counts) / inside.sum())


def chart_level_variance(height, valid):
    """Per texel, the variance (mm^2) of its chart's unknown level (module docstring, item 2).

    Batch means over the chart's bounding box, blocks at least half on the chart: with
    :data:`BLOCKS_PER_SIDE` blocks per side the variance of the chart's mean is that of the
    block means times the mean block's texel count over the chart's. Block means of
    neighbouring blocks are correlated, which biases this low by about ``c / b`` for blocks
    of ``b`` texels; the estimate at ``b`` and at ``b / 2`` combine to cancel that term
    (``2 V_b - V_b/2``, not below ``V_b``). With fewer than :data:`MINIMUM_BLOCKS` blocks
    the chart's relief variance is used. Returns (T, T) float64, 0 off the charts.
    """
    height = np.asarray(height, np.float64)
    labels, _ = chart_labels(valid)
    out = np.zeros(height.shape)
    for chart, box in enumerate(ndimage.find_objects(labels), start=1):
        inside = labels[box] == chart
        values = height[box]
        coarse = _batch_means_variance(values, inside, BLOCKS_PER_SIDE)
        if coarse is None:
            variance = np.var(values[inside]) if inside.sum() > 1 else 0.0
        else:
            fine = _batch_means_variance(values, inside, 2 * BLOCKS_PER_SIDE)
            variance = coarse if fine is None else max(2.0 * coarse - fine, coarse)
        out[box][inside] = variance
    return out
