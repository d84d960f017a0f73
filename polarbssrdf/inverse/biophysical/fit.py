"""The biophysical stage: melanin and hemoglobin maps from subsurface albedo maps (supplement sec. 5.3).

``fit_biophysical(albedo_maps, bands, atlas)`` recovers ``C_m, beta_m, C_h_out, C_h_in`` per
texel with their posterior std, by one algorithm:

* the problem (:mod:`.problem`): the input lobe albedo per band against the band integral
  a camera records, rendered through the bands' spectral quadrature and the texture-space
  layered blur synth renders with (:class:`~.model.BiophysicalModel`, eq. 40-47) at the
  face's epidermal thickness and oxygenation (``config.thickness_mm``, ``config.gamma``)
  and the input index map, seen through the capture's blur (``config.capture_blur_mm``);
  the bands' own and band-common noise; a Matérn prior on every chromophore map around its
  face mean, freed at local features such as freckles (``config.feature_fraction``,
  :func:`~.prior.feature_coupling`);
* the start (:mod:`.start`): the per-texel inversion of eq. 47 on block means, and the
  face means from larger blocks (:func:`~.start.block_face_means`, their std with what the
  face's held thickness and oxygenation may move them, :func:`~.start.face_mean_skin_shifts`,
  combined with Table 2's rows), which the maps' own mean is then held near;
* one projected Gauss-Newton over the chromophore maps (:mod:`.gauss_newton`);
* one outer loop (at most ``rounds``): between Gauss-Newton runs the layer kernels are
  fitted at the median texel, the noise is re-estimated from the residuals and the
  chromophores' spreads by expectation-maximization. It stops once the kernels change by
  less than ``kernel_tolerance`` and no noise estimate nor spread moves by more than
  :data:`OUTER_TOLERANCE`; the rounds before that end their steps at
  :data:`EARLY_ROUND_TOLERANCE`, the last at ``config.tolerance``;
* the posterior standard deviation of every map per texel (:mod:`.uncertainty`), with what
  the skin's other unknowns move the maps by (:data:`~.config.NUISANCES`): the thickness and
  oxygenation at the face level (``nuisance_mean``'s std) and within the face
  (``nuisance_std``), and the index's error (the input ``eta_std``).

A map the bands cannot tell keeps a posterior close to its prior: it stays near its face mean
with about the prior spread as its std (shrinkage, no threshold deciding that a map is held).

The face's oxygenation is estimated first, from the band shape no chromophore can mimic
(:mod:`.oxygenation`; ``config.oxygenation``). The thickness is not: with the default six
bands it is degenerate with the dermal blood (0.05 mm more epidermis moved the fitted
``C_h_in`` by +0.14 on a cheek III face), and neither a search over per-block inversions
(noise-free, it found 0.24 mm for a 0.30 mm face: block averaging's own nonlinearity
outweighs what separates them) nor a Newton step of the problem reduced to the face values
(it moved away from the truth) recovered it (docs/biophysical.md).

Input albedos are lobe albedos (``rho_sss`` of eq. 19, what the static stage recovers and
synth's truth maps hold); the skin model's flux ``R_bar`` is ``c(eta) rho_sss``
(docs/biophysical.md). Texels whose input is not finite, outside [0, 1] or of confidence 0
in any band do not enter the data term, take their values from the prior and are flagged.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.biophysical.config import NUISANCES, BiophysicalConfig
from polarbssrdf.inverse.biophysical.correlation import albedo_correlation_length
from polarbssrdf.inverse.biophysical.gauss_newton import INITIAL_DAMPING, PriorTerms, gauss_newton
from polarbssrdf.inverse.biophysical.model import PARAMETERS, BiophysicalModel, jit_types
from polarbssrdf.inverse.biophysical.oxygenation import face_oxygenation
from polarbssrdf.inverse.biophysical.prior import SpatialPrior, capture_gain, feature_coupling, noise_spectrum
from polarbssrdf.inverse.biophysical.problem import DataTerm, NuisanceSensitivity
from polarbssrdf.inverse.biophysical.start import (
    albedo_stack,
    block_face_means,
    face_mean_skin_shifts,
    fill_from_neighbours,
    start_maps,
)
from polarbssrdf.inverse.biophysical.uncertainty import calibrated_noise, posterior_blocks, residual_correlation
from polarbssrdf.render.subsurface import layer_profile_kernels, subsurface_exit_fraction
from polarbssrdf.skin.parameters import SkinParameters
from polarbssrdf.skin.quadrature import DESIGN_BOX, spectral_quadrature

OUTER_TOLERANCE = 0.05
"""The outer loop stops once the kernels have settled and no band's noise estimate, map's
spread (relative) nor the face's thickness and oxygenation (in their spread) moved by more."""

EARLY_ROUND_TOLERANCE = 1e-3
"""Relative loss decrease at which the Gauss-Newton steps of a round before the last end: the
noise and spreads the next round re-estimates move every map's weights (by 7-107% after the
first two rounds of a 128^2 freckled face), so steps past it were spent on a landscape about
to change. On that face rounds 1 and 2 took their 12-step limit with the decrease still
2.8e-4 and 2.0e-4 (bench/RESULTS.md, 2026-12-07)."""

NOISE_FLOOR = 2e-4
"""Smallest relative noise the fit assumes: the model's own error (its tables, the kernels'
fit, float32) is of this order, so residuals below it do not make the data term stiffer."""

@dataclasses.dataclass
class BiophysicalResult:
    """Maps (T, T float32) of the fit and what it did.

    ``maps``: the four chromophores and, where fitted, ``thickness_mm``, ``gamma`` and
    ``eta``. ``residual`` is the RMS over bands of rendered minus input albedo (0 at
    flagged texels), ``flagged`` marks surface texels whose input was invalid (their
    values come from the prior). ``std``: the posterior standard deviation per map (same
    units; 0 off the surface); ``noise``: the bands' relative noise, the face means with
    their std, the spreads. ``history`` has one entry per round: loss before/after,
    kernel change, the noise estimate, the face values, seconds."""

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
        """Channels of the stage's map file: the maps, their ``<name>_std``, ``residual``, ``flagged``."""
        out = {}
        for name in (*PARAMETERS, *NUISANCES):
            if name in self.maps:
                out[name] = np.ascontiguousarray(self.maps[name], dtype=np.float32)
            if name in self.std:
                out[f"{name}_std"] = np.ascontiguousarray(self.std[name], dtype=np.float32)
        out["residual"] = np.ascontiguousarray(self.residual, dtype=np.float32)
        out["flagged"] = self.flagged.astype(np.float32)
        return out


def median_intensity_texel(observed, valid):
    """Flat index of the valid texel of median mean-over-bands albedo."""
    intensity = observed.mean(axis=0).ravel()
    index = np.flatnonzero(valid.ravel())
    order = np.argsort(intensity[index])
    return int(index[order[len(order) // 2]])


def fit_kernels(maps, texel, model):
    """The layer kernels of every quadrature node at the chromophores of one texel (eq. 40, 43,
    45), with the model's thickness, oxygenation and index there."""

    values = {name: float(np.ravel(maps[name])[texel]) for name in PARAMETERS}
    skin = SkinParameters(**values, thickness_mm=model.thickness_mm, gamma=model.gamma,
                          eta=float(np.ravel(model.eta)[texel]))
    return layer_profile_kernels(model.quadrature, skin)


def kernel_change(old, new):
    """Largest absolute change of a normalized SoG weight over nodes and profiles."""
    return max(float(np.max(np.abs(np.asarray(o[name][0]) - np.asarray(n[name][0]))))
               for o, n in zip(old, new) for name in o)


def _checked_inputs(albedo_maps, bands, shape, surface, config):
    """The input albedo, index and its std, and which texels enter the data term."""
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
    good = (surface & eta_ok & np.all(np.isfinite(observed), axis=0)
            & np.all((observed >= 0) & (observed <= 1), axis=0) & (np.nan_to_num(confidence) > 0))
    if not good.any():
        raise ValueError("no texel has valid subsurface albedo in every band (finite, in [0, 1], confidence > 0)")
    eta = fill_from_neighbours(np.where(eta_ok, eta, np.nan), eta_ok & surface, surface)
    observed = np.clip(np.stack([fill_from_neighbours(o, good, surface) for o in observed]), 1e-4, 1.0)
    eta_std = None
    if "eta_std" in albedo_maps:
        values = np.asarray(albedo_maps["eta_std"], dtype=np.float64)
        if values.shape != tuple(shape):
            raise ValueError(f"map 'eta_std' is {values.shape}, the atlas is {tuple(shape)}")
        values = values[good]
        values = values[np.isfinite(values) & (values > 0)]
        eta_std = float(np.median(values)) if values.size else None
    return observed, eta, eta_std, good


NOISE_SCALE_FLOOR = 0.25
"""Smallest :func:`texel_noise_scale`: a texel whose input std claims far less noise than the
face's typical texel would otherwise outweigh its neighbours on a std that may be a hair from 0."""


def texel_noise_scale(albedo_maps, bands, observed, good):
    """(T, T) each texel's albedo noise relative to the face's typical texel, from the input's
    ``rho_sss.<band>_std`` (the static stage's per-texel posterior); 1 everywhere without them.

    Per texel the root mean square over bands of the relative std ``std_b / a_b``, divided by
    its median over the texels that enter the data term, floored at
    :data:`NOISE_SCALE_FLOOR`. The static stage's std varies over a face with the views that
    see each texel (2-3x between the 10th and 90th percentile texel of the demo and of a
    4-view cheek): the biophysical stage keeps its own calibration of the noise's level and
    band structure (``calibrated_noise``) and takes from the input only how each texel's noise
    stands to the typical one's (issue 33, item 5). Texels without a finite positive std in
    every band get 1."""

    shape = good.shape
    names = [f"rho_sss.{band.name}_std" for band in bands]
    if not all(name in albedo_maps for name in names):
        return np.ones(shape)
    std = []
    for name in names:
        values = np.asarray(albedo_maps[name], dtype=np.float64)
        if values.shape != tuple(shape):
            raise ValueError(f"map {name!r} is {values.shape}, the atlas is {tuple(shape)}")
        std.append(values)
    relative = np.sqrt(np.mean(np.square(np.stack(std) / observed), axis=0))
    usable = good & np.isfinite(relative) & (relative > 0)
    if not usable.any():
        return np.ones(shape)
    scale = relative / float(np.median(relative[usable]))
    return np.where(usable, np.maximum(scale, NOISE_SCALE_FLOOR), 1.0)


def nuisance_priors(config, eta_std, face):
    """``name -> (within-face spread, variance of the face value)`` of the nuisances the std
    marginalizes (:data:`~polarbssrdf.inverse.biophysical.config.NUISANCES`): thickness and
    oxygenation with the config's spreads and the face step's posterior variance, the index
    with the input's ``eta_std`` (else the config's spread) around the input map. A spread
    of 0 leaves a nuisance out."""
    out = {}
    for name in NUISANCES:
        std = config.nuisance_std[name]
        if name == "eta":
            std = eta_std if (eta_std is not None and std > 0) else std
            if std > 0:
                out[name] = (std, 0.0)
        elif std > 0:
            out[name] = (std, float(face.get(f"{name}_variance", 0.0)))
    return out


def face_mean_hyperprior(config, names, blocks):
    """``name -> (mean, variance)`` of each chromophore's face mean: the block estimate
    (:func:`~.start.block_face_means`, ``(mean, std)``) combined with the population
    hyperprior ``config.prior_mean`` (precision-weighted), or the latter alone."""
    out = {}
    for name in names:
        mean, std = config.prior_mean[name]
        precision, weighted = 1.0 / std ** 2, mean / std ** 2
        if name in blocks:
            block, block_std = blocks[name]
            block_precision = 1.0 / max(block_std, 1e-6) ** 2
            precision, weighted = precision + block_precision, weighted + block * block_precision
        out[name] = (weighted / precision, 1.0 / precision)
    return out


def fit_biophysical(albedo_maps, bands, atlas, config=None, start=None, held=None, progress=None,
                    held_std=None):
    """Biophysical maps from subsurface albedo maps (see the module docstring).

    Parameters
    ----------
    albedo_maps : dict
        ``rho_sss.<band>`` (T, T) lobe albedo maps for every band (result or
        truth channel names); optional ``eta`` (T, T) refractive index map
        (else ``config.eta``) with its ``eta_std`` (the static stage's posterior:
        its median is the index's spread), optional ``rho_sss.<band>_std`` for every
        band (each texel's noise relative to the typical texel's weighs its data,
        :func:`texel_noise_scale`), and ``confidence`` (texels with 0 are flagged).
    bands : list of Band
    atlas : TexelAtlas
        The mesh's texel atlas at the maps' resolution (texel sizes in mm).
    config : BiophysicalConfig, optional
    start : dict, optional
        Start maps of the four chromophores (replaces the per-texel start), e.g. the
        static frame's maps for a dynamic frame.
    held : dict, optional
        Chromophore maps held fixed (not fitted), e.g. ``C_m`` and ``beta_m`` of the
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
    Float, _, _ = jit_types()
    config = config or BiophysicalConfig()
    held = dict(held or {})
    shape = atlas.valid.shape
    surface = np.asarray(atlas.valid, bool)
    for name in held:
        if name not in PARAMETERS:
            raise ValueError(f"held: unknown map {name!r}; known: {list(PARAMETERS)}")
    for name, value in list(held.items()) + list((start or {}).items()):
        if np.asarray(value).shape != tuple(shape):
            raise ValueError(f"map {name!r} is {np.asarray(value).shape}, the atlas is {tuple(shape)}")
    observed, eta, eta_std, good = _checked_inputs(albedo_maps, bands, shape, surface, config)
    flagged = surface & ~good
    rbar = observed * subsurface_exit_fraction(eta)[None]

    # the face's thickness is held at the config's value, known only as well as its
    # hyperprior says; its oxygenation is estimated unless held (module docstring)
    face = {"thickness_mm": float(config.thickness_mm), "gamma": float(config.gamma),
            "thickness_mm_variance": config.nuisance_mean["thickness_mm"][1] ** 2,
            "gamma_variance": config.nuisance_mean["gamma"][1] ** 2}
    if config.oxygenation == "fit":
        if progress:
            progress("bio: the face's oxygenation from the band shape")
        oxygenation = face_oxygenation(rbar, good, atlas, bands, eta, config, face["thickness_mm"])
        face.update(gamma=oxygenation.gamma, gamma_variance=oxygenation.std ** 2,
                    oxygenation=oxygenation.to_json())
    if start is None:
        maps, _ = start_maps(rbar, good, atlas, bands, eta, config, face["thickness_mm"], face["gamma"])
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

    quadrature = spectral_quadrature(bands, config.spectral)
    model = BiophysicalModel(quadrature, atlas, eta, face["thickness_mm"], config.bounds, gamma=face["gamma"])
    noise_scale = texel_noise_scale(albedo_maps, bands, observed, good)
    blur_variance = float(config.capture_blur_mm or 0.0) ** 2
    data = DataTerm(model, observed, good / noise_scale, np.full(len(bands), config.albedo_noise),
                    config.common_noise, blur_variance)
    length = {"correlation_mm": config.correlation_mm, "from": "config"}
    spatial = None
    if config.prior == "matern":
        if config.correlation_mm == "fit":
            length = {**albedo_correlation_length(rbar, good, atlas.texel_size_mm, config.prior_order)[1],
                      "from": "albedo"}
        spatial = SpatialPrior(surface, atlas.texel_size_mm, length["correlation_mm"], config.prior_order)
    chromophores = [n for n in PARAMETERS if n not in held]
    bounds = {n: config.bounds[n] for n in chromophores}
    blocks = {}
    if spatial is not None:
        blocks = block_face_means(rbar, good, atlas, bands, eta, config, face["thickness_mm"], face["gamma"])
        # the face values the std marginalizes are not known: their share in the face means
        face_std = {n: float(np.sqrt(face[f"{n}_variance"])) for n in ("thickness_mm", "gamma")
                    if config.nuisance_std[n] > 0}
        shifts = face_mean_skin_shifts(rbar, good, atlas, bands, eta, config, face["thickness_mm"],
                                       face["gamma"], face_std)
        blocks = {n: (mean, float(np.hypot(std, shifts[n]))) for n, (mean, std) in blocks.items()}
        face["face_mean_skin_std"] = shifts
    hyper = face_mean_hyperprior(config, chromophores, blocks)
    coupling = None
    if spatial is not None and config.feature_fraction > 0 and chromophores:
        # which map each albedo departure is, read through the start maps' Jacobian
        jacobian = data.local_jacobian(maps, chromophores)[surface.ravel()]
        relative = jacobian / np.maximum(observed.reshape(len(bands), -1)[:, surface.ravel()].T, 1e-4)[:, :, None]
        weights, pairs = feature_coupling(observed, good, spatial, relative, config.feature_fraction,
                                          config.feature_spread)
        kept = np.array([n in config.feature_maps for n in chromophores])
        coupling = (np.where(kept, weights, 1.0), np.where(kept, pairs, 1.0))
    # a mean from the blocks is fixed there (with its variance for the std); else the face
    # mean is fitted under the population hyperprior
    known = [hyper[n][1] if spatial is not None else 0.0 for n in chromophores]
    prior = PriorTerms(chromophores, spatial, std=[config.prior_std[n] for n in chromophores],
                       mean0=[hyper[n][0] for n in chromophores],
                       mean_variance=[0.0 if spatial is not None else hyper[n][1] for n in chromophores],
                       start=[hyper[n][0] for n in chromophores], adapt=[config.spread == "fit"] * len(chromophores),
                       known_variance=known,
                       coupling=coupling,
                       gain=None if spatial is None else capture_gain(spatial.area, blur_variance))
    movable = surface.ravel()  # the flat maps' unknowns, in the spatial prior's order
    texel = median_intensity_texel(observed, good)
    history = []
    kernels = None
    damping = INITIAL_DAMPING
    for round_index in range(config.rounds):
        t_round = time.perf_counter()
        new_kernels = fit_kernels(maps, texel, model)
        change = None if kernels is None else kernel_change(kernels, new_kernels)  # None: the first
        kernels = model.kernels = new_kernels

        def step_progress(message, _round=round_index):
            if progress:
                progress(f"bio round {_round + 1}/{config.rounds}, {message}")

        # a round whose noise and spreads are still moving ends its steps early; the last
        # round the loop allows, and the one after which it stops, end at the config's tolerance
        tolerance = (config.tolerance if round_index == config.rounds - 1
                     else max(config.tolerance, EARLY_ROUND_TOLERANCE))
        maps, before, after, losses, damping = gauss_newton(
            data, prior, maps, list(held), bounds, movable, config.iterations, tolerance, step_progress,
            damping)
        entry = {"round": round_index, "loss_start": before, "loss_end": after,
                 "losses": [float(v) for v in losses], "kernel_change": change}
        moved = 0.0
        if config.noise == "fit":
            predicted = _predicted(data, maps)
            covariance, _, J, _ = posterior_blocks(data, prior, maps, movable)
            sigma, common, figures = calibrated_noise(data, predicted, covariance, J, movable)
            sigma = np.maximum(sigma, NOISE_FLOOR)
            moved = max(moved, float(np.max(np.abs(np.log(sigma / data.sigma)))),
                        # the common part may be near 0: its change counts against the bands' noise
                        abs(common - data.common) / float(np.mean(sigma)))
            entry.update(noise=[float(v) for v in sigma], common_noise=common, residuals=figures)
            data.set_noise(sigma, common)
        if config.spread == "fit" and spatial is not None:
            C, _ = data.precision(maps, chromophores, movable)
            moved = max(moved, prior.update_spreads(maps, C, movable))
            entry["spread"] = {n: float(v) for n, v in zip(chromophores, prior.std)}
        entry["seconds"] = time.perf_counter() - t_round
        history.append(entry)
        if progress:
            progress(f"bio round {round_index + 1}: loss {before:.6g} -> {after:.6g}, "
                     f"kernel change {'-' if change is None else f'{change:.4f}'}, largest move {moved:.3f}")
        if change is not None and change < config.kernel_tolerance and moved < OUTER_TOLERANCE:
            if tolerance > config.tolerance:  # the round ended early: finish its steps
                maps, _, after, losses, damping = gauss_newton(
                    data, prior, maps, list(held), bounds, movable, config.iterations, config.tolerance,
                    step_progress, damping)
                entry.update(loss_end=after, finished=[float(v) for v in losses],
                             seconds=time.perf_counter() - t_round)
            break
    nuisances = nuisance_priors(config, eta_std, face) if spatial is not None else {}
    if nuisances:
        data.set_sensitivity(NuisanceSensitivity(quadrature, maps, np.flatnonzero(movable),
                                                 model.thickness_mm, model.gamma, eta))
    std, noise = _uncertainty(data, prior, nuisances, maps, movable, good, held, held_std, config, bounds)
    predicted = np.stack(_predicted(data, maps)).reshape(len(bands), *shape).astype(np.float32)
    residual = np.where(good, np.sqrt(np.mean((predicted - observed) ** 2, axis=0)), 0.0)
    out = {n: maps[n].astype(np.float32) for n in PARAMETERS}
    scale_quantiles = np.quantile(noise_scale[good], [0.1, 0.5, 0.9])
    if prior.weights is not None:
        # texels where a local feature freed a map's prior (weight below one half)
        noise["freed_texels"] = {n: int(np.sum(prior.weights[:, i] < 0.5)) for i, n in enumerate(chromophores)}
    noise["capture_blur_mm"] = float(config.capture_blur_mm or 0.0)
    noise.update(correlation_length=length, face=face, model=config.noise, std_noise=config.std_noise,
                 texel_noise_scale={"from": "input std" if np.any(noise_scale != 1.0) else "none",
                                    "q10": float(scale_quantiles[0]), "q50": float(scale_quantiles[1]),
                                    "q90": float(scale_quantiles[2])})
    return BiophysicalResult(out, residual.astype(np.float32), flagged, kernels, history,
                             predicted, start_copy, time.perf_counter() - t0, std, noise)


def _predicted(data, maps):
    """Per band, the predicted albedo (flat float64) of NumPy maps."""
    Float, _, _ = jit_types()
    params = {n: to_jit(Float, np.ravel(v), np.float32) for n, v in maps.items()}
    return [np.array(p, dtype=np.float64) for p in data.predict(params)]


def _uncertainty(data, prior, nuisances, maps, movable, good, held, held_std, config, bounds):
    """``(std maps, noise figures)``: the posterior std of every fitted chromophore, with what
    the ``nuisances`` (:func:`nuisance_priors`) move the maps by: the within-face part as the
    error of maps fitted with the nuisances held (the fit does not estimate them), the face
    values' through the joint posterior's face means; in the sandwich form with the
    residuals' correlation between texels as ``config.std_noise`` says; and the held maps' std."""
    shape = good.shape
    chromophores = prior.names
    spectrum, correlation = None, {}
    if prior.spatial is not None and config.std_noise in ("correlated", "projected"):
        predicted = _predicted(data, maps)
        J = None
        if config.std_noise == "projected" and chromophores:
            # the band directions no chromophore can move
            _, J = data.precision(maps, chromophores, movable)
        correlation = residual_correlation(data, predicted, good, jacobian=J, movable=movable)
        spectrum = noise_spectrum(correlation)
    joint = prior
    if nuisances and prior.spatial is not None:
        k = len(chromophores)
        joint = PriorTerms(chromophores + list(nuisances), prior.spatial,
                           std=list(prior.std) + [v[0] for v in nuisances.values()],
                           mean0=list(prior.mu) + [0.0] * len(nuisances),
                           mean_variance=list(prior.mean_variance) + [v[1] for v in nuisances.values()],
                           start=list(prior.mu) + [0.0] * len(nuisances), adapt=[False] * (k + len(nuisances)),
                           known_variance=list(prior.known_variance) + [0.0] * len(nuisances),
                           coupling=(None if prior.coupling is None else tuple(
                               np.concatenate([c, np.ones((len(c), len(nuisances)))], axis=1)
                               for c in prior.coupling)),
                           gain=prior.gain)
    covariance, _, _, mean_covariance = posterior_blocks(data, joint, maps, movable, spectrum,
                                                         held=len(joint.names) - len(chromophores))
    std = {}
    for k, name in enumerate(chromophores):
        values = np.zeros(good.size)
        low, high = bounds[name]
        values[movable] = np.minimum(np.sqrt(np.maximum(covariance[:, k, k], 0.0)), high - low)
        std[name] = values.reshape(shape).astype(np.float32)
    for name in held:
        given = (held_std or {}).get(name)
        if given is not None:  # a held map of unknown spread gets no std channel
            std[name] = np.asarray(given, np.float32)
    means = {n: {"mean": float(prior.mu[k]), "std": float(np.sqrt(max(mean_covariance[k, k], 0.0)))}
             for k, n in enumerate(chromophores) if prior.free[k] or prior.known_variance[k] > 0}
    noise = {"relative_sigma": {b.name: float(s) for b, s in zip(data.model.bands, data.sigma)},
             "common_relative_sigma": data.common, "face_means": means,
             "marginalized": {n: {"spread": v[0], "face_std": float(np.sqrt(v[1]))} for n, v in nuisances.items()},
             "residual_correlation": {f"{dy},{dx}": round(v, 4) for (dy, dx), v in sorted(correlation.items())
                                      if dy > 0 or (dy == 0 and dx > 0)},
             "spread": {n: float(v) for n, v in zip(chromophores, prior.std)}}
    return std, noise
