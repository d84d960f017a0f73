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
4. **The displacement's noise is the cameras' disagreement.** The slopes
   integrate into the relief, so error that is the same in the neighbouring
   texels of one camera (interreflection, a shadow's edge, a glossy level
   that is off: light the per-texel model lacks) accumulates at low
   frequencies, where the model's independent noise accounts for 1/40 to
   1/80 of the relief's error power on the demo (wavelengths above 30
   texels). Its power per frequency is taken from the cameras' scores at
   the fitted maps, a clustered (sandwich) variance with the cameras as
   clusters and the jackknife's leverage correction
   (:func:`displacement_noise_inflation`); on the demo captures it took the
   displacement's 2-std coverage from 0.30-0.43 to 0.87-0.92 (bench/RESULTS.md).
   The capture's blur (:func:`blur_transfer`, ``config.capture_blur_mm``)
   hides relief finer than the pixels' footprint: the std counts that detail
   as the prior's.
5. **The relief's level** over each chart, which no view sees, is added by the
   static stage (:mod:`polarbssrdf.inverse.polarimetric.relief_level`), not here.

Error the cameras share and an optimizer that stopped short of the minimum
are not in it, which is what the coverage of
:mod:`polarbssrdf.inverse.evaluation.scores` measures.
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
    jacobians, values = finite_jacobians(jacobians, values)
    return information_from_jacobians(jacobians, band_of, usable, values, prepared)


def finite_jacobians(jacobians, values):
    """``(jacobians, values)`` with what is not finite set to 0 (copies)."""
    return ({name: np.where(np.isfinite(d), d, 0.0) for name, d in jacobians.items()},
            np.where(np.isfinite(values), values, 0.0))


def texel_view_scores(jacobians, band_of, values):
    """``J^T r`` of each texel-view (N, P): the derivative of half its chi-square with respect
    to its texel's parameters (the order of :func:`texel_information`), from
    :func:`residual_jacobians`' outputs made finite (:func:`finite_jacobians`)."""
    n_bands = int(band_of.max()) + 1 if len(band_of) else 0
    K = len(TANGENTS)
    scores = np.zeros((values.shape[1], K + n_bands))
    for a, name in enumerate(TANGENTS):
        scores[:, a] = np.sum(jacobians[name] * values, axis=0)
    for band in range(n_bands):
        rows = band_of == band
        scores[:, K + band] = np.sum(jacobians["rho_sss"][rows] * values[rows], axis=0)
    return scores


def information_from_jacobians(jacobians, band_of, usable, values, prepared, scores=None):
    """:func:`texel_information` from :func:`residual_jacobians`' outputs made finite
    (:func:`finite_jacobians`), so one pass of derivatives serves the information and
    :func:`displacement_noise_inflation`; ``scores``: their :func:`texel_view_scores`
    when the caller has them."""
    n_window = len(prepared.window_index)
    n_bands = len(prepared.observed)
    texel = np.asarray(prepared.texel_numpy)
    K = len(TANGENTS)
    P = K + n_bands
    information = np.zeros((n_window, P, P))

    def per_texel(values):
        return np.bincount(texel, weights=values, minlength=n_window)

    if scores is None:
        scores = texel_view_scores(jacobians, band_of, values)
    gradient = np.stack([per_texel(scores[:, a]) for a in range(P)], axis=1)
    for a in range(K):
        for b in range(a, K):
            entry = per_texel(np.sum(jacobians[TANGENTS[a]] * jacobians[TANGENTS[b]], axis=0))
            information[:, a, b] = information[:, b, a] = entry
    albedo = jacobians["rho_sss"]
    for band in range(n_bands):
        rows = band_of == band
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


def roughness_variance(observed, data_precision, data_symbol, fit_prior, stencil,
                       noise_inflation=1.0, transfer=1.0):
    """The truth's strength ``theta`` of a regularizer's residual, from the fitted map's.

    The fitted map at frequency ``f`` is ``x_hat = g (m x + n)``, ``g = d S /
    (d S + P_fit)``, the truth ``x`` of variance ``theta / |A|^2`` (a prior
    of the regularizer's form whose strength ``theta`` is unknown), ``m`` the
    capture's ``transfer`` of it into the data (its blur, :func:`blur_transfer`;
    1 for sharp data) and the noise ``n`` of variance ``c / (d S)``, ``c`` the
    ``noise_inflation`` (:func:`view_noise_inflation`; 1 for the noise the
    model assumes). The mean square of the regularizer's residual ``A x_hat``
    is then linear in ``theta``:

        R = theta mean_f [|A| > 0] g^2 m^2 + mean_f c |A|^2 g^2 / (d S)

    (the residual is blind to what ``A`` annihilates, the face's mean
    level), solved for ``theta`` with ``R`` the term's value on the fitted
    map, both means averaged over the texels' ``d``; at least 0 (the noise
    alone explains ``R``).
    """
    seen = np.asarray(stencil) > 0

    def gain(d):
        return d * data_symbol / (d * data_symbol + fit_prior)

    signal = _tabulated(data_precision, lambda d: np.mean(seen * np.square(gain(d) * transfer)))
    noise = _tabulated(data_precision, lambda d: np.mean(
        noise_inflation * stencil * np.square(gain(d)) / np.maximum(d * data_symbol, 1e-300)))
    good = np.isfinite(signal) & np.isfinite(noise)
    if not good.any():
        return 0.0
    return max((float(observed) - float(np.mean(noise[good]))) / float(np.mean(signal[good])), 0.0)


def estimator_variance(data_precision, data_symbol, fit_prior, true_prior, noise_inflation=1.0,
                       transfer=1.0):
    """Per texel, ``mean_f [(1 - g m)^2 / P_true + c g^2 / (d S)]``, ``g = d S / (d S +
    P_fit)``: the error variance of the map the fit returns (regularized with ``P_fit``)
    when the truth follows ``P_true``, reaches the data through the ``transfer`` ``m`` and
    the noise is ``noise_inflation`` ``c`` times the model's (:func:`roughness_variance`).

    With ``P_true = P_fit`` and ``c = m = 1`` this is the posterior variance
    ``mean_f 1 / (d S + P)``; a regularizer stronger than the truth's roughness
    adds the bias it causes (the detail it flattens), and a blur ``m < 1`` the
    detail the data never showed. ``S``, ``P_fit``, ``P_true``, ``c``, ``m``:
    (rows, cols) arrays or scalars over the patch's frequencies (approximation 2
    above).
    """

    def mean(d):
        data = d * data_symbol
        gain = data / (data + fit_prior)
        return np.mean(np.square(1.0 - gain * transfer) / true_prior
                       + noise_inflation * np.square(gain) / np.maximum(data, 1e-300))

    return _tabulated(data_precision, mean)


def regularizer_precision(weights, name, information_count, interior_count):
    """``kappa = lambda N / n`` of a regularizer term (module docstring) on one patch."""
    return float(weights.get(name, 0.0)) * information_count / max(interior_count, 1)


def spatial_variance(observed, data_precision, data_symbol, kappa, stencil, floor,
                     noise_inflation=1.0, transfer=1.0):
    """:func:`estimator_variance` of a map under a regularizer ``kappa |A|^2`` (plus the
    frequency-flat ``floor``: the uniform prior, the magnitude prior), the truth's strength
    from :func:`roughness_variance` on the regularizer's ``observed`` value."""
    fit_prior = kappa * stencil + floor
    theta = roughness_variance(observed, data_precision, data_symbol, fit_prior, stencil,
                               noise_inflation, transfer)
    true_prior = stencil / max(theta, 1e-300) + floor
    return estimator_variance(data_precision, data_symbol, fit_prior, true_prior,
                              noise_inflation, transfer)


def efficient_slope_scores(scores, information, prior, texel):
    """Each texel-view's score on its texel's two slopes with the texel's other parameters
    projected out (N, 2): ``g_s - M_so M_oo^-1 g_o``, ``M`` the texel's information plus
    ``diag(prior)`` (the efficient score; summed over a texel's views its covariance is the
    slopes' marginal precision when the residuals are the noise the model assumes).

    ``scores`` (N, P) from :func:`texel_view_scores`, ``information`` (n_window, P, P),
    ``texel`` (N,) the window texel of each texel-view.
    """
    slopes = [TANGENTS.index(name) for name in SLOPES]
    others = [index for index in range(scores.shape[1]) if index not in slopes]
    matrix = information + np.diag(prior)[None]
    m_so = matrix[:, slopes][:, :, others]
    m_oo = matrix[:, others][:, :, others]
    # M_so M_oo^-1 per texel, as the solve of M_oo X = M_os (M_oo is symmetric)
    projection = np.swapaxes(np.linalg.solve(m_oo, np.swapaxes(m_so, 1, 2)), 1, 2)
    return scores[:, slopes] - np.einsum("tsk,tk->ts", projection[texel], scores[:, others])


def camera_slope_share(jacobians, texel, camera, n_window):
    """The share ``h`` (N,) of its texel's slope information that each texel-view's camera
    gives: the camera's sum of squared slope derivatives at the texel over all of the
    texel's (its weight in the texel's slopes)."""
    per_view = sum(np.sum(np.square(jacobians[name]), axis=0) for name in SLOPES)
    key = texel.astype(np.int64) * (int(camera.max()) + 1 if len(camera) else 1) + camera
    _, group = np.unique(key, return_inverse=True)
    by_camera = np.bincount(group, weights=per_view)[group]
    by_texel = np.bincount(texel, weights=per_view, minlength=n_window)[texel]
    return by_camera / np.maximum(by_texel, 1e-300)


LEVERAGE_LIMIT = 0.9
"""Largest camera share :func:`camera_score_power` divides by ``1 - h`` for: a texel one camera
sees alone tells nothing of the cameras' disagreement (its centred score is 0)."""


def camera_score_power(efficient, share, camera, texel, shape, jackknife=True):
    """``sum_c |B_c(f)|^2`` (rows, cols): the power at each frequency of the displacement's
    score from each camera ``c`` of the window, ``B_c = conj(K_u) E_u + conj(K_v) E_v``,
    ``E`` the camera's centred efficient slope scores per texel and ``K`` the
    central-difference slopes' transfer function (:func:`slope_symbol_squared`).

    ``efficient`` (N, 2) from :func:`efficient_slope_scores`, ``share`` (N,) from
    :func:`camera_slope_share`. A camera's score is centred by its share of the texel's
    total, ``e_c - h_c sum_j e_j``: at a texel whose slopes weigh the cameras by ``h``
    this is ``d_c (s_mean - s_c)``, the camera's departure from the texel's weighted
    mean slope, and the regularizers' force (the total score's share at the fitted
    maps) drops out. With ``jackknife``, the centred score is divided by ``1 - h_c``,
    which makes it the departure from the mean of the other cameras: the jackknife's
    leverage correction of a clustered variance (CR3; MacKinnon and White 1985, Bell and
    McCaffrey 2002). It is conservative, ``sum_c h_c / (1 - h_c)`` of the error's power
    for independent cameras where the plain centred scores (CR0) give ``1 - sum_c
    h_c^2``; with a face's few, unequal cameras the unbiased CR2 still under-covers
    (MacKinnon, Nielsen and Webb 2023).
    """
    omega_v, omega_u = _frequencies(shape)
    k_u = 1j * shape[1] * np.sin(omega_u)
    k_v = 1j * shape[0] * np.sin(omega_v)
    n_window = shape[0] * shape[1]
    total = np.stack([np.bincount(texel, weights=efficient[:, axis], minlength=n_window)
                      for axis in (0, 1)], axis=1)
    centred = efficient - share[:, None] * total[texel]
    if jackknife:
        centred = centred / (1.0 - np.minimum(share, LEVERAGE_LIMIT))[:, None]
    power = np.zeros(shape)
    for index in np.unique(camera):
        rows = camera == index
        e_u, e_v = (np.bincount(texel[rows], weights=centred[rows, axis],
                                minlength=n_window).reshape(shape) for axis in (0, 1))
        score = np.conj(k_u) * np.fft.fft2(e_u) + np.conj(k_v) * np.fft.fft2(e_v)
        power += np.square(np.abs(score))
    return power


def view_noise_inflation(power, model_power):
    """``c(f) = P(f) / (d S(f))`` (rows, cols): at each frequency the cameras' score power
    (:func:`camera_score_power`, per seen texel) over the model's, 1 where the slopes see
    nothing (``S = 0``: the mean level, the Nyquist lines).

    Under the model's noise the cameras' scores are independent and ``c = 1``. Light
    the per-texel model lacks (interreflection, a shadow's edge, a glossy level that is
    off) is the same in the neighbouring texels of one camera and differs between
    cameras: it raises the power of the low frequencies, which the slopes integrate
    into the relief; the images' blur correlates the noise of neighbouring texels and
    lowers the power of the high ones. This is the clustered (sandwich) variance of
    the scores (Liang and Zeger 1986) with the cameras as clusters, per frequency as
    Whittle's approximation takes a stationary field's. One frequency's estimate is
    noisy (a few cameras' powers); the variance averages it over every frequency
    (:func:`estimator_variance`). Error the cameras share is not in it.
    """
    positive = model_power > 0
    return np.where(positive, power / np.where(positive, model_power, 1.0), 1.0)


def blur_transfer(shape, blur_texels2):
    """``m(f) = exp(-(s_u omega_u^2 + s_v omega_v^2) / 2)`` (rows, cols): the transfer of a
    Gaussian blur of variance ``blur_texels2 = (s_u, s_v)`` (texels^2 along ``u`` and ``v``)
    on the window's frequencies; 1 for ``None``."""
    if blur_texels2 is None:
        return 1.0
    omega_v, omega_u = _frequencies(shape)
    s_u, s_v = (float(value) for value in blur_texels2)
    return np.exp(-0.5 * (s_u * np.square(omega_u) + s_v * np.square(omega_v)))


def displacement_noise_inflation(jacobians, scores, information, prior, prepared,
                                 slope_precision, seen):
    """:func:`view_noise_inflation` of a window's displacement from one pass of
    :func:`residual_jacobians` made finite (``jacobians``) and its texel-views'
    :func:`texel_view_scores`, the texels' ``information``, the parameters' ``prior``
    precisions, the slopes' marginal precision per texel and the ``seen`` texels of the
    window."""
    shape = prepared.window_valid.shape
    if not np.any(seen):
        return np.ones(shape)
    texel = np.asarray(prepared.texel_numpy)
    camera = np.asarray(prepared.camera_numpy)
    efficient = efficient_slope_scores(scores, information, prior, texel)
    share = camera_slope_share(jacobians, texel, camera, len(prepared.window_index))
    n_seen = max(int(np.sum(seen)), 1)
    power = camera_score_power(efficient, share, camera, texel, shape) / n_seen
    model_power = float(np.mean(slope_precision[seen])) * slope_symbol_squared(shape)
    return view_noise_inflation(power, model_power)


def patch_posterior_std(params, prepared, config, weights, noise, blur_texels2=None):
    """Posterior std of every map over a patch's window: ``{map or ("rho_sss", band):
    (n_window,)}`` (NaN where the window's texel is off the surface or unseen).

    ``blur_texels2``: the capture's blur along ``u`` and ``v`` (texels^2, see
    :func:`blur_transfer`) that the displacement's std accounts for; ``None``: sharp data.
    """
    jacobians, band_of, usable, values = residual_jacobians(params, prepared, config, weights,
                                                            noise)
    jacobians, values = finite_jacobians(jacobians, values)
    scores = texel_view_scores(jacobians, band_of, values)
    information, _, counts, _ = information_from_jacobians(jacobians, band_of, usable, values,
                                                           prepared, scores)
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
        inflation = displacement_noise_inflation(jacobians, scores, information, prior,
                                                 prepared, slope_precision, seen)
        variance = spatial_variance(
            observed["H_laplacian"], np.where(seen, slope_precision, np.nan),
            slope_symbol_squared(shape),
            regularizer_precision(weights, "H_laplacian", used, stencils.count),
            laplacian_symbol_squared(shape), floor, inflation,
            blur_transfer(shape, blur_texels2))
        std["displacement"] = np.sqrt(variance)
    K = len(TANGENTS)
    for band in range(n_bands):
        std[("rho_sss", band)] = np.sqrt(variances[:, K + band])
    for key, values in std.items():
        std[key] = np.where(seen, values, np.nan)
    return std


def map_posterior_std(params, cache, patches, config, weights, noise, band_names,
                      blur_texels2=None):
    """Posterior std of every fitted map over the texture: ``{"<map>_std": (T, T) float32}``.

    ``rho_sss`` per band as ``rho_sss.<band>_std``. Each patch sets its own
    texels (not its halo's); texels no usable view sees are NaN (the stages
    replace them, see :func:`polarbssrdf.inverse.polarimetric.fit.final_maps`).
    ``blur_texels2`` as in :func:`patch_posterior_std`. Memory is that of one patch's
    Jacobians.
    """
    T = params.resolution
    out = {}
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared) == 0:
            continue
        std = patch_posterior_std(params, prepared, config, weights, noise, blur_texels2)
        interior = prepared.stencils.interior.ravel() > 0
        texels = prepared.window_index[interior]
        for key, values in std.items():
            channel = (f"rho_sss.{band_names[key[1]]}_std" if isinstance(key, tuple)
                       else f"{key}_std")
            if channel not in out:
                out[channel] = np.full(T * T, np.nan)
            out[channel][texels] = values[interior]
    return {channel: values.reshape(T, T).astype(np.float32) for channel, values in out.items()}
