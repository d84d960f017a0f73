"""Calibration of posterior standard deviations against the truth (the report's coverage plot).

A map with a per-texel posterior standard deviation ``std`` (same unit as
the map) is calibrated when its errors behave like Gaussian draws of that
width: the fraction of texels with ``|recovered - truth| < k std`` is then
``erf(k / sqrt 2)`` for every ``k``.
"""

from __future__ import annotations

from math import erf, sqrt

import numpy as np

COVERAGE_K = tuple(float(k) for k in np.round(np.arange(0.25, 3.0001, 0.25), 2))
"""Multiples k of the posterior standard deviation at which coverage is measured (0.25 to 3)."""


def expected_coverage(ks=COVERAGE_K):
    """``erf(k / sqrt 2)``: the fraction of a Gaussian within ``k`` standard deviations (unitless)."""
    return np.array([erf(k / sqrt(2.0)) for k in ks])


def coverage_fractions(recovered, truth, std, mask, ks=COVERAGE_K):
    """Observed coverage: for each ``k`` of ``ks``, the fraction of texels with
    ``|recovered - truth| < k std``.

    ``recovered``, ``truth``, ``std``: arrays in one unit; only texels in
    ``mask`` with finite values and ``std > 0`` count. Returns ``(fractions,
    texels)``: an array of ``len(ks)`` fractions (NaN when no texel counts) and
    the number of texels counted.
    """
    recovered, truth, std = (np.asarray(a, np.float64) for a in (recovered, truth, std))
    use = (np.asarray(mask, bool) & np.isfinite(recovered) & np.isfinite(truth)
           & np.isfinite(std) & (std > 0))
    count = int(use.sum())
    if not count:
        return np.full(len(ks), np.nan), 0
    z = np.abs(recovered[use] - truth[use]) / std[use]
    return np.array([np.mean(z < k) for k in ks]), count
