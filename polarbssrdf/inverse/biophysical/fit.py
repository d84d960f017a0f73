"""The biophysical stage: melanin and hemoglobin maps from subsurface albedo maps (supplement sec. 5.3).

``fit_biophysical(albedo_maps, bands, atlas)`` recovers ``C_m, beta_m,
C_h_out, C_h_in`` per texel by the paper's coordinate descent (eq. 40-47):

a. a start per texel from the fast per-texel inversion
   (:func:`polarbssrdf.skin.invert_bands`, eq. 47) on block-averaged maps
   (blocks of about ``start_texel_mm``, where the blur is negligible),
   upsampled bilinearly;
b. the sum-of-Gaussians kernels of the five layer profiles (eq. 40, 43) fitted
   at the parameters of the median-intensity texel
   (:func:`polarbssrdf.render.subsurface.layer_profile_kernels`, the kernels
   synth renders with), homogeneous over the face (eq. 45);
c. at full resolution, damped Gauss-Newton steps (or Adam, ``drjit.opt``; the
   config's ``method``) on the four maps, a band-common gain and the maps' face
   means to the posterior mode of the eq. 46 rendering
   (:class:`~polarbssrdf.inverse.biophysical.model.BiophysicalModel`: the
   texture-space layered blur of synth, differentiable) against the input
   (eq. 41) under the Matérn prior of :mod:`~polarbssrdf.inverse.biophysical.prior`
   (its correlation length estimated from the albedo,
   :mod:`~polarbssrdf.inverse.biophysical.correlation`); clamped to the bounds
   after every step;
d. the bands' noise and the maps' spreads re-estimated from the posterior (a
   map the re-estimated noise leaves prior-dominated is held at its face mean
   from then on, :func:`hold_prior_dominated`), and (b)-(d) repeated until the
   kernels change by less than ``kernel_tolerance`` and neither estimate moves
   by more than :data:`NOISE_TOLERANCE`;
e. the posterior standard deviation of every map per texel
   (:func:`posterior_blocks`).

Input albedos are lobe albedos (``rho_sss`` of eq. 19, what the static stage
recovers and synth's truth maps hold); the skin model's flux ``R_bar`` is
``c(eta) rho_sss`` (docs/biophysical.md). Texels whose input is not finite,
outside [0, 1] or of confidence 0 in any band do not enter the data term,
take their values from the prior (or, without one, from their valid
neighbours) and are flagged.
"""

from __future__ import annotations

import copy
import dataclasses
import time

import drjit as dr
import drjit.opt
import numpy as np
from scipy.ndimage import zoom
from scipy.sparse.linalg import LinearOperator, cg

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
from polarbssrdf.inverse.biophysical.correlation import albedo_correlation_length
from polarbssrdf.inverse.biophysical.model import PARAMETERS, BiophysicalModel, jit_types
from polarbssrdf.inverse.biophysical.prior import (
    FourierPreconditioner,
    SpatialPrior,
    expected_prior_energy,
    known_mean_covariance,
    mean_mode_covariance,
    noise_spectrum,
    posterior_covariance,
    updated_spread,
)
from polarbssrdf.inverse.results.fill import fill_from_neighbours as fill
from polarbssrdf.render.subsurface import layer_profile_kernels, subsurface_exit_fraction
from polarbssrdf.skin.inversion import invert_bands
from polarbssrdf.skin.parameters import SkinParameters

START_ETA_STEP = 0.02
"""Texels of the start's inversion share one eta per bin of this width."""

GAIN = "albedo_gain"
"""The band-common gain's map (unitless): the input albedo is modelled as ``gain * rendered``."""

GAIN_BOUNDS = (0.5, 2.0)

LEVEL_STD_FRACTION = 0.1
"""A map whose face mean comes from the blocks keeps its own mean within this fraction of
that estimate's std (a quadratic penalty on the mean deviation)."""

STEP_RTOL = 0.05
"""Relative residual at which the conjugate gradients of a Gauss-Newton step stop: an
inexact Newton step (Dembo, Eisenstat and Steihaug, SIAM J. Numer. Anal. 19, 1982) with a
constant forcing term. At 512^2 the residual stalls at 1-5% for a hundred iterations
after the first steps; solving to 1e-3 cost 1580 iterations in 10 steps (111 s) for the
same maps as 478 iterations (36 s; bench/RESULTS.md, 2026-12-02)."""

STEP_MAX_ITERATIONS = 100
"""A cap on a step's conjugate-gradient iterations (the damping still guards the step)."""

BOUND_MARGIN = 1e-3
"""A value within this fraction of its bounds range of a bound counts as at the bound
(the Gauss-Newton step's active set)."""

ARC_FRACTIONS = (1.0, 0.5, 0.25)
"""Fractions of a Gauss-Newton step tried along the projected arc before the damping grows."""

NOISE_TOLERANCE = 0.05
"""Rounds stop once the kernels have settled and no band's noise estimate nor map's spread
moved by more than this (relative)."""


@dataclasses.dataclass
class BiophysicalResult:
    """Maps (T, T float32) of the fit and what it did.

    ``residual`` is the RMS over bands of rendered minus input albedo (0 at
    flagged texels), ``flagged`` marks surface texels whose input was invalid
    (their parameters come from the prior and their neighbours). ``std``: the
    posterior standard deviation per map (same units; 0 off the surface),
    ``noise``: the bands' relative noise and the face means with their std.
    ``history`` has one entry per round: loss before/after, kernel change, the
    noise estimate, seconds."""

    maps: dict
    residual: np.ndarray
    flagged: np.ndarray
    kernels: list
    history: list
    predicted: np.ndarray
    start: dict
    seconds: float
    std: dict = dataclasses.field(default_factory=dict)
    noise: dict = dataclasses.field(default_factory=dict)

    def channels(self):
        """Channels of the stage's map file: ``C_m, beta_m, C_h_out, C_h_in``, their ``<name>_std``,
        ``albedo_gain`` (with a gain) and its std, ``residual``, ``flagged``."""
        out = {}
        for name in (*PARAMETERS, GAIN):
            if name in self.maps:
                out[name] = np.ascontiguousarray(self.maps[name], dtype=np.float32)
            if name in self.std:
                out[f"{name}_std"] = np.ascontiguousarray(self.std[name], dtype=np.float32)
        out["residual"] = np.ascontiguousarray(self.residual, dtype=np.float32)
        out["flagged"] = self.flagged.astype(np.float32)
        return out


def albedo_stack(albedo_maps, bands, shape):
    """(n_bands, T, T) float64 of ``rho_sss.<band>`` (or ``<band>``) channels; clear errors."""
    if len(bands) < 4:
        raise ValueError(f"need at least 4 bands to fit 4 parameters, got {len(bands)}")
    stack = []
    for band in bands:
        key = next((k for k in (f"rho_sss.{band.name}", band.name) if k in albedo_maps), None)
        if key is None:
            raise ValueError(f"missing subsurface albedo map 'rho_sss.{band.name}' (have: "
                             f"{', '.join(sorted(albedo_maps)) or 'none'})")
        value = np.asarray(albedo_maps[key], dtype=np.float64)
        if value.shape != tuple(shape):
            raise ValueError(f"map {key!r} is {value.shape}, the atlas is {tuple(shape)}")
        stack.append(value)
    return np.stack(stack)


def fill_from_neighbours(values, known, domain):
    """``values`` with texels of ``domain`` not ``known`` replaced by a normalized Gaussian
    average of known neighbours (radius doubling until every one is filled); off
    ``domain`` too, so the map is finite everywhere."""

    known = known & np.isfinite(np.asarray(values, dtype=np.float64))
    if not known.any():
        raise ValueError("no texel with valid input to fill from")
    return fill(values, known)


def _block_mean(values, weight, factor):
    """Weighted means over factor x factor blocks (edge padded)."""
    T = values.shape[-1]
    n = -(-T // factor)
    pad = n * factor - T
    v = np.pad(values * weight, [(0, 0)] * (values.ndim - 2) + [(0, pad), (0, pad)])
    w = np.pad(weight.astype(np.float64), [(0, pad), (0, pad)])
    shape = v.shape[:-2] + (n, factor, n, factor)
    ws = w.reshape(n, factor, n, factor).sum(axis=(1, 3))
    vs = v.reshape(shape).sum(axis=(-3, -1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return vs / ws, ws > 0


def block_inversion(rbar, valid, atlas, bands, eta, config, block_mm):
    """The per-texel inversion of eq. 47 on means over blocks of about ``block_mm``.

    Returns ``(maps, ok, texels, factor)``: per block the four parameters
    (NaN where the block has no valid texel), which blocks have one, how many
    valid texels each holds, and the block size in texels."""

    T = valid.shape[0]
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    factor = max(1, int(round(block_mm / max(texel, 1e-9)))) if block_mm > 0 else 1
    factor = min(factor, T)
    means, ok = _block_mean(rbar, valid, factor)
    eta_means, _ = _block_mean(eta, valid, factor)
    texels = _block_mean(valid.astype(np.float64), np.ones_like(valid, dtype=np.float64), factor)[0] * factor ** 2
    # invert_bands takes one eta: invert texels in bins of START_ETA_STEP
    bins = np.round(eta_means / START_ETA_STEP) * START_ETA_STEP
    coarse_maps = {name: np.full(ok.shape, np.nan) for name in PARAMETERS}
    for value in np.unique(bins[ok]):
        members = ok & (bins == value)
        result = invert_bands(np.moveaxis(means[:, members], 0, -1), bands, thickness_mm=config.thickness_mm,
                              eta=float(value), table_size="default")
        for name in PARAMETERS:
            coarse_maps[name][members] = getattr(result, name)
    return coarse_maps, ok, texels, factor


def start_maps(rbar, valid, atlas, bands, eta, config):
    """Step (a): the per-texel inversion of eq. 47 on block means, upsampled; (T, T) maps."""

    T = valid.shape[0]
    coarse_maps, ok, _, factor = block_inversion(rbar, valid, atlas, bands, eta, config, config.start_texel_mm)
    out = {}
    for name in PARAMETERS:
        coarse = coarse_maps[name]
        coarse = fill_from_neighbours(coarse, ok, np.ones_like(ok))
        if factor > 1:
            # block centres -> texel centres
            fine = zoom(coarse, factor, order=1, mode="nearest", grid_mode=True)[:T, :T]
        else:
            fine = coarse
        low, high = config.bounds[name]
        out[name] = np.clip(fine, low, high)
    return out, factor


MINIMUM_BLOCK_FILL = 0.5
"""A block enters the face means if at least this fraction of its texels has valid input."""


def block_face_means(rbar, valid, atlas, bands, eta, config):
    """``name -> (mean, std of the mean)`` of each chromophore from blocks of ``mean_block_mm``.

    Each block's albedo is averaged before it is inverted, so the per-texel
    noise is averaged out before the model's curvature can turn it into bias
    (inverting every texel and averaging the results moved ``beta_m``'s face
    mean by +0.08 on the demo); the face mean is the texel-weighted mean of the
    blocks' values, its std their weighted spread over the square root of the
    number of blocks."""

    maps, ok, texels, factor = block_inversion(rbar, valid, atlas, bands, eta, config, config.mean_block_mm)
    full = ok & (texels >= MINIMUM_BLOCK_FILL * factor ** 2)
    use = full if full.sum() >= 4 else ok
    weight = texels[use]
    out = {}
    for name in PARAMETERS:
        values = maps[name][use]
        mean = float(np.sum(weight * values) / np.sum(weight))
        spread = float(np.sqrt(np.sum(weight * (values - mean) ** 2) / np.sum(weight)))
        out[name] = (mean, spread / np.sqrt(max(int(use.sum()) - 1, 1)))
    return out


def median_intensity_texel(observed, valid):
    """Flat index of the valid texel of median mean-over-bands albedo."""
    intensity = observed.mean(axis=0).ravel()
    index = np.flatnonzero(valid.ravel())
    order = np.argsort(intensity[index])
    return int(index[order[len(order) // 2]])


def fit_kernels(maps, texel, bands, eta, config):
    """Step (b): the layer kernels at the parameters of one texel (eq. 40, 43, 45)."""

    values = {name: float(np.ravel(maps[name])[texel]) for name in PARAMETERS}
    skin = SkinParameters(**values, thickness_mm=config.thickness_mm, eta=float(np.ravel(eta)[texel]))
    return layer_profile_kernels(bands, skin)


def kernel_change(old, new):
    """Largest absolute change of a normalized SoG weight over bands and profiles."""
    return max(float(np.max(np.abs(np.asarray(o[name][0]) - np.asarray(n[name][0]))))
               for o, n in zip(old, new) for name in o)


class FitLoss:
    """The data term of step (c), eq. 41, over Dr.Jit parameter arrays (and an optional
    smoothness penalty): ``1/2 sum_b sum_i ((g_i A_b,i - a_b,i) / (sigma_b a_b,i))^2``.

    ``A_b`` is the eq. 46 rendering, ``a_b`` the input albedo, ``g`` the
    band-common gain (``albedo_gain`` in ``params``, 1 without it) and
    ``sigma_b`` the band's relative noise (:meth:`set_noise`). The Matérn
    prior is added in NumPy by :class:`PriorTerms`."""

    def __init__(self, model, observed, weight, config, sigma=None):
        Float, UInt32, _ = jit_types()
        self.model = model
        self.config = config
        self.observed_numpy = observed
        self.weight = weight
        T = model.shape[0]
        self.observed = [to_jit(Float, observed[b].ravel(), np.float32) for b in range(len(model.bands))]
        self.set_noise(np.full(len(model.bands), config.albedo_noise) if sigma is None else sigma,
                       config.common_noise)
        surface = model.atlas.valid
        index = np.arange(T * T).reshape(T, T)
        pairs = []
        for a, b in ((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])):
            both = surface.ravel()[a.ravel()] & surface.ravel()[b.ravel()]
            pairs.append((a.ravel()[both], b.ravel()[both]))
        first = np.concatenate([p[0] for p in pairs])
        second = np.concatenate([p[1] for p in pairs])
        # centre distance of each pair, mm: along u for row neighbours, along v for column ones
        sizes = model.atlas.texel_size_mm.reshape(T * T, 2)
        along = np.concatenate([np.zeros(len(pairs[0][0]), int), np.ones(len(pairs[1][0]), int)])
        distance = 0.5 * (sizes[first, along] + sizes[second, along])
        inverse_distance = 1.0 / np.maximum(distance, 1e-6)
        self.pairs = (to_jit(UInt32, first, np.uint32), to_jit(UInt32, second, np.uint32))
        self.inverse_distance = to_jit(Float, inverse_distance, np.float32)
        self.smoothness = config.smoothness_weights()
        # the penalty keeps the old normalization: a mean over pairs against the mean data
        # term, i.e. times the number of data terms / 2 against the summed one
        data_terms = max(int(weight.sum()), 1) * len(model.bands)
        pair_weight = 0.5 * data_terms / max(len(first), 1)
        # scalars that vary with the data and the config enter the kernels as inputs, not
        # literals, so that other faces and configs reuse the compiled kernels
        self._smoothness_jit = {name: (dr.opaque(Float, w * pair_weight),
                                       dr.opaque(Float, config.bounds[name][1] - config.bounds[name][0]))
                                for name, w in self.smoothness.items() if w > 0}

    def set_noise(self, sigma, common):
        """Set the bands' own relative noise ``sigma`` (n_bands,), the band-common relative
        noise ``common`` and the data term's weights.

        Per texel the relative residuals ``r`` have covariance ``diag(sigma^2) +
        common^2 1 1^T``; in ``z_b = r_b / sigma_b`` its inverse is ``I - kappa v v^T``
        with ``v_b = 1 / sigma_b`` and ``kappa = 1 / (1 / common^2 + sum_b v_b^2)``
        (Sherman-Morrison)."""
        Float, _, _ = jit_types()
        self.sigma = np.asarray(sigma, np.float64)
        self.common = float(common)
        scale = self.weight[None] / (self.sigma[:, None, None] * np.maximum(self.observed_numpy, 1e-3))
        self.scale_numpy = scale.reshape(len(self.sigma), -1)
        self.scale = [to_jit(Float, row, np.float32) for row in self.scale_numpy]
        self.v = 1.0 / self.sigma
        self.kappa = 0.0 if self.common <= 0 else 1.0 / (1.0 / self.common ** 2 + float(np.sum(self.v ** 2)))
        # they change every round: kernel inputs, not literals
        self._v_jit = [dr.opaque(Float, float(v)) for v in self.v]
        self._kappa_jit = dr.opaque(Float, self.kappa)

    def data_terms(self, params):
        """Per band, the predicted albedo ``g A_b`` (flat Float)."""
        gain = params.get(GAIN)
        values = [self.model.render(params, b) for b in range(len(self.model.bands))]
        return values if gain is None else [gain * v for v in values]

    def __call__(self, params, predicted=None):
        Float, _, _ = jit_types()
        predicted = predicted or self.data_terms(params)
        loss = Float(0.0)
        common = Float(0.0)
        for b, value in enumerate(predicted):
            z = (value - self.observed[b]) * self.scale[b]
            loss += 0.5 * dr.sum(z * z)
            common += z * self._v_jit[b]
        loss -= 0.5 * self._kappa_jit * dr.sum(common * common)
        for name in PARAMETERS:
            if name in self._smoothness_jit:
                weight, span = self._smoothness_jit[name]
                x = params[name]
                # the map's gradient in bounds ranges per mm, whatever the texel size
                slope = ((dr.gather(Float, x, self.pairs[0]) - dr.gather(Float, x, self.pairs[1]))
                         * self.inverse_distance / span)
                loss += weight * dr.sum(slope * slope)
        return loss


def local_jacobian(model, maps, names):
    """``(n_texels, n_bands, len(names))`` d(predicted albedo)/d(map) of the unblurred model.

    By Dr.Jit forward mode for the chromophores (times the gain where
    ``maps`` has one); the gain's column is the unblurred albedo itself."""

    Float, _, _ = jit_types()
    gain = np.ravel(maps[GAIN]) if GAIN in maps else None
    columns = []
    for name in names:
        params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS}
        if name == GAIN:
            values = [model.local_albedo(params, b) for b in range(len(model.bands))]
            columns.append(np.stack([np.array(v, dtype=np.float64) for v in values], axis=-1))
            continue
        dr.enable_grad(params[name])
        values = [model.local_albedo(params, b) for b in range(len(model.bands))]
        dr.forward(params[name])
        column = np.stack([np.array(dr.grad(v), dtype=np.float64) for v in values], axis=-1)
        columns.append(column if gain is None else column * gain[:, None])
    return np.stack(columns, axis=-1)


def data_precision(loss_fn, maps, names, movable):
    """``(n, k, k)`` Gauss-Newton normal matrix ``J_z^T (I - kappa v v^T) J_z`` of the movable
    texels (``J_z`` the Jacobian in the data term's ``z`` units, :meth:`FitLoss.set_noise`),
    and ``J_z``."""
    J = local_jacobian(loss_fn.model, maps, names)[movable] * loss_fn.scale_numpy[:, movable].T[:, :, None]
    projected = np.einsum("nbi,b->ni", J, loss_fn.v)
    precision = np.einsum("nbi,nbj->nij", J, J) - loss_fn.kappa * np.einsum("ni,nj->nij", projected, projected)
    return precision, J


def _evaluate(loss_fn, maps, names, fixed):
    """The data term at NumPy maps with the free maps' gradients enabled: ``(loss, params, value)``.

    :func:`_gradient` then runs the reverse pass only if the point is kept.
    """

    Float, _, _ = jit_types()
    params = dict(fixed)
    for n in names:
        params[n] = to_jit(Float, np.ravel(maps[n]), np.float32)
        dr.enable_grad(params[n])
    value = loss_fn(params)
    return float(value[0]), params, value


def _gradient(evaluated, names):
    """(n_texels, len(names)) gradient of an :func:`_evaluate` d loss, through the blur."""

    _, params, value = evaluated
    dr.backward(value)
    return np.stack([np.array(dr.grad(params[n]), dtype=np.float64) for n in names], axis=-1)


class PriorTerms:
    """The Matérn prior of the optimized maps and their face means, in NumPy.

    ``names``: the optimized maps (chromophores and, with a gain, ``albedo_gain``);
    ``spatial``: :class:`~polarbssrdf.inverse.biophysical.prior.SpatialPrior` over
    the movable texels, or None (no prior). ``tau2`` per map (``inf``: none),
    the face means ``mu`` with their hyperprior ``(mean0, mean_variance)``
    (variance 0: fixed, as the gain's mean of 1). ``block_means``: ``name ->
    (mean, std)`` estimated from block-averaged albedo
    (:func:`block_face_means`); such a mean is combined with the hyperprior and
    held, its variance kept in ``known_variance`` for the posterior spread.
    """

    def __init__(self, names, spatial, config, start_means, block_means=None):
        block_means = block_means or {}
        self.names = list(names)
        self.spatial = spatial
        k = len(self.names)
        self.tau2 = np.full(k, np.inf)
        self.mean0 = np.zeros(k)
        self.mean_variance = np.zeros(k)
        self.mu = np.zeros(k)
        self.std = np.zeros(k)
        self.known_variance = np.zeros(k)
        for i, name in enumerate(self.names):
            if name == GAIN:
                std, (mean, mean_std), start = config.gain_std, (1.0, 0.0), 1.0
            else:
                std, (mean, mean_std), start = config.prior_std[name], config.prior_mean[name], start_means[name]
            if name in block_means:
                # the blocks' estimate combined with the hyperprior, then held
                block, block_std = block_means[name]
                precision = 1.0 / max(block_std, 1e-12) ** 2 + (1.0 / mean_std ** 2 if mean_std > 0 else 0.0)
                mean = (block / max(block_std, 1e-12) ** 2 + (mean / mean_std ** 2 if mean_std > 0 else 0.0)) / precision
                self.known_variance[i] = 1.0 / precision
                mean_std = 0.0
            self.mean0[i], self.mean_variance[i] = mean, mean_std ** 2
            self.mu[i] = start if mean_std > 0 else mean
            self.std[i] = std
            if spatial is not None:
                self.tau2[i] = spatial.tau2(std)
        self.free = self.mean_variance > 0
        self.active = np.isfinite(self.tau2)
        # a mean from the blocks holds the map's own (area-weighted) mean there: without it
        # the field's nearly free constant mode lets per-texel noise move the level again
        self.level_precision = np.zeros(k)
        if spatial is not None:
            self.level_weights = spatial.area / spatial.area.sum()
            held_level = self.known_variance > 0
            self.level_precision[held_level] = 1.0 / (LEVEL_STD_FRACTION ** 2 * self.known_variance[held_level])
        if spatial is not None:
            self.ones_response = spatial.unit @ np.ones(len(spatial.index))  # Q 1 tau^2
            self.ones_energy = float(self.ones_response.sum())  # 1^T Q 1 tau^2

    def energy(self, X, mu):
        """``(value, gradient (n, k), gradient of mu (k,))`` at surface values ``X`` (n, k)."""
        if self.spatial is None:
            return 0.0, np.zeros_like(X), np.zeros_like(mu)
        inverse_tau2 = np.where(self.active, 1.0 / self.tau2, 0.0)
        deviation = X - mu[None, :]
        gradient = (self.spatial.unit @ deviation) * inverse_tau2[None, :]
        value = 0.5 * float(np.sum(deviation * gradient))
        mean_gradient = -gradient.sum(axis=0)
        level = self.level_weights @ deviation  # (k,) the maps' mean deviation
        value += 0.5 * float(np.sum(self.level_precision * level ** 2))
        gradient = gradient + self.level_weights[:, None] * (self.level_precision * level)[None, :]
        free = self.free & self.active
        value += 0.5 * float(np.sum((mu[free] - self.mean0[free]) ** 2 / self.mean_variance[free]))
        mean_gradient[free] += (mu[free] - self.mean0[free]) / self.mean_variance[free]
        mean_gradient[~free] = 0.0
        return value, gradient, mean_gradient

    def restricted(self, names):
        """The same terms over a subset of the maps (their spreads, means and precisions kept)."""
        keep = [self.names.index(n) for n in names]
        out = copy.copy(self)
        out.names = list(names)
        for attribute in ("tau2", "mean0", "mean_variance", "mu", "std", "known_variance", "free", "active",
                          "level_precision"):
            setattr(out, attribute, getattr(self, attribute)[keep].copy())
        return out

    def update_spreads(self, maps, C, movable):
        """Re-estimate the chromophores' spreads (not the gain's) from the posterior
        (:func:`~polarbssrdf.inverse.biophysical.prior.updated_spread`); returns the
        largest relative change."""
        if self.spatial is None:
            return 0.0
        spatial = self.spatial
        energy = expected_prior_energy(C, spatial.area, self.tau2, spatial.correlation_mm, spatial.order)
        change = 0.0
        for i, name in enumerate(self.names):
            if name == GAIN or not self.active[i]:
                continue
            deviation = np.ravel(maps[name])[movable] - self.mu[i]
            tau2, std = updated_spread(deviation, spatial.unit, energy[:, i], self.tau2[i], self.std[i])
            change = max(change, abs(np.log(std / self.std[i])))
            self.tau2[i], self.std[i] = tau2, std
        return change


def _solve_step(blocks, prior, rhs_x, rhs_mu, damping, max_iterations=STEP_MAX_ITERATIONS, rtol=STEP_RTOL, fixed=None):
    """``(delta_x (n, k), delta_mu (k,), predicted)`` of the damped Gauss-Newton system, by CG.

    The system is ``H delta = rhs`` with ``H`` the per-texel data blocks
    (n, k, k) plus the prior's Hessian over the maps and their face means
    (:class:`PriorTerms`), plus ``damping`` times its diagonal
    (Levenberg-Marquardt); conjugate gradients preconditioned in the Fourier
    domain (:class:`~polarbssrdf.inverse.biophysical.prior.FourierPreconditioner`).
    Without a prior the blocks decouple and are solved directly. ``fixed``
    (n, k) bool marks values that do not move (their rows and columns are
    replaced by the identity, their step is 0). ``predicted`` is the decrease
    ``rhs . delta - delta . H delta / 2`` the undamped quadratic model promises.
    """

    n, k = rhs_x.shape
    eye = np.eye(k)
    keep = np.ones((n, k)) if fixed is None else (~np.asarray(fixed, bool)).astype(np.float64)
    rhs_x = rhs_x * keep
    if prior.spatial is None:
        diagonal = np.einsum("nii->ni", blocks)
        damped = blocks + damping * (diagonal[:, :, None] * eye + 1e-12 * eye)
        pinned = (1.0 - keep)
        damped = damped * keep[:, :, None] * keep[:, None, :] + pinned[:, :, None] * eye
        x = np.linalg.solve(damped, rhs_x[:, :, None])[..., 0] * keep
        predicted = float(np.sum(rhs_x * x) - 0.5 * np.einsum("ni,nij,nj->", x, blocks, x))
        return x, np.zeros(k), predicted
    inverse_tau2 = np.where(prior.active, 1.0 / prior.tau2, 0.0)
    unit = prior.spatial.unit
    q1 = prior.ones_response
    free = prior.free & prior.active
    safe_variance = np.where(free, prior.mean_variance, 1.0)
    mean_diagonal = np.where(free, prior.ones_energy * inverse_tau2 + 1.0 / safe_variance, 1.0)
    prior_diagonal = unit.diagonal()[:, None] * inverse_tau2[None, :]
    diagonal = np.einsum("nii->ni", blocks) + prior_diagonal
    damped_blocks = blocks + damping * (diagonal[:, :, None] * eye + 1e-12 * eye)
    mean_damped = mean_diagonal * (1.0 + damping)
    spatial = prior.spatial
    level_weights = prior.level_weights
    fourier = FourierPreconditioner(spatial.shape, spatial.index, spatial.texel_area, prior.tau2,
                                    damped_blocks.mean(axis=0), spatial.correlation_mm, spatial.order)

    def apply(z):
        x, mu = z[:n * k].reshape(n, k), z[n * k:]
        pinned = x * (1.0 - keep)
        x = x * keep
        mu = np.where(free, mu, 0.0)
        y = (np.einsum("nij,nj->ni", damped_blocks, x) + (unit @ x) * inverse_tau2[None, :]
             - q1[:, None] * (mu * inverse_tau2)[None, :]
             + level_weights[:, None] * (prior.level_precision * (level_weights @ x))[None, :])
        y = y * keep + pinned
        y_mu = np.where(free, -(q1 @ x) * inverse_tau2 + mean_damped * mu, z[n * k:])
        return np.concatenate([y.ravel(), y_mu])

    def precondition(z):
        x, mu = z[:n * k].reshape(n, k), z[n * k:]
        return np.concatenate([(fourier(x * keep) * keep + x * (1.0 - keep)).ravel(), mu / mean_damped])

    size = n * k + k
    rhs = np.concatenate([rhs_x.ravel(), np.where(free, rhs_mu, 0.0)])
    operator = LinearOperator((size, size), matvec=apply, dtype=np.float64)
    solution, _ = cg(operator, rhs, x0=precondition(rhs), rtol=rtol, maxiter=max_iterations,
                     M=LinearOperator((size, size), matvec=precondition, dtype=np.float64))
    x, mu = solution[:n * k].reshape(n, k) * keep, np.where(free, solution[n * k:], 0.0)
    # the undamped quadratic model's decrease, r.d - d.H d / 2, with H d = A d - damping D d
    undamped = apply(np.concatenate([x.ravel(), mu])) - damping * np.concatenate(
        [(diagonal * x).ravel(), np.where(free, mean_diagonal * mu, 0.0)])
    solution = np.concatenate([x.ravel(), mu])
    predicted = float(rhs @ solution - 0.5 * solution @ undamped)
    return x, mu, predicted


def _bounds(config, name):
    return GAIN_BOUNDS if name == GAIN else config.bounds[name]


def _gauss_newton(loss_fn, prior, maps, held, config, movable, progress=None):
    """Step (c) by damped Gauss-Newton on the free maps and their face means.

    The step solves ``(H + mu diag(H)) delta = -g`` with ``g`` the exact
    gradient (Dr.Jit reverse mode through the blur, plus the prior's), ``H``
    per texel ``sum_b s_b^2 J_b J_b^T`` (``J_b`` the Jacobian of the unblurred
    model, :func:`local_jacobian`) plus the prior's exact Hessian, which couples
    neighbours and the face means (:func:`_solve_step`). Values at a bound that
    the gradient pushes outward are held there for the step (projected Newton);
    a step that does not lower the loss is tried at :data:`ARC_FRACTIONS` of its
    length along the projected arc, then with ``mu`` grown; an accepted one
    updates ``mu`` by Nielsen's rule. With the band-common gain fitted (a ridge
    with melanin and blood), the few values a full step pushed out of bounds
    (0.2-1% of the demo's texels) made the clipped step's loss rise where the
    quadratic model promised a fall, and ``mu`` crept up by 4/3 a step (two solves
    a step, none of 36 steps converged); with the active set the same fit converged.
    Returns maps, first/last loss and the accepted losses; ``prior.mu`` is updated.
    """
    Float, _, _ = jit_types()
    names = prior.names
    fixed = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS if n in held}
    flat = {n: np.asarray(maps[n], np.float64).ravel().copy() for n in maps}

    def total(values, means):
        evaluated = _evaluate(loss_fn, values, names, fixed)
        X = np.stack([values[n][movable] for n in names], axis=-1)
        value, grad_x, grad_mu = prior.energy(X, means)
        return evaluated[0] + value, evaluated, grad_x, grad_mu

    mean = prior.mu.copy()
    loss, evaluated, prior_x, prior_mu = total(flat, mean)
    gradient = _gradient(evaluated, names)[movable] + prior_x
    first = loss
    losses = [loss]
    damping = 1e-3
    growth = 2.0
    steps = int(config.iterations)
    lows = np.array([_bounds(config, n)[0] for n in names])
    highs = np.array([_bounds(config, n)[1] for n in names])
    margin = BOUND_MARGIN * (highs - lows)
    for step_index in range(steps):
        blocks, _ = data_precision(loss_fn, flat, names, movable)
        X = np.stack([flat[n][movable] for n in names], axis=-1)
        # the active set: values at a bound that the gradient pushes outward stay there, and
        # the step of the others accounts for it (projected Newton; Bertsekas 1982)
        pinned = ((X <= lows + margin) & (gradient > 0)) | ((X >= highs - margin) & (gradient < 0))
        accepted = False
        while damping < 1e8:
            step, step_mu, predicted = _solve_step(blocks, prior, -gradient, -prior_mu, damping, fixed=pinned)
            # along the projected arc clip(x + t step): the values that still cross a bound
            # make the full step's clipped loss unreliable, a shorter one often is not
            for fraction in ARC_FRACTIONS:
                trial = {n: v.copy() for n, v in flat.items()}
                for k, n in enumerate(names):
                    trial[n][movable] = np.clip(X[:, k] + fraction * step[:, k], lows[k], highs[k])
                trial_mean = np.clip(mean + fraction * step_mu, lows, highs)
                trial_loss, trial_evaluated, trial_prior_x, trial_prior_mu = total(trial, trial_mean)
                if np.isfinite(trial_loss) and trial_loss < loss:
                    accepted = True
                    break
            if accepted:
                break
            damping *= growth
            growth *= 2.0
        if not accepted:
            break
        # Nielsen's update (Madsen, Nielsen and Tingleff, Methods for non-linear least
        # squares problems, 2004, sec. 3.2) from the gain ratio of actual to predicted decrease
        linear = float(-np.sum(gradient * step) - np.sum(prior_mu * step_mu))
        model = fraction * linear - fraction ** 2 * (linear - predicted)
        ratio = min((loss - trial_loss) / max(model, 1e-30), 1.0)
        damping = max(damping * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 1e-6)
        growth = 2.0
        decrease = (loss - trial_loss) / max(abs(loss), 1e-30)
        flat, mean, loss = trial, trial_mean, trial_loss
        losses.append(loss)
        if progress:
            progress(f"step {step_index + 1}/{steps}: loss {loss:.6g}")
        if decrease < config.tolerance:
            break
        gradient = _gradient(trial_evaluated, names)[movable] + trial_prior_x
        prior_mu = trial_prior_mu
    out = dict(maps)
    for n in names:
        out[n] = flat[n].reshape(maps[n].shape)
    prior.mu = mean
    return out, first, loss, losses


def posterior_blocks(loss_fn, prior, maps, movable, spectrum=None):
    """``(n, k, k)`` posterior covariance of the optimized maps per movable texel, the data
    precision and the means' covariance (:mod:`~polarbssrdf.inverse.biophysical.prior`).

    Without a spatial prior, the data term's own inverse per texel (a pseudo-inverse: a
    direction the bands do not see has no finite spread, it is reported as the
    map's bounds range)."""

    names = prior.names
    C, J = data_precision(loss_fn, maps, names, movable)
    k = len(names)
    if prior.spatial is None:
        covariance = np.linalg.pinv(C, hermitian=True)
        return covariance, C, J, np.zeros((k, k))
    area = prior.spatial.area
    covariance = posterior_covariance(C, area, prior.tau2, prior.spatial.correlation_mm, prior.spatial.order,
                                      spectrum=spectrum)
    mean_variance = np.where(prior.free & prior.active, prior.mean_variance, 0.0)
    extra, mean_covariance = mean_mode_covariance(C, area, prior.tau2, mean_variance)
    if np.any(prior.known_variance > 0):
        extra = extra + known_mean_covariance(C, area, prior.tau2, prior.known_variance)
        mean_covariance = mean_covariance + np.diag(prior.known_variance)
    return covariance + extra, C, J, mean_covariance


def calibrated_noise(loss_fn, predicted, covariance, J, movable):
    """``(sigma (n_bands,), common, figures)``: the noise re-estimated from the residuals.

    Per texel the relative residuals ``r_b`` split into their mean over bands
    ``m`` (the band-common part) and the rest ``e_b``. For noise of covariance
    ``diag(sigma^2) + common^2 1 1^T`` over ``B`` bands (equal ``sigma``),
    ``E[e_b^2] = sigma_b^2 (B - 1) / B`` and ``E[m^2] = common^2 + mean(sigma^2) / B``.
    Both moments are scaled by ``N / (N - t)``, ``t = sum_i tr(C_i Sigma_i)`` the
    degrees of freedom the posterior spends on the data (the hat matrix's
    trace; Gelman et al., Bayesian Data Analysis, 3rd ed., sec. 7.2's effective
    number of parameters), ``N`` the data terms."""

    B = len(predicted)
    weight = loss_fn.scale_numpy[:, movable] > 0
    observed = loss_fn.observed_numpy.reshape(B, -1)[:, movable]
    relative = (np.stack([np.ravel(p) for p in predicted])[:, movable] - observed) / np.maximum(observed, 1e-3)
    texels = np.all(weight, axis=0)
    relative = relative[:, texels]
    count = relative.size
    precision, _ = _precision_from_jacobian(loss_fn, J)
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


def residual_correlation(loss_fn, predicted, valid, radius=CORRELATION_RADIUS, jacobian=None, movable=None):
    """``(dy, dx) -> rho``: the correlation of the whitened relative residuals ``r_b / sigma_b``
    between texels ``(dy, dx)`` apart (both with valid input), pooled over bands.

    The albedo a capture gives is not white across texels: the demo's static albedo
    error correlates 0.43 (per band) and 0.28 (band-common) between neighbours, from the
    resampling of images into texture space, and a std that takes it as white covered
    only 67-81% of the chromophore errors within 2 std there. Residuals miss the part of
    the noise the maps absorb. With ``jacobian`` (``J_z`` of the ``movable`` texels,
    :func:`data_precision`) each texel's residual is first projected on the band
    directions no map can move, ``(I - J (J^T J)^-1 J^T) z``: there the prior's smoothing
    neither absorbs the correlated part nor leaves the white part behind, so for noise
    whose correlation between texels is the same in every band direction the
    projection's correlation is the noise's (``tr(P Sigma_ij P) / tr(P Sigma_ii P)``)."""

    B = len(predicted)
    T = valid.shape[0]
    observed = loss_fn.observed_numpy.reshape(B, T, T)
    relative = (np.stack([np.asarray(p).reshape(T, T) for p in predicted]) - observed) / np.maximum(observed, 1e-3)
    z = relative / loss_fn.sigma[:, None, None]
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


def _precision_from_jacobian(loss_fn, J):
    """The data precision per texel from ``J_z`` (:func:`data_precision`'s second output)."""
    projected = np.einsum("nbi,b->ni", J, loss_fn.v)
    return (np.einsum("nbi,nbj->nij", J, J) - loss_fn.kappa * np.einsum("ni,nj->nij", projected, projected)), projected


def _optimize(loss_fn, prior, maps, held, config, movable, progress=None):
    """Step (c) with the configured method; returns maps and the first and last loss."""
    if config.method == "gauss_newton":
        return _gauss_newton(loss_fn, prior, maps, held, config, movable, progress)
    return _adam(loss_fn, prior, maps, held, config, movable)


def _adam(loss_fn, prior, maps, held, config, movable):
    """Step (c): Adam on the maps (flat), clamped after every step; returns maps and losses.

    The data term only (``prior`` must be without a spatial part): Adam is the
    slow reference the Gauss-Newton fit is checked against."""

    if prior.spatial is not None:
        raise ValueError("method 'adam' fits without a prior: set prior to 'none'")
    Float, _, _ = jit_types()
    names = prior.names
    fixed = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS if n in held}
    opt = dr.opt.Adam(lr=1e-3)
    freeze = to_jit(Float, movable.ravel(), np.float32)  # 1 where a texel may move
    for n in names:
        opt[n] = to_jit(Float, np.ravel(maps[n]), np.float32)
    rates = {**config.learning_rates, GAIN: 1e-3}
    steps = int(config.iterations)
    decay = config.final_lr_fraction ** (1.0 / max(steps - 1, 1))
    first = None
    last = None
    for step in range(steps):
        for n in names:
            opt.set_learning_rate({n: rates[n] * decay**step})
        params = {**fixed, **{n: opt[n] for n in names}}
        loss = loss_fn(params)
        dr.backward(loss)
        for n in names:
            grad = dr.grad(opt[n])
            dr.set_grad(opt[n], grad * freeze)
        value = float(loss[0])
        first = value if first is None else first
        last = value
        opt.step()
        for n in names:
            low, high = _bounds(config, n)
            opt[n] = dr.clip(opt[n], low, high)
    out = dict(maps)
    for n in names:
        out[n] = np.array(opt[n], dtype=np.float64).reshape(maps[n].shape)
    return out, first, last, []


PRIOR_DOMINATED = 0.4
"""A map whose posterior variance over one correlation area would stay above this fraction
of its prior variance is held at its face mean (:func:`prior_dominated_maps`)."""


def prior_dominated_maps(loss_fn, maps, names, texels, spatial, config):
    """The chromophores the bands cannot tell even pooled over one correlation area.

    With ``C`` the median data precision per texel (k x k, at the start maps,
    with the other maps free) and ``P = 4 pi l^2 / area`` the texels in one
    correlation area, the pooled posterior covariance is ``(P C + diag(1 /
    s^2))^-1``; a map whose variance there exceeds :data:`PRIOR_DOMINATED`
    times its prior ``s^2`` learns less from the data than from the prior, and
    fitting it per texel turns the albedo's structured errors into spurious
    patterns (``beta_m`` with six bands: 5x the constant map's error on the
    demo). Such a map is held at its face mean, with the prior spread as its std.
    Returns those maps and, per chromophore, the fraction of its prior variance left."""

    C, _ = data_precision(loss_fn, maps, names, texels)
    typical = np.median(C, axis=0)
    pooled = 4.0 * np.pi * spatial.correlation_mm ** 2 / spatial.texel_area
    spread = np.array([config.gain_std if n == GAIN else config.prior_std[n] for n in names])
    posterior = np.linalg.inv(pooled * typical + np.diag(1.0 / spread ** 2))
    ratio = np.diag(posterior) / spread ** 2
    remaining = {n: float(r) for n, r in zip(names, ratio) if n != GAIN}
    return [n for n, r in remaining.items() if r > PRIOR_DOMINATED], remaining


def hold_prior_dominated(loss_fn, maps, names, good, spatial, config, block_means, held, held_std):
    """Hold the maps :func:`prior_dominated_maps` finds at their face means (in place).

    A held map takes its block-averaged face mean (:func:`block_face_means`, else its
    median over ``good``) everywhere, and as its std the prior spread combined with
    that mean's std; ``maps``, ``held`` and ``held_std`` are updated. Returns the maps
    held now and, per chromophore in ``names``, the fraction of its prior variance left."""

    dominated, remaining = prior_dominated_maps(loss_fn, maps, names, good.ravel(), spatial, config)
    starts = _start_means(maps, good)
    for name in dominated:
        mean, mean_std = block_means.get(name, (starts[name], 0.0))
        held[name] = maps[name] = np.full(good.shape, mean)
        held_std[name] = np.full(good.shape, np.hypot(config.prior_std[name], mean_std), np.float32)
    return dominated, remaining


def _start_means(maps, good):
    """The face means' start: each map's median over the texels with valid input."""
    return {n: float(np.median(maps[n][good])) for n in PARAMETERS}


def fit_biophysical(albedo_maps, bands, atlas, config=None, start=None, held=None, progress=None,
                    held_std=None):
    """Biophysical maps from subsurface albedo maps (see the module docstring).

    Parameters
    ----------
    albedo_maps : dict
        ``rho_sss.<band>`` (T, T) lobe albedo maps for every band (result or
        truth channel names); optional ``eta`` (T, T) refractive index map
        (else ``config.eta``) and ``confidence`` (texels with 0 are flagged).
    bands : list of Band
    atlas : TexelAtlas
        The mesh's texel atlas at the maps' resolution (texel sizes in mm).
    config : BiophysicalConfig, optional
    start : dict, optional
        Start maps of the four parameters (replaces step a), e.g. the static
        biophysical maps for a dynamic frame.
    held : dict, optional
        Maps held fixed (not optimized), e.g. ``C_m`` and ``beta_m`` of the
        static frame.
    progress : callable, optional
        Called with a message per Gauss-Newton step and per round.
    held_std : dict, optional
        Posterior standard deviation of the held maps (their ``<name>_std``
        channels then carry it); a held map without one has no std channel.

    Returns
    -------
    BiophysicalResult
    """
    t0 = time.perf_counter()
    config = config or BiophysicalConfig()
    held = dict(held or {})
    shape = atlas.valid.shape
    for name in held:
        if name not in PARAMETERS:
            raise ValueError(f"held: unknown map {name!r}; known: {list(PARAMETERS)}")
    observed = albedo_stack(albedo_maps, bands, shape)
    if "eta" in albedo_maps:
        eta = np.asarray(albedo_maps["eta"], dtype=np.float64)
        if eta.shape != tuple(shape):
            raise ValueError(f"map 'eta' is {eta.shape}, the atlas is {tuple(shape)}")
        eta_ok = np.isfinite(eta) & (eta > 1.0) & (eta < 3.0)
    else:
        eta = np.full(shape, float(config.eta))
        eta_ok = np.ones(shape, bool)
    confidence = np.asarray(albedo_maps.get("confidence", np.ones(shape)), dtype=np.float64)
    if confidence.shape != tuple(shape):
        raise ValueError(f"map 'confidence' is {confidence.shape}, the atlas is {tuple(shape)}")
    surface = np.asarray(atlas.valid, bool)
    good = (surface & eta_ok & np.all(np.isfinite(observed), axis=0) & np.all((observed >= 0) & (observed <= 1), axis=0)
            & (np.nan_to_num(confidence) > 0))
    if not good.any():
        raise ValueError("no texel has valid subsurface albedo in every band (finite, in [0, 1], confidence > 0)")
    flagged = surface & ~good
    eta = fill_from_neighbours(np.where(eta_ok, eta, np.nan), eta_ok & surface, surface)
    observed = np.stack([fill_from_neighbours(o, good, surface) for o in observed])
    observed = np.clip(observed, 1e-4, 1.0)

    rbar = observed * subsurface_exit_fraction(eta)[None]

    for name, value in list(held.items()) + list((start or {}).items()):
        if np.asarray(value).shape != tuple(shape):
            raise ValueError(f"map {name!r} is {np.asarray(value).shape}, the atlas is {tuple(shape)}")
    if start is None:
        maps, _ = start_maps(rbar, good, atlas, bands, eta, config)
    else:
        missing = [n for n in PARAMETERS if n not in start and n not in held]
        if missing:
            raise ValueError(f"start lacks {missing}")
        maps = {n: np.asarray(start[n], np.float64) for n in PARAMETERS if n in start}
    for name, value in held.items():
        maps[name] = np.asarray(value, np.float64)
    for name in PARAMETERS:
        low, high = config.bounds[name]
        maps[name] = np.clip(fill_from_neighbours(maps[name], good & np.isfinite(maps[name]), surface), low, high)
    start_copy = {n: maps[n].astype(np.float32) for n in PARAMETERS}
    with_gain = config.gain_std > 0
    names = [n for n in PARAMETERS if n not in held] + ([GAIN] if with_gain else [])
    if with_gain:
        maps[GAIN] = np.where(surface, 1.0, 1.0)

    model = BiophysicalModel(bands, atlas, eta, config.thickness_mm, config.bounds)
    # flagged texels have no data term: the prior interpolates them
    loss_fn = FitLoss(model, observed, good.astype(np.float64), config)
    length = {"correlation_mm": config.correlation_mm, "from": "config"}
    if config.prior == "matern" and config.correlation_mm == "fit":
        length = {**albedo_correlation_length(rbar, good, atlas.texel_size_mm, config.prior_order)[1], "from": "albedo"}
    spatial = (SpatialPrior(surface, atlas.texel_size_mm, length["correlation_mm"], config.prior_order)
               if config.prior == "matern" else None)
    block_means = {}
    if spatial is not None and config.face_means == "blocks":
        block_means = {n: v for n, v in block_face_means(rbar, good, atlas, bands, eta, config).items()
                       if n in names}
    movable = surface.ravel()  # the flat maps' unknowns, in the spatial prior's order
    held_std = dict(held_std or {})
    dominated, remaining = [], {}
    if spatial is not None and config.hold_uninformed:
        dominated, remaining = hold_prior_dominated(loss_fn, maps, names, good, spatial, config, block_means,
                                                    held, held_std)
        names = [n for n in names if n not in dominated]
    prior = PriorTerms(names, spatial, config, _start_means(maps, good),
                       {n: v for n, v in block_means.items() if n in names})
    texel = median_intensity_texel(observed, good)
    kernels = fit_kernels(maps, texel, bands, eta, config)
    history = []
    rounds = config.rounds
    round_index = -1
    while round_index + 1 < rounds:
        round_index += 1
        t_round = time.perf_counter()
        model.kernels = kernels

        def step_progress(message, _round=round_index):
            if progress:
                progress(f"bio round {_round + 1}/{config.rounds}, {message}")

        maps, before, after, losses = _optimize(loss_fn, prior, maps, held, config, movable, step_progress)
        if spatial is None and flagged.any():
            for name in names:
                maps[name] = fill_from_neighbours(maps[name], good, surface)
        new_kernels = fit_kernels(maps, texel, bands, eta, config)
        change = kernel_change(kernels, new_kernels)
        entry = {"round": round_index, "loss_start": before, "loss_end": after,
                 "losses": [float(v) for v in losses], "kernel_change": change}
        noise_change = 0.0
        if config.noise == "fit" and config.method == "gauss_newton":
            # re-estimate the noise at this round's maps (and kernels): the next round
            # weighs the data by it, the posterior spread is scaled by it
            predicted = loss_fn.data_terms({n: to_jit(jit_types()[0], np.ravel(maps[n]), np.float32)
                                            for n in maps})
            predicted = [np.array(p, dtype=np.float64) for p in predicted]
            covariance, _, J, _ = posterior_blocks(loss_fn, prior, maps, movable)
            sigma, common, figures = calibrated_noise(loss_fn, predicted, covariance, J, movable)
            noise_change = float(np.max(np.abs(np.log(sigma / loss_fn.sigma))))
            # the common part may be near 0: its change counts against the bands' noise
            noise_change = max(noise_change, abs(common - loss_fn.common) / float(np.mean(sigma)))
            entry.update(noise=[float(v) for v in sigma], common_noise=common, residuals=figures)
            loss_fn.set_noise(sigma, common)
            if spatial is not None and config.hold_uninformed:
                # the start's noise (albedo_noise) can overstate what the bands tell: decide
                # again with the noise the residuals show, and fit the others once more
                newly, left = hold_prior_dominated(loss_fn, maps, names, good, spatial, config, block_means,
                                                   held, held_std)
                remaining.update(left)
                if newly:
                    names = [n for n in names if n not in newly]
                    prior = prior.restricted(names)
                    dominated += newly
                    entry["held_at_face_mean"] = newly
                    rounds = max(rounds, round_index + 2)
                    noise_change = np.inf
        if config.spread == "fit" and config.method == "gauss_newton" and spatial is not None:
            C, _ = data_precision(loss_fn, maps, names, movable)
            noise_change = max(noise_change, prior.update_spreads(maps, C, movable))
            entry["spread"] = {n: float(v) for n, v in zip(names, prior.std)}
        entry["seconds"] = time.perf_counter() - t_round
        history.append(entry)
        if progress:
            progress(f"bio round {round_index + 1}: loss {before:.6g} -> {after:.6g}, "
                     f"kernel change {change:.4f}, noise change {noise_change:.3f}")
        kernels = new_kernels
        if change < config.kernel_tolerance and noise_change < NOISE_TOLERANCE:
            break
    model.kernels = kernels
    spectrum, correlation = None, {}
    if spatial is not None and config.std_noise in ("correlated", "projected"):
        # the std from the noise's own correlation between texels (a sandwich covariance)
        rendered = loss_fn.data_terms({n: to_jit(jit_types()[0], np.ravel(maps[n]), np.float32) for n in maps})
        _, J = data_precision(loss_fn, maps, names, movable) if config.std_noise == "projected" else (None, None)
        correlation = residual_correlation(loss_fn, [np.array(p, dtype=np.float64) for p in rendered], good,
                                           jacobian=J, movable=movable)
        spectrum = noise_spectrum(correlation)
    covariance, _, _, mean_covariance = posterior_blocks(loss_fn, prior, maps, movable, spectrum)
    std = {}
    for k, name in enumerate(names):
        values = np.zeros(surface.size)
        low, high = _bounds(config, name)
        values[surface.ravel()] = np.minimum(np.sqrt(np.maximum(covariance[:, k, k], 0.0)), high - low)
        std[name] = values.reshape(shape).astype(np.float32)
    for name in held:
        given = held_std.get(name)
        if given is not None:  # a held map of unknown spread gets no std channel
            std[name] = np.asarray(given, np.float32)
    predicted = model.render_numpy(maps)
    if with_gain:
        predicted = predicted * maps[GAIN][None].astype(np.float32)
    residual = np.sqrt(np.mean((predicted - observed) ** 2, axis=0))
    residual = np.where(good, residual, 0.0)
    out = {n: maps[n].astype(np.float32) for n in PARAMETERS}
    if with_gain:
        out[GAIN] = maps[GAIN].astype(np.float32)
    means = {n: {"mean": float(prior.mu[k]), "std": float(np.sqrt(max(mean_covariance[k, k], 0.0))),
                 "from": "blocks" if n in block_means else "joint"}
             for k, n in enumerate(names) if prior.free[k] or n in block_means}
    noise = {"relative_sigma": {b.name: float(s) for b, s in zip(bands, loss_fn.sigma)},
             "held_at_face_mean": dominated,
             "prior_variance_left": remaining,
             "common_relative_sigma": loss_fn.common,
             "model": config.noise, "face_means": means, "std_noise": config.std_noise,
             "correlation_length": length,
             "residual_correlation": {f"{dy},{dx}": round(v, 4) for (dy, dx), v in sorted(correlation.items())
                                      if dy > 0 or (dy == 0 and dx > 0)},
             "spread": {n: float(v) for n, v in zip(names, prior.std)}}
    return BiophysicalResult(out, residual.astype(np.float32), flagged, kernels, history,
                             predicted, start_copy, time.perf_counter() - t0, std, noise)
