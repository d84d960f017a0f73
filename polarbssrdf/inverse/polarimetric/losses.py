"""Loss terms of the static stage (supplement eq. 26-35), normalized, on Dr.Jit arrays.

Data terms compare the paper's separations (eq. 22-24) formed the same way
from the predicted and the observed analyser images:

* ``L_sss`` (eq. 27): ``I_sss = 2 I90``;
* ``L_s`` (eq. 28): ``I_s = I0 - I90``;
* ``L_psi`` (eq. 29-30): the degree-of-polarization ratio
  ``psi = sqrt(I_zeta^2 + I_xi^2) / I_sss`` of the subsurface light, with
  ``I_xi = I_s - (glossy part of I_s)``. Eq. 29 as printed divides by
  ``2 I90``, which is only the subsurface light behind the 90-degree
  analyser, so ``psi = DoP / (1 - DoP cos 2 phi)`` and fitting
  Atkinson-Hancock's DoP to it biases ``eta``. Here the predicted ``psi`` is
  formed from the predicted images with the same formula as the observed one,
  so the comparison is like with like (and unbiased). Used only where the
  subsurface light dominates (``I_sss > |I_s|``) and the observed ``psi < 1``;
* ``L_phi`` (eq. 31): ``(I_zeta, I_xi)`` weighted by ``I_sss / mean(I_sss)``.

Normalization (so the paper's weights work whatever the number of views, the
patch size or the exposure): every data term is a *mean* over the
texel-views (and bands) of the patch of squared residuals in units of the
expected photometric noise, ``sigma = photometric_noise x mean observed
I_sss`` of the patch (1% by default): a mean chi-square per texel-view.
Every regularizer is a mean over the patch's valid texels, in the
parameter's own units. The paper's plain sums make the balance between data
and regularizers depend on the number of views per texel, the patch size
and the image scale; here one unit of weight means the same on a 4-view test
and a 200-view capture, at any exposure. ``L_psi`` compares ratios of
images; its residuals are in units of their own noise, ``sigma / I_sss``.
"""

from __future__ import annotations

import drjit as dr

from polarbssrdf.optics.coaxial import (
    specular_polarization_observation,
    subsurface_observation,
    subsurface_polarization_observation,
)

DATA_TERMS = ("sss", "s", "psi", "phi")


def separations(I0, I45, I90, I135):
    """``(I_sss, I_zeta, I_s)`` of eq. 22-24 (the project's one definition)."""
    return (subsurface_observation(I90), subsurface_polarization_observation(I45, I135),
            specular_polarization_observation(I0, I90))


def _mean(values, count):
    return dr.sum(values) / count


def data_losses(predicted, observed, glossy_I_s, weight, mean_sss, noise, count):
    """The data terms of one band: ``{"sss", "s", "psi", "phi"}`` as Dr.Jit scalars (means).

    The means of :func:`data_loss_terms` over ``count`` texel-views.
    """
    return {name: _mean(values, count)
            for name, values in data_loss_terms(predicted, observed, glossy_I_s, weight, mean_sss,
                                                noise).items()}


def data_loss_terms(predicted, observed, glossy_I_s, weight, mean_sss, noise):
    """Per texel-view contributions to the data terms of one band (arrays; see :func:`data_losses`).

    The sums of squares of :func:`data_residuals`' residuals, per term.
    """
    return {name: sum(dr.square(residual) for residual in residuals)
            for name, residuals in data_residuals(predicted, observed, glossy_I_s, weight,
                                                  mean_sss, noise).items()}


def data_residuals(predicted, observed, glossy_I_s, weight, mean_sss, noise):
    """Per texel-view residuals of one band, in units of their noise: ``{term: [Float, ...]}``.

    A term's contribution to the loss is the sum of the squares of its
    residuals (:func:`data_loss_terms`); the Gauss-Newton posterior of the
    maps (:mod:`polarbssrdf.inverse.polarimetric.posterior`) differentiates
    the residuals themselves.

    Parameters
    ----------
    predicted, observed : tuple of 4 Float
        ``(I0, I45, I90, I135)`` per texel-view.
    glossy_I_s : Float
        Predicted glossy part of ``I_s`` (``I0 - I90`` of the glossy lobes).
        Subtracted from the predicted ``I_s`` it leaves the predicted
        subsurface part ``I_xi``; subtracted from the observed ``I_s`` it
        gives the observed ``I_xi`` of eq. 29 (``I_s - kappa S R+``), which
        therefore depends on the glossy parameters too; it is not detached,
        so the gradients are those of the loss as written.
    weight : Float
        Per texel-view weight, 0 or 1 (visibility and selection; 0 drops a view).
    mean_sss : float or Float
        The patch's mean observed ``I_sss`` (image scale).
    noise : float or Float
        ``photometric_noise``: the residual unit is ``sigma = noise * mean_sss``.
    """
    sss_hat, zeta_hat, s_hat = separations(*predicted)
    sss, zeta, s = separations(*observed)
    inv_sigma = 1.0 / (noise * mean_sss)
    xi_hat = s_hat - glossy_I_s
    xi = s - glossy_I_s
    residuals = {
        "sss": [weight * ((sss_hat - sss) * inv_sigma)],
        "s": [weight * ((s_hat - s) * inv_sigma)],
    }
    # W_phi of eq. 31 (the subsurface image relative to its mean) weighs the squares
    phi_scale = dr.sqrt(weight * dr.maximum(sss, 0.0) / mean_sss)
    residuals["phi"] = [phi_scale * ((zeta_hat - zeta) * inv_sigma),
                        phi_scale * ((xi_hat - xi) * inv_sigma)]
    dominated = (sss > dr.abs(s)) & (sss > 0.0)
    # where the subsurface light does not dominate, psi is undefined (I_sss <= 0 gives inf):
    # select before squaring, so neither the value nor the gradient meets 0 x inf
    safe_sss = dr.select(dominated, sss, 1.0)
    psi = dr.sqrt(dr.square(zeta) + dr.square(xi)) / safe_sss
    psi_hat = (dr.sqrt(dr.square(zeta_hat) + dr.square(xi_hat) + 1e-12 * dr.square(mean_sss))
               / dr.maximum(sss_hat, 1e-6 * mean_sss))
    dominated &= psi < 1.0
    # psi is a ratio of images: its noise is about sigma / I_sss
    residuals["psi"] = [dr.select(dominated, weight * ((psi_hat - psi) * safe_sss * inv_sigma),
                                  0.0)]
    return residuals
