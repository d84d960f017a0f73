"""The chromophore fields' correlation length, estimated from the input albedo (issue 20).

The Matérn prior of :mod:`~polarbssrdf.inverse.biophysical.prior` needs a
correlation length ``l``. A fixed one is a guess about the face: on synthetic
faces whose fields are smoother than the default's 5 mm, a length of 8 mm took
``C_h_in``'s error from 0.63 to 0.46 of the constant map's (bench/RESULTS.md,
2026-12-02). The albedo itself tells it. The chromophores are fields of
length ``l``; the log albedo of each band is, to first order, a linear
combination of them, so its covariance between texels a distance ``r`` apart
is ``s^2 rho(r / l)`` with ``rho`` the prior's own correlation function
(:func:`matern_correlation_shape`), while white noise, and the correlation the
resampling of images into texture space leaves between neighbours, add
nothing at lags of two texels and more. :func:`albedo_correlation_length` is
the least-squares fit of ``(s^2, l)`` to the band-summed empirical
covariance at those lags (:func:`lattice_covariance`): a method-of-moments
estimate, as a variogram fit in geostatistics (Cressie, Statistics for Spatial
Data, 1993, sec. 2.6), not a marginal likelihood.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize, special

from polarbssrdf.inverse.biophysical.prior import DEFAULT_CORRELATION_MM

MINIMUM_LAG = 2
"""Shortest lag (texels) in the fit: the resampling of images into texture space correlates
the demo's albedo error 0.43 between neighbours and 0.04 two texels apart (bench/RESULTS.md)."""

MAXIMUM_DISTANCE_MM = 40.0
"""Longest lag in the fit (mm): a few correlation lengths of the fields a face has."""

LENGTH_BOUNDS_MM = (1.0, 30.0)
"""The estimate is kept in this range (mm); the fit's result metadata says when it hit a bound."""

MINIMUM_PAIRS = 100
"""A lag with fewer texel pairs (a small atlas's longest lags) does not enter the fit."""


def matern_correlation_shape(distance_mm, correlation_mm, order=2):
    """``x^nu K_nu(x)``, ``x = r / l``: the Matérn correlation up to its scale (unitless).

    The prior ``(1 - l^2 Laplacian)^order x = white noise`` in two dimensions is a
    Matérn field of smoothness ``nu = order - 1`` and range ``l`` (Lindgren, Rue and
    Lindström, J. R. Stat. Soc. B 73, 2011, eq. 2 with ``kappa = 1 / l``, ``alpha =
    order``); its correlation is ``x^nu K_nu(x) 2^(1 - nu) / Gamma(nu)``, whose constant
    (infinite for ``nu = 0``) a fit of the scale absorbs. ``distance_mm`` > 0."""

    nu = int(order) - 1
    x = np.maximum(np.asarray(distance_mm, np.float64) / float(correlation_mm), 1e-12)
    return x ** nu * special.kv(nu, x)


def _runs(valid, axis):
    """Length of the run of valid texels ending at each texel along ``axis`` (0 where invalid)."""
    valid = np.moveaxis(np.asarray(valid, bool), axis, -1)
    run = np.zeros(valid.shape, np.int64)
    run[..., 0] = valid[..., 0]
    for i in range(1, valid.shape[-1]):
        run[..., i] = (run[..., i - 1] + 1) * valid[..., i]
    return np.moveaxis(run, -1, axis)


def lattice_covariance(fields, valid, texel_size_mm, minimum_lag=MINIMUM_LAG, maximum_distance_mm=MAXIMUM_DISTANCE_MM):
    """``(distance_mm, covariance, pairs)`` per horizontal and vertical lag of the band-summed fields.

    Parameters
    ----------
    fields : (B, T, T) float
        Zero-mean fields (their mean over ``valid`` removed); the covariance is summed over ``B``.
    valid : (T, T) bool
    texel_size_mm : (T, T, 2) float
        Texel extent along ``u`` (the grid's columns) and ``v`` (its rows), mm.

    A pair enters only where every texel between its two is valid, so no pair
    spans a gap between charts. Its distance is the lag times the mean extent of
    its two texels along the lag."""

    fields = np.asarray(fields, np.float64)
    valid = np.asarray(valid, bool)
    sizes = np.asarray(texel_size_mm, np.float64)
    typical = float(np.median(sizes[valid])) if valid.any() else 1.0
    longest = int(min(maximum_distance_mm / max(typical, 1e-9), valid.shape[0] // 2))
    distance, covariance, pairs = [], [], []
    for axis, extent in ((1, sizes[..., 0]), (0, sizes[..., 1])):
        runs = _runs(valid, axis)
        for lag in range(int(minimum_lag), longest + 1):
            first = [slice(None), slice(None)]
            second = [slice(None), slice(None)]
            first[axis], second[axis] = slice(0, -lag), slice(lag, None)
            first, second = tuple(first), tuple(second)
            joined = runs[second] > lag
            count = int(joined.sum())
            if count < MINIMUM_PAIRS:
                continue
            product = np.sum(fields[(slice(None),) + first] * fields[(slice(None),) + second], axis=0)
            distance.append(float(np.mean(lag * 0.5 * (extent[first] + extent[second])[joined])))
            covariance.append(float(np.mean(product[joined])))
            pairs.append(count)
    return np.array(distance), np.array(covariance), np.array(pairs, np.float64)


def fitted_correlation_length(distance_mm, covariance, pairs, order=2, bounds=LENGTH_BOUNDS_MM):
    """``(l, s^2)``: the least-squares fit of ``s^2`` :func:`matern_correlation_shape` to a covariance.

    Each lag is weighted by its number of pairs; ``s^2`` is solved in closed form
    for each ``l`` (a one-dimensional search over ``ln l`` within ``bounds``, mm)."""

    distance_mm, covariance, pairs = (np.asarray(a, np.float64) for a in (distance_mm, covariance, pairs))
    if distance_mm.size < 3:
        raise ValueError(f"{distance_mm.size} lags: too few to fit a correlation length (3 needed)")

    def scale(length):
        shape = matern_correlation_shape(distance_mm, length, order)
        return max(float(np.sum(pairs * shape * covariance) / np.sum(pairs * shape * shape)), 0.0), shape

    def misfit(log_length):
        s2, shape = scale(np.exp(log_length))
        return float(np.sum(pairs * (covariance - s2 * shape) ** 2))

    grid = np.linspace(np.log(bounds[0]), np.log(bounds[1]), 64)
    best = int(np.argmin([misfit(g) for g in grid]))
    low, high = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    length = float(np.exp(optimize.minimize_scalar(misfit, bounds=(low, high), method="bounded").x))
    return length, scale(length)[0]


def albedo_correlation_length(rbar, valid, texel_size_mm, order=2):
    """``(l, figures)``: the chromophore fields' correlation length (mm) from the input's albedo.

    ``rbar`` (B, T, T): the skin model's flux per band (positive); its log, less
    its mean over ``valid`` per band, is the field whose covariance
    :func:`fitted_correlation_length` fits. ``figures`` (for the result's
    metadata): ``l``, the fitted scale ``s^2``, whether ``l`` sits at a bound of
    :data:`LENGTH_BOUNDS_MM`, the number of lags and the longest lag (mm). With fewer
    than 3 lags of :data:`MINIMUM_PAIRS` pairs (a map of a few texels, or charts a
    few texels wide) ``l`` is the prior's default
    (:data:`~polarbssrdf.inverse.biophysical.prior.DEFAULT_CORRELATION_MM`) and
    ``figures["note"]`` says so."""

    valid = np.asarray(valid, bool)
    logs = np.log(np.clip(np.asarray(rbar, np.float64), 1e-6, None))
    means = np.array([band[valid].mean() for band in logs])
    fields = np.where(valid[None], logs - means[:, None, None], 0.0)
    distance, covariance, pairs = lattice_covariance(fields, valid, texel_size_mm)
    if distance.size < 3:  # a map too small or too fragmented to tell: the prior's usual length
        return DEFAULT_CORRELATION_MM, {"correlation_mm": DEFAULT_CORRELATION_MM, "scale": None, "at_bound": False,
                                        "lags": int(distance.size), "longest_mm": None,
                                        "note": "too few lags to fit: the default length"}
    length, s2 = fitted_correlation_length(distance, covariance, pairs, order)
    at_bound = bool(np.isclose(length, LENGTH_BOUNDS_MM[0], rtol=0.02) or np.isclose(length, LENGTH_BOUNDS_MM[1], rtol=0.02))
    return length, {"correlation_mm": round(length, 3), "scale": s2, "at_bound": at_bound,
                    "lags": int(distance.size), "longest_mm": round(float(distance.max()), 2)}
