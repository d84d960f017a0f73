"""The biophysical fit's uncertainty: the posterior covariance of the maps per texel, the noise
re-estimated from the residuals, and the noise's correlation between texels.

* :func:`posterior_blocks`: the Laplace posterior of the Gauss-Newton fit (its data precision
  per texel, the Matérn prior and the face means' uncertainty), per texel;
* :func:`calibrated_noise`: the bands' own and band-common noise from the residuals, corrected
  for the degrees of freedom the maps spend;
* :func:`residual_correlation`: how the whitened residuals correlate between neighbouring
  texels (the sandwich term of the reported std).
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.inverse.biophysical.prior import (
    held_map_error_covariance,
    known_mean_covariance,
    mean_mode_covariance,
)


def posterior_blocks(data, prior, maps, movable, spectrum=None, held=0):
    """``(covariance (n, k, k), C, J_z, mean covariance (k, k))`` of the fitted maps
    (``prior.names``) per movable texel.

    ``C`` is the data precision per texel and ``J_z`` the Jacobian in the data term's
    whitened units (:meth:`~polarbssrdf.inverse.biophysical.problem.DataTerm.precision`);
    the covariance is the zone average of ``(C + Q)^-1`` over the Matérn prior's spectrum
    (:func:`~polarbssrdf.inverse.biophysical.prior.posterior_covariance`, the sandwich form
    with a noise ``spectrum``) plus what the free face means add
    (:func:`~polarbssrdf.inverse.biophysical.prior.mean_mode_covariance`). Without a spatial
    prior, the data term's own pseudo-inverse per texel (a direction the bands do not see
    has no finite spread; the caller clips it to the map's range). A texel where a feature frees
    the prior (:attr:`~.gauss_newton.PriorTerms.coupling`) takes its own spread and correlation
    length, the capture's blur enters through ``prior.gain``.

    ``held`` > 0: the last ``held`` of ``prior.names`` are maps the fit did not estimate (held
    at their face values); the covariance is then that of the other maps' error
    (:func:`~polarbssrdf.inverse.biophysical.prior.held_map_error_covariance`, shape
    ``(n, k - held, k - held)``), the face means' part still the joint posterior's."""

    names = prior.names
    C, J = data.precision(maps, names, movable)
    k = len(names)
    if prior.spatial is None:
        return np.linalg.pinv(C, hermitian=True), C, J, np.zeros((k, k))
    area = prior.spatial.area
    fitted = k - int(held)
    covariance = held_map_error_covariance(C, held, area, prior.local_tau2(), prior.correlation,
                                           prior.spatial.order, spectrum=spectrum, gain=prior.gain)
    extra, mean_covariance = mean_mode_covariance(C, area, prior.tau2, np.where(prior.free, prior.mean_variance, 0.0))
    if np.any(prior.known_variance > 0):  # face means estimated before the fit
        extra = extra + known_mean_covariance(C, area, prior.tau2, prior.known_variance)
        mean_covariance = mean_covariance + np.diag(prior.known_variance)
    return covariance + extra[:, :fitted, :fitted], C, J, mean_covariance


def relative_residuals(data, predicted):
    """(n_bands, T*T) ``(A_b - a_b) / a_b`` of the predicted albedo against the input."""
    observed = data.observed_numpy.reshape(len(predicted), -1)
    return (np.stack([np.ravel(p) for p in predicted]) - observed) / np.maximum(observed, 1e-3)


def texel_scaled_residuals(data, predicted):
    """(n_bands, T*T) :func:`relative_residuals` over each texel's noise scale ``q_i`` (times the
    data term's weight ``1 / q_i``; 0 where a texel does not enter): residuals of noise ``S``."""
    return relative_residuals(data, predicted) * np.ravel(data.weight)[None]


def calibrated_noise(data, predicted, covariance, J, movable):
    """``(sigma (n_bands,), common, figures)``: the noise re-estimated from the residuals.

    Per texel the relative residuals ``r_b`` (over the texel's noise scale ``q_i``,
    :func:`texel_scaled_residuals`) split into their mean over bands
    ``m`` (the band-common part) and the rest ``e_b``. For noise of covariance
    ``diag(sigma^2) + common^2 1 1^T`` over ``B`` bands (equal ``sigma``),
    ``E[e_b^2] = sigma_b^2 (B - 1) / B`` and ``E[m^2] = common^2 + mean(sigma^2) / B``.
    Both moments are scaled by ``N / (N - t)``, ``t = sum_i tr(C_i Sigma_i)`` the
    degrees of freedom the posterior spends on the data (the hat matrix's
    trace; Gelman et al., Bayesian Data Analysis, 3rd ed., sec. 7.2's effective
    number of parameters), ``N`` the data terms."""

    B = len(predicted)
    weight = data.scale_numpy[:, movable] > 0
    relative = texel_scaled_residuals(data, predicted)[:, movable]
    texels = np.all(weight, axis=0)
    relative = relative[:, texels]
    count = relative.size
    precision = data.precision_from_jacobian(J)
    dof = float(np.einsum("nij,nji->", precision[texels], covariance[texels]))
    inflation = count / max(count - dof, 0.1 * count)
    m = relative.mean(axis=0)
    e = relative - m[None]
    sigma2 = np.mean(e ** 2, axis=1) * B / (B - 1) * inflation
    common2 = max(float(np.mean(m ** 2)) * inflation - float(np.mean(sigma2)) / B, 0.0)
    figures = {"texels": int(texels.sum()), "dof_per_texel": dof / max(int(texels.sum()), 1),
               "band_mean_rms": float(np.sqrt(np.mean(m ** 2))),
               "band_rest_rms": [float(v) for v in np.sqrt(np.mean(e ** 2, axis=1))]}
    return np.sqrt(sigma2), float(np.sqrt(common2)), figures


CORRELATION_RADIUS = 3
"""Offsets (texels, each axis) at which :func:`residual_correlation` measures the noise's
correlation; beyond them it is taken as 0."""


def residual_correlation(data, predicted, valid, radius=CORRELATION_RADIUS, jacobian=None, movable=None):
    """``(dy, dx) -> rho``: the correlation of the whitened relative residuals ``r_b / (q_i sigma_b)``
    between texels ``(dy, dx)`` apart (both with valid input), pooled over bands.

    The albedo a capture gives is not white across texels: the demo's static albedo
    error correlates 0.43 (per band) and 0.28 (band-common) between neighbours, from the
    resampling of images into texture space, and a std that takes it as white covered
    only 67-81% of the chromophore errors within 2 std there. Residuals miss the part of
    the noise the maps absorb. With ``jacobian`` (``J_z`` of the ``movable`` texels) each
    texel's residual is first projected on the band directions no map can move,
    ``(I - J (J^T J)^-1 J^T) z``: there the prior's smoothing neither absorbs the
    correlated part nor leaves the white part behind, so for noise whose correlation
    between texels is the same in every band direction the projection's correlation is
    the noise's (``tr(P Sigma_ij P) / tr(P Sigma_ii P)``)."""

    B = len(predicted)
    T = valid.shape[0]
    z = texel_scaled_residuals(data, predicted).reshape(B, T, T) / data.sigma[:, None, None]
    if jacobian is not None:
        flat = z.reshape(B, -1)[:, movable].T  # (n, B)
        normal = np.einsum("nbi,nbj->nij", jacobian, jacobian) + 1e-12 * np.eye(jacobian.shape[-1])
        coefficients = np.linalg.solve(normal, np.einsum("nbi,nb->ni", jacobian, flat)[..., None])[..., 0]
        flat = flat - np.einsum("nbi,ni->nb", jacobian, coefficients)
        z = z.reshape(B, -1).copy()
        z[:, movable] = flat.T
        z = z.reshape(B, T, T)
    z = np.where(valid[None], z - np.array([z[b][valid].mean() for b in range(B)])[:, None, None], 0.0)
    variance = float(np.mean(z[:, valid] ** 2))
    out = {}
    for dy in range(0, radius + 1):
        for dx in range(-radius, radius + 1):
            if (dy, dx) == (0, 0) or (dy == 0 and dx < 0):
                continue
            a = (slice(0, T - dy), slice(max(0, -dx), T - max(0, dx)))
            b = (slice(dy, T), slice(max(0, dx), T - max(0, -dx)))
            both = valid[a] & valid[b]
            if both.sum() < 16:
                continue
            product = z[:, a[0], a[1]] * z[:, b[0], b[1]]
            out[(dy, dx)] = float(np.mean(product[:, both]) / max(variance, 1e-30))
            out[(-dy, -dx)] = out[(dy, dx)]
    return out
