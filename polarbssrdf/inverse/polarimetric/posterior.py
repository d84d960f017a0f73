"""Per-texel posterior standard deviations of the polarimetric maps (a Gauss-Newton / Laplace posterior).

The static stage minimizes (supplement eq. 26-35, normalized as in
:mod:`polarbssrdf.inverse.polarimetric.losses`)

    L = sum_t w_t sum r^2 / N  +  sum_k lambda_k sum_i s_k,i^2 / n,

residuals ``r`` in units of the photometric noise over the patch's ``N``
texel-view-bands, regularizer residuals ``s`` over its ``n`` texels. Read as
a negative log posterior, ``N L / 2`` is one (the data terms a chi-square,
the regularizers Gaussian priors of precision ``kappa_k = lambda_k N / n``),
and its Laplace approximation at the fitted maps has the precision

    J^T W J (the data, per texel)  +  kappa_k A_k^T A_k (the priors, between texels).

What is computed, and the approximations made (each stated, none hidden):

1. **Per texel**, the Gauss-Newton information ``J^T W J`` of the data terms
   over the texel's parameters: ``eta, rho_s, alpha_s, rho_ss, alpha_ss``,
   the displacement's two slopes and ``rho_sss`` per band
   (:func:`texel_information`), from forward derivatives of the residuals
   (:func:`polarbssrdf.inverse.polarimetric.losses.data_residuals`) through
   the same model the fit steps with. Each map's data precision is the
   reciprocal of its diagonal element of the inverse: the texel's other
   parameters are marginalized, not held. A uniform prior over each map's
   bounds (variance ``range^2 / 12``) keeps a parameter the views do not
   see finite.
2. **Between texels**, the smoothness priors (eq. 33-35) couple a texel to
   its neighbours. Their effect on a texel's variance is taken from a field
   whose every texel has that texel's data precision ``d`` (a locally
   stationary approximation): ``var = mean_f 1 / (d + kappa |A(f)|^2)`` over
   the frequencies ``f`` of the patch, ``A(f)`` the stencil's transfer
   function (:func:`stationary_variance`). The displacement is seen only
   through its slopes (eq. 25): its precision at ``f`` is the slopes'
   ``d T^2 (sin^2 2 pi f_u + sin^2 2 pi f_v)`` plus the magnitude and
   Laplacian priors.
3. The fit's photometric noise is the one its last epoch measured
   (:func:`polarbssrdf.inverse.polarimetric.fit.epoch_noise`), so the
   precision is that of the residuals the model actually leaves.

This is the posterior of the model: error the model cannot see (light it
lacks, an optimizer that stopped short of the minimum) is not in it, which
is what the coverage of :mod:`polarbssrdf.inverse.evaluation.scores` measures.
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.polarimetric.config import OPTIMIZED
from polarbssrdf.inverse.polarimetric.losses import data_residuals
from polarbssrdf.inverse.polarimetric.model import GLOSSY_PARAMETERS
from polarbssrdf.inverse.polarimetric.optimize import (
    SLOPES,
    patch_leaves,
    predict_from_leaves,
    usable_views,
    window_regularizers,
)
from polarbssrdf.inverse.polarimetric.regularizers import BOX

TANGENTS = (*GLOSSY_PARAMETERS, *SLOPES)
"""The per texel-view parameters differentiated one at a time (``rho_sss`` is one more pass)."""

SMOOTHED = {"eta": "eta_smoothness", "alpha_s": "alpha_s_smoothness",
            "alpha_ss": "alpha_ss_smoothness"}
"""Maps under eq. 35's neighbourhood prior, with its weight's name."""

ALBEDO_RANGE = 1.0
"""Range of the uniform prior on ``rho_sss`` (an albedo is in [0, 1])."""

SLOPE_PRIOR_STD = 1e3
"""Std of the (vanishing) prior on a slope, per unit ``u`` (mm): only keeps the matrix regular."""

TABLE_POINTS = 160
"""Data precisions at which :func:`stationary_variance` is tabulated (log-spaced)."""


def uniform_prior_precision(low, high):
    """``12 / (high - low)^2``: the precision of a uniform prior over ``[low, high]``."""
    return 12.0 / float(high - low) ** 2


def _residuals(params, prepared, config, weights, noise, leaves, rho_sss, offsets, rho_offset):
    """Every data residual of a patch (a list of Float), each scaled by the square root of its
    term's weight, with the tangent ``offsets`` (and ``rho_offset`` on every band's albedo)."""
    stokes, normal, _ = predict_from_leaves(params, prepared, config, leaves, offsets)
    weight = usable_views(prepared, normal, config)
    Float = type(weight)
    residuals = []
    glossy_I_s = stokes.glossy[1]
    for band, observed in enumerate(prepared.observed):
        rho = dr.gather(Float, to_jit(Float, rho_sss[band], np.float32), prepared.texel)
        if rho_offset is not None:
            rho = rho + rho_offset
        terms = data_residuals(stokes.analyser_images(rho), observed, glossy_I_s, weight,
                               dr.opaque(Float, prepared.image_scale), dr.opaque(Float, noise))
        for name, values in terms.items():
            scale = float(weights.get(name, 0.0))
            if scale > 0.0:
                residuals += [dr.opaque(Float, np.sqrt(scale)) * value for value in values]
    return residuals, weight


def residual_jacobians(params, prepared, config, weights, noise):
    """Forward derivatives of every residual with respect to each per texel-view parameter.

    Returns ``(jacobians, band_of, usable, values)``: ``{tangent: (R, n_views) float64}``
    for every name of :data:`TANGENTS` and ``"rho_sss"`` (one pass: a band's
    residuals depend only on its own albedo, so one tangent on every band's
    albedo gives each band's derivative), ``band_of`` the band of each of
    the ``R`` residual rows, ``usable`` the texel-views' 0/1 weights and
    ``values`` the residuals themselves (R, n_views).
    """
    _, leaves = patch_leaves(params, prepared, differentiable=False)
    T = params.resolution
    rho_sss = params.rho_sss.reshape(len(params.rho_sss), T * T)[:, prepared.window_index]
    Float = type(leaves["eta"])
    jacobians, band_of, usable = {}, None, None
    for tangent in (*TANGENTS, "rho_sss"):
        offset = dr.zeros(Float, len(prepared))
        dr.enable_grad(offset)
        offsets = {} if tangent == "rho_sss" else {tangent: offset}
        residuals, weight = _residuals(params, prepared, config, weights, noise, leaves, rho_sss,
                                       offsets, offset if tangent == "rho_sss" else None)
        dr.forward_from(offset)
        derivatives = [dr.grad(value) for value in residuals]
        dr.eval(derivatives)
        jacobians[tangent] = np.stack([np.array(d, np.float64) for d in derivatives])
        if band_of is None:
            per_band = len(residuals) // max(len(prepared.observed), 1)
            band_of = np.repeat(np.arange(len(prepared.observed)), per_band)
            usable = np.array(weight, np.float64)
            values = np.stack([np.array(dr.detach(value), np.float64) for value in residuals])
    return jacobians, band_of, usable, values


def texel_information(params, prepared, config, weights, noise):
    """Per window texel, the Gauss-Newton information of the data terms over its parameters.

    Returns ``(information, gradient, usable_counts, chi_square)``:
    ``(n_window, P, P)`` float64 with ``P = len(TANGENTS) + n_bands`` (the
    order of :data:`TANGENTS`, then ``rho_sss`` per band), the gradient
    ``J^T r`` of half the chi-square (n_window, P), the usable texel-views
    per texel and the chi-square ``sum r^2`` itself per texel (n_window,).
    Derivatives that are not finite (a singular configuration of the model)
    count as 0, as in the fit's gradients.
    """
    jacobians, band_of, usable, values = residual_jacobians(params, prepared, config, weights,
                                                            noise)
    values = np.where(np.isfinite(values), values, 0.0)
    n_window = len(prepared.window_index)
    n_bands = len(prepared.observed)
    texel = np.asarray(prepared.texel_numpy)
    K = len(TANGENTS)
    P = K + n_bands
    for name, derivatives in jacobians.items():
        jacobians[name] = np.where(np.isfinite(derivatives), derivatives, 0.0)
    information = np.zeros((n_window, P, P))

    def per_texel(values):
        return np.bincount(texel, weights=values, minlength=n_window)

    gradient = np.zeros((n_window, P))
    for a in range(K):
        gradient[:, a] = per_texel(np.sum(jacobians[TANGENTS[a]] * values, axis=0))
        for b in range(a, K):
            entry = per_texel(np.sum(jacobians[TANGENTS[a]] * jacobians[TANGENTS[b]], axis=0))
            information[:, a, b] = information[:, b, a] = entry
    albedo = jacobians["rho_sss"]
    for band in range(n_bands):
        rows = band_of == band
        gradient[:, K + band] = per_texel(np.sum(albedo[rows] * values[rows], axis=0))
        information[:, K + band, K + band] = per_texel(np.sum(albedo[rows] ** 2, axis=0))
        for a in range(K):
            entry = per_texel(np.sum(jacobians[TANGENTS[a]][rows] * albedo[rows], axis=0))
            information[:, a, K + band] = information[:, K + band, a] = entry
    chi_square = per_texel(np.sum(np.square(values), axis=0))
    return information, gradient, per_texel(usable), chi_square


def prior_precisions(config, n_bands):
    """The diagonal precisions (P,) of the uniform priors over the bounds (and the slopes')."""
    glossy = [uniform_prior_precision(*config.bounds[name]) for name in GLOSSY_PARAMETERS]
    slopes = [1.0 / SLOPE_PRIOR_STD ** 2] * len(SLOPES)
    return np.array(glossy + slopes + [uniform_prior_precision(0.0, ALBEDO_RANGE)] * n_bands)


def marginal_variances(information, prior):
    """Per texel, the diagonal of ``(information + diag(prior))^-1`` (n, P), and the slopes'
    2 x 2 marginal precision's mean diagonal (n,)."""
    matrix = information + np.diag(prior)[None]
    inverse = np.linalg.inv(matrix)
    variances = np.diagonal(inverse, axis1=1, axis2=2).copy()
    k = len(GLOSSY_PARAMETERS)
    slope_covariance = inverse[:, k:k + 2, k:k + 2]
    slope_precision = np.linalg.inv(slope_covariance)
    return variances, 0.5 * (slope_precision[:, 0, 0] + slope_precision[:, 1, 1])


def _frequencies(shape):
    """Angular frequencies ``(omega_v, omega_u)`` (rad per texel) of a (rows, cols) grid."""
    omega_v = 2.0 * np.pi * np.fft.fftfreq(shape[0])[:, None]
    omega_u = 2.0 * np.pi * np.fft.fftfreq(shape[1])[None, :]
    return omega_v, omega_u


def neighbourhood_symbol_squared(shape):
    """``|A(f)|^2`` of eq. 35's residual ``p - mean of the 5 x 5 neighbours`` on a
    (rows, cols) grid."""
    omega_v, omega_u = _frequencies(shape)
    offsets = np.arange(-(BOX // 2), BOX // 2 + 1)

    def line_sum(omega):
        return np.sum(np.cos(omega[..., None] * offsets), axis=-1)

    neighbours = BOX * BOX - 1
    box = line_sum(omega_v) * line_sum(omega_u)
    return np.square(1.0 - (box - 1.0) / neighbours)


def laplacian_symbol_squared(shape):
    """``|A(f)|^2`` of the 5-point Laplacian (eq. 34) on a (rows, cols) grid."""
    omega_v, omega_u = _frequencies(shape)
    return np.square(2.0 * np.cos(omega_u) + 2.0 * np.cos(omega_v) - 4.0)


def slope_symbol_squared(shape):
    """``|A(f)|^2`` of the central-difference slopes (eq. 25) per unit of the window's ``u`` and
    ``v`` (a texel is ``1 / cols`` in ``u``, ``1 / rows`` in ``v``), summed over both."""
    omega_v, omega_u = _frequencies(shape)
    return shape[1] ** 2 * np.square(np.sin(omega_u)) + shape[0] ** 2 * np.square(np.sin(omega_v))


def _tabulated(data_precision, mean_over_frequencies):
    """``mean_over_frequencies(d)`` for each texel's ``d``, tabulated at :data:`TABLE_POINTS`
    log-spaced precisions and interpolated in log-log (NaN where ``d`` is not > 0), so the cost
    is that of the table, not of the texels."""
    d = np.asarray(data_precision, np.float64)
    out = np.full(d.shape, np.nan)
    good = np.isfinite(d) & (d > 0)
    if not good.any():
        return out
    low, high = np.log(d[good].min()), np.log(d[good].max())
    table = np.linspace(low, high if high > low else low + 1e-6, TABLE_POINTS)
    values = np.array([mean_over_frequencies(np.exp(x)) for x in table])
    floor = np.finfo(np.float64).tiny
    out[good] = np.exp(np.interp(np.log(d[good]), table, np.log(np.maximum(values, floor))))
    return out


def roughness_variance(observed, data_precision, data_symbol, fit_prior, stencil):
    """The truth's strength ``theta`` of a regularizer's residual, from the fitted map's.

    The fitted map at frequency ``f`` is ``x_hat = g (x + n)``, ``g = d S /
    (d S + P_fit)``, the truth ``x`` of variance ``theta / |A|^2`` (a prior
    of the regularizer's form whose strength ``theta`` is unknown) and the
    noise ``n`` of variance ``1 / (d S)``. The mean square of the
    regularizer's residual ``A x_hat`` is then linear in ``theta``:

        R = theta mean_f [|A| > 0] g^2 + mean_f |A|^2 g^2 / (d S)

    (the residual is blind to what ``A`` annihilates, the face's mean
    level), solved for ``theta`` with ``R`` the term's value on the fitted
    map, both means averaged over the texels' ``d``; at least 0 (the noise
    alone explains ``R``).
    """
    seen = np.asarray(stencil) > 0

    def gain(d):
        return d * data_symbol / (d * data_symbol + fit_prior)

    signal = _tabulated(data_precision, lambda d: np.mean(seen * np.square(gain(d))))
    noise = _tabulated(data_precision, lambda d: np.mean(
        stencil * np.square(gain(d)) / np.maximum(d * data_symbol, 1e-300)))
    good = np.isfinite(signal) & np.isfinite(noise)
    if not good.any():
        return 0.0
    return max((float(observed) - float(np.mean(noise[good]))) / float(np.mean(signal[good])), 0.0)


def estimator_variance(data_precision, data_symbol, fit_prior, true_prior):
    """Per texel, ``mean_f (d S + P_fit^2 / P_true) / (d S + P_fit)^2``: the error variance of
    the map the fit returns (regularized with ``P_fit``) when the truth follows ``P_true``.

    With ``P_true = P_fit`` this is the posterior variance ``mean_f 1 / (d S +
    P)``; a regularizer stronger than the truth's roughness adds the bias it
    causes (the detail it flattens). ``S``, ``P_fit``, ``P_true``: (rows, cols)
    arrays or scalars over the patch's frequencies (approximation 2 above).
    """

    def mean(d):
        data = d * data_symbol
        return np.mean((data + np.square(fit_prior) / true_prior) / np.square(data + fit_prior))

    return _tabulated(data_precision, mean)


def regularizer_precision(weights, name, information_count, interior_count):
    """``kappa = lambda N / n`` of a regularizer term (module docstring) on one patch."""
    return float(weights.get(name, 0.0)) * information_count / max(interior_count, 1)


def spatial_variance(observed, data_precision, data_symbol, kappa, stencil, floor):
    """:func:`estimator_variance` of a map under a regularizer ``kappa |A|^2`` (plus the
    frequency-flat ``floor``: the uniform prior, the magnitude prior), the truth's strength
    from :func:`roughness_variance` on the regularizer's ``observed`` value."""
    fit_prior = kappa * stencil + floor
    theta = roughness_variance(observed, data_precision, data_symbol, fit_prior, stencil)
    true_prior = stencil / max(theta, 1e-300) + floor
    return estimator_variance(data_precision, data_symbol, fit_prior, true_prior)


def patch_posterior_std(params, prepared, config, weights, noise):
    """Posterior std of every map over a patch's window: ``{map or ("rho_sss", band):
    (n_window,)}`` (NaN where the window's texel is off the surface or unseen)."""
    information, _, counts, _ = texel_information(params, prepared, config, weights, noise)
    n_bands = len(prepared.observed)
    prior = prior_precisions(config, n_bands)
    variances, slope_precision = marginal_variances(information, prior)
    seen = (counts > 0) & prepared.window_valid.ravel()
    shape = prepared.window_valid.shape
    stencils = prepared.stencils
    used = float(np.sum(counts)) * n_bands
    windows = {name: np.array(params.to_numpy()[name].ravel()[prepared.window_index], np.float64)
               for name in OPTIMIZED}
    observed, _ = window_regularizers(windows, prepared, {}, ())
    std = {}
    for index, name in enumerate(GLOSSY_PARAMETERS):
        if name not in params.optimized:
            continue
        variance = variances[:, index]
        if name in SMOOTHED:
            # the data's share of the precision (rounding can leave it a hair below 0)
            data = np.maximum(1.0 / variance - prior[index], 1e-9 * prior[index])
            variance = spatial_variance(
                observed[SMOOTHED[name]], np.where(seen, data, np.nan), 1.0,
                regularizer_precision(weights, SMOOTHED[name], used, stencils.count),
                neighbourhood_symbol_squared(shape), prior[index])
        std[name] = np.sqrt(variance)
    if "displacement" in params.optimized:
        floor = (regularizer_precision(weights, "H_magnitude", used, stencils.count)
                 + uniform_prior_precision(*config.bounds["displacement"]))
        variance = spatial_variance(
            observed["H_laplacian"], np.where(seen, slope_precision, np.nan),
            slope_symbol_squared(shape),
            regularizer_precision(weights, "H_laplacian", used, stencils.count),
            laplacian_symbol_squared(shape), floor)
        std["displacement"] = np.sqrt(variance)
    K = len(TANGENTS)
    for band in range(n_bands):
        std[("rho_sss", band)] = np.sqrt(variances[:, K + band])
    for key, values in std.items():
        std[key] = np.where(seen, values, np.nan)
    return std


def map_posterior_std(params, cache, patches, config, weights, noise, band_names):
    """Posterior std of every fitted map over the texture: ``{"<map>_std": (T, T) float32}``.

    ``rho_sss`` per band as ``rho_sss.<band>_std``. Each patch sets its own
    texels (not its halo's); texels no usable view sees are NaN (the stages
    replace them, see :func:`polarbssrdf.inverse.polarimetric.fit.final_maps`).
    Memory is that of one patch's Jacobians.
    """
    T = params.resolution
    out = {}
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared) == 0:
            continue
        std = patch_posterior_std(params, prepared, config, weights, noise)
        interior = prepared.stencils.interior.ravel() > 0
        texels = prepared.window_index[interior]
        for key, values in std.items():
            channel = (f"rho_sss.{band_names[key[1]]}_std" if isinstance(key, tuple)
                       else f"{key}_std")
            if channel not in out:
                out[channel] = np.full(T * T, np.nan)
            out[channel][texels] = values[interior]
    return {channel: values.reshape(T, T).astype(np.float32) for channel, values in out.items()}
