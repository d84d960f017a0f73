"""The fit both polarimetric stages run: epochs of patch steps, checkpoints, confidence, final maps.

:func:`run_polarimetric_fit` optimizes the maps of one frame on its
texture-space observations (:mod:`polarbssrdf.inverse.observations`) and returns
them in the result format (:mod:`polarbssrdf.inverse.results.directory`); the
static stage (:mod:`.static`, supplement sec. 5.1) runs it from constant start
maps, the dynamic stage (:mod:`.dynamic`, sec. 5.2) from the static maps with
the index and roughness held.

Each epoch visits every patch in a seeded random order (a texture of one
patch repeats it ``min_steps_per_epoch`` times) and takes one optimizer step
on it (:mod:`polarbssrdf.inverse.polarimetric.optimize`). After every
epoch the maps, the optimizer state and the loss history are checkpointed
atomically, so a killed run resumes at the last finished epoch and ends
with the same maps as an uninterrupted one. A step's gradient does not
depend on how many threads Dr.Jit runs it on (its per-texel sums are taken
in a fixed order, see :func:`polarbssrdf.inverse.polarimetric.optimize.patch_leaves`), so
runs repeat bit for bit on any number of cores.

Confidence: ``min(1, n / 8)`` for a texel with ``n`` usable texel-views
(view and light cosines above ``min_cosine`` with the final normals), 0
below ``min_views`` and 0 where the fitted model leaves residuals far above
the typical texel's, beyond what the texel's step from its neighbours'
albedo explains (:func:`texel_confidence`, :func:`feature_chi_square`: a
freckle is a feature, not an outlier); confidence-0 texels (and
texels off the mesh) take the values of their confident neighbours
(normalized Gaussian fill), never NaN. The share of the surface that is
confident is returned (:func:`confidence_summary`); below
:data:`LOW_CONFIDENT_FRACTION` the stages warn, and a fit with no confident
texel fails (:class:`NoConfidentTexelError`).

Specular peak angle (``specular_peak_angle``, degrees): between the fitted
normal and the closest half vector among the texel's usable texel-views.
With near-coaxial light a view samples a texel's glossy lobes near their
peak only when it looks at the texel nearly head-on; where this angle is
large the lobes were seen on their tails alone, so ``alpha_s`` and ``rho_s``
rest on the tail's shape and on the smoothness prior (eq. 35), while ``eta``,
``rho_sss`` and the normals are still measured. On a 12-view sphere the
``alpha_s`` error is 0.003 where the angle is below 10 degrees and 0.029
above 30 degrees (bench/RESULTS.md).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import zipfile
from pathlib import Path

import drjit as dr
import numpy as np
from tqdm import tqdm

from polarbssrdf._arrays import to_jit
from polarbssrdf.geometry.height import normals_from_height
from polarbssrdf.inverse.polarimetric.config import OPTIMIZED
from polarbssrdf.inverse.polarimetric.model import GLOSSY_PARAMETERS, half_vector_cosine
from polarbssrdf.inverse.polarimetric.face_level import (
    FALLBACK_MAPS,
    fit_face_levels,
    held_std_channels,
    hold_at_face_level,
    unresolved_maps,
)
from polarbssrdf.inverse.polarimetric.optimize import (
    MapParameters,
    active_weights,
    optimizer_step,
    per_view_normals,
    predicted_patch,
    texel_view_terms,
)
from polarbssrdf.inverse.polarimetric.patches import PatchCache, patch_order, texture_patches
from polarbssrdf.inverse.polarimetric.posterior import map_posterior_std
from polarbssrdf.inverse.polarimetric.relief_level import (
    chart_level_variance,
    relief_at_prior_level,
)
from polarbssrdf.inverse.results.fill import fill_from_neighbours
from polarbssrdf.io.atomic import atomic_write_bytes

FULL_CONFIDENCE_VIEWS = 8
INITIAL_RHO_SSS = 0.5

LOW_CONFIDENT_FRACTION = 0.5
"""Below this share of the surface (texels on the mesh) with confidence > 0 a stage warns:
most of its maps are then not measured but filled in from neighbours (a capture whose
cameras see less than half of the object, e.g. 3 views of a face, is below it)."""


class NoConfidentTexelError(ValueError):
    """A polarimetric fit in which no texel of the surface is confident: no map was measured."""


@dataclasses.dataclass
class StageResult:
    """What a polarimetric stage returns: the maps (channel -> (T, T)), the loss history and
    :func:`confidence_summary`."""

    maps: dict
    history: list
    path: Path | None = None
    confidence: dict | None = None
    held: dict = dataclasses.field(default_factory=dict)
    """Maps held at the face's level
    (:func:`polarbssrdf.inverse.polarimetric.face_level.hold_at_face_level`)."""
    face_levels: dict | None = None
    """The record of the face-level start
    (:func:`polarbssrdf.inverse.polarimetric.face_level.fit_face_levels`; ``None`` when
    ``face_level_evaluations`` is 0, for a resumed run and for a run handed its start)."""


def initial_parameters(config, texture_size, n_bands, start=None):
    """Start maps: the config's constants, or ``start`` maps where given."""
    maps = {name: np.full((texture_size, texture_size), config.initial[name], np.float32)
            for name in OPTIMIZED}
    rho_sss = np.full((n_bands, texture_size, texture_size), INITIAL_RHO_SSS, np.float32)
    for name, values in (start or {}).items():
        if name in maps:
            maps[name] = np.asarray(values, np.float32)
    return maps, rho_sss


def run_fingerprint(config, texture_size, bands, texel_views):
    """What a checkpoint must share with the run that resumes it (a short hash)."""

    settings = dict(config.to_json())
    settings.pop("iterations")  # a run may be extended by more epochs
    settings.pop("bio", None)  # the later stages' settings do not change this fit
    settings.pop("dynamic", None)
    settings.pop("capture_blur_mm", None)  # the posterior's, not the fit's
    text = json.dumps({"config": settings, "texture": int(texture_size), "bands": list(bands),
                       "texel_views": int(texel_views)}, sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _text_array(text):
    return np.frombuffer(text.encode("utf-8"), dtype=np.uint8)


def save_checkpoint(path, params, epoch, history, fingerprint=""):
    """Write the optimizer state after ``epoch`` epochs, atomically."""

    buffer = io.BytesIO()
    state = params.state()
    np.savez(buffer, epoch=np.int64(epoch), history=_text_array(json.dumps(history)),
             fingerprint=_text_array(fingerprint), **state)
    atomic_write_bytes(path, buffer.getvalue(), overwrite=True)


def load_checkpoint(path, params, fingerprint=""):
    """Restore ``params`` from a checkpoint; returns ``(epochs_done, history)``.

    Refuses a checkpoint written by a run with other settings (``fingerprint``).
    """
    try:
        with np.load(path) as data:
            state = {key: data[key] for key in data.files}
        for key in ("epoch", "history"):
            if key not in state:
                raise KeyError(key)
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as error:
        # cut short (a full disk, a copy that stopped) or replaced by another file
        raise ValueError(f"checkpoint {path} is unreadable ({type(error).__name__}: {error}); "
                         "remove it to fit that stage from its start, or rerun with "
                         "--overwrite") from None
    stored = bytes(state.get("fingerprint", np.zeros(0, np.uint8))).decode("utf-8")
    if stored != fingerprint:
        raise ValueError(f"checkpoint {path} was written by a run with other settings (config, "
                         "texture, bands or observations); remove it or rerun with those "
                         "settings")
    params.restore(state)
    history = json.loads(bytes(state["history"]).decode("utf-8"))
    return int(state["epoch"]), history


def _epoch_summary(records):
    """Mean of each loss term over an epoch's steps (skipped steps and dropped texel-views
    counted, not averaged)."""
    records = [r for r in records if r is not None]
    if not records:
        return {}
    taken = [r for r in records if not r.get("skipped")] or records
    summary = {key: float(np.mean([r[key] for r in taken])) for key in records[0]}
    for key in ("skipped", "dropped_views"):
        summary[key] = float(sum(r.get(key, 0.0) for r in records))
    return summary


def epoch_noise(config, history):
    """The noise unit of the next epoch: the config's, or (``estimate_noise``) the RMS
    ``I_sss`` residual of the last epoch relative to the mean ``I_sss``, never below the
    config's value.

    The last epoch's ``L_sss`` is a chi-square in units of its own noise, so its
    square root rescales that noise to the residual the fit actually leaves.
    """
    if not config.estimate_noise or not history:
        return config.photometric_noise
    last = history[-1]
    previous = last.get("photometric_noise", config.photometric_noise)
    chi_square = last.get("sss", float("nan"))
    if not np.isfinite(chi_square):
        return previous
    return float(max(config.photometric_noise, previous * np.sqrt(max(chi_square, 0.0))))


def optimize_maps(store, atlas, config, params, checkpoint=None, progress=True, weights=None,
                  description="fit", face_levels=()):
    """Run the epochs of a polarimetric stage (resuming from ``checkpoint`` when it exists).

    A run that starts at epoch 0 first fits one face-wide value of each map of
    ``face_levels`` (:func:`~polarbssrdf.inverse.polarimetric.face_level.fit_face_levels`,
    at most ``config.face_level_evaluations`` passes; a resumed run restores its maps
    instead). Returns ``(history, cache, start)``: the loss history (one summary per
    epoch), the patch cache and the face-level fit's record (``None`` when not run).
    """

    weights = active_weights(config, weights)
    patches = texture_patches(atlas.resolution, config.patch_size, store.block_size)
    cache = PatchCache(store, atlas)
    fingerprint = run_fingerprint(config, atlas.resolution, store.bands, len(store))
    history, first = [], 0
    if checkpoint is not None and Path(checkpoint).is_file():
        first, history = load_checkpoint(checkpoint, params, fingerprint)
        if first > config.iterations:
            raise ValueError(f"checkpoint {checkpoint} holds {first} epochs, more than the "
                             f"{config.iterations} asked for")
    start = None
    if first == 0 and face_levels and config.face_level_evaluations > 0:
        start = fit_face_levels(params, cache, patches, config, weights, tuple(face_levels),
                                atlas.valid, config.face_level_evaluations, progress,
                                f"{description}: face levels")
    with tqdm(total=config.iterations, initial=first, desc=description, unit="epoch",
              disable=not progress) as bar:
        for epoch in range(first, config.iterations):
            params.scale_learning_rates(
                config.final_learning_rate ** (epoch / max(config.iterations - 1, 1)))
            epoch_config = dataclasses.replace(config, photometric_noise=epoch_noise(config,
                                                                                     history))
            records = [optimizer_step(params, cache.get(patch), epoch_config, weights)
                       for patch in patch_order(patches, epoch, config.seed,
                                                config.min_steps_per_epoch)]
            summary = _epoch_summary(records)
            summary["epoch"] = epoch + 1
            summary["photometric_noise"] = epoch_config.photometric_noise
            history.append(summary)
            if checkpoint is not None:
                save_checkpoint(checkpoint, params, epoch + 1, history, fingerprint)
            bar.set_postfix(loss=f"{summary.get('total', float('nan')):.3g}")
            bar.update()
    return history, cache, start


UNSEEN_PEAK_ANGLE_DEG = 90.0
"""``specular_peak_angle`` of a texel without usable texel-views."""


@dataclasses.dataclass
class TexelStatistics:
    """Per texel (T, T) float64 summaries of the fitted texel-views.

    Attributes
    ----------
    counts : array
        Usable texel-views (view and light cosines above ``min_cosine``).
    chi_square : array
        Their mean chi-square of ``I_sss`` and ``I_s`` per texel-view and band (NaN where unseen).
    specular_peak_angle : array
        Degrees between the fitted normal and the closest half vector of the
        usable texel-views (:data:`UNSEEN_PEAK_ANGLE_DEG` where unseen).
    albedo_sensitivity : array, optional
        Mean over the usable texel-views of ``(I_sss of a unit subsurface albedo / sigma)^2``
        (1 / albedo^2), ``sigma`` the noise unit of ``chi_square``: a change ``d`` of
        ``rho_sss`` moves the texel's predicted ``I_sss`` by a chi-square of ``d^2`` times
        this (NaN where unseen; :func:`feature_chi_square`).
    """

    counts: np.ndarray
    chi_square: np.ndarray
    specular_peak_angle: np.ndarray
    albedo_sensitivity: np.ndarray | None = None


def texel_statistics(params, cache, patches, config):
    """:class:`TexelStatistics` of the current maps over every patch."""

    T = params.resolution
    counts = np.zeros(T * T, np.float64)
    chi_square = np.zeros(T * T, np.float64)
    sensitivity = np.zeros(T * T, np.float64)
    peak_cosine = np.full(T * T, -1.0, np.float64)
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared) == 0:
            continue
        per_view, weight, _, leaves = texel_view_terms(params, prepared, config, solve_albedo=False)
        texel = prepared.window_index[prepared.texel_numpy]
        usable = np.array(weight)
        np.add.at(counts, texel, usable)
        residual = (np.array(per_view["sss"]) + np.array(per_view["s"])) / len(prepared.observed)
        np.add.at(chi_square, texel, residual)
        np.add.at(sensitivity, texel, usable * unit_albedo_chi_square(params, prepared, config))
        normal = per_view_normals(leaves["dH_du"], leaves["dH_dv"], prepared)
        cosine = np.array(half_vector_cosine(prepared.geometry, normal), np.float64)
        np.maximum.at(peak_cosine, texel, np.where(usable > 0, cosine, -1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, chi_square / counts, np.nan)
        sensitivity = np.where(counts > 0, sensitivity / counts, np.nan)
    angle = np.where(counts > 0, np.degrees(np.arccos(np.clip(peak_cosine, -1.0, 1.0))),
                     UNSEEN_PEAK_ANGLE_DEG)
    return TexelStatistics(counts.reshape(T, T), mean.reshape(T, T), angle.reshape(T, T),
                           sensitivity.reshape(T, T))


def unit_albedo_chi_square(params, prepared, config):
    """Per texel-view ``(I_sss of a unit subsurface albedo / sigma)^2`` (NumPy float64, 1 / albedo^2).

    ``I_sss = 2 I90`` is linear in ``rho_sss``
    (:class:`polarbssrdf.inverse.polarimetric.model.PredictedStokes`), so this is the
    chi-square, in the units of ``L_sss`` (``sigma = photometric_noise`` times the
    patch's mean observed ``I_sss``), by which a change of 1 in the albedo moves a
    texel-view.
    """
    stokes = predicted_patch(params, prepared, config)[0]
    unit = stokes.subsurface
    # I90 = (S0 - S1) / 2 per unit albedo, and I_sss = 2 I90 = S0 - S1
    unit_sss = np.array(dr.detach(unit[0] - unit[1]), np.float64)
    sigma = config.photometric_noise * prepared.image_scale
    return np.square(unit_sss / sigma)


NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))
"""The 8 neighbours a texel's albedo is compared with (:func:`albedo_step`)."""


def albedo_step(rho_sss, measured):
    """Per band and texel, the median over its 8 neighbours of ``|rho_k - rho_i|`` (albedo units).

    How far a texel's subsurface albedo stands from its surroundings: large
    at a sharp local feature (a freckle, a mole), small in smooth skin. The
    median, not the largest difference, so one wild neighbour (a texel fitted
    on light the model lacks) does not make a smooth texel next to it look
    like a feature. A feature can only be told from its surroundings where
    they were measured: a texel with a neighbour that is not ``measured`` (too
    few views: the edge of what the cameras see, where fits are least
    reliable) or off the texture gets step 0.

    Parameters
    ----------
    rho_sss : (n_bands, T, T) array
    measured : (T, T) bool
        Texels whose albedo the fit measured (enough usable views).

    Returns
    -------
    (n_bands, T, T) float64.
    """
    rho = np.asarray(rho_sss, np.float64)
    measured = np.asarray(measured, bool)
    rows, cols = measured.shape
    padded_rho = np.pad(rho, ((0, 0), (1, 1), (1, 1)))
    padded_measured = np.pad(measured, 1, constant_values=False)
    differences = np.stack([
        np.abs(padded_rho[:, 1 + dy:1 + dy + rows, 1 + dx:1 + dx + cols] - rho)
        for dy, dx in NEIGHBOURS])
    surrounded = measured & np.all(
        [padded_measured[1 + dy:1 + dy + rows, 1 + dx:1 + dx + cols] for dy, dx in NEIGHBOURS],
        axis=0)
    return np.where(surrounded, np.median(differences, axis=0), 0.0)


FEATURE_MIXING_VARIANCE = 0.25
"""The largest variance over views of a mixing weight in [0, 1] (:func:`feature_chi_square`)."""


def feature_chi_square(step, sensitivity):
    """The mean chi-square a texel's albedo step can leave in a per-texel fit (``L_sss`` units).

    A camera pixel, and the texel-view read from it, mixes a texel's light
    with its neighbours' by a weight ``w`` in [0, 1] that changes from view to
    view (the pixel's footprint and its position on the surface differ per
    camera). Where the albedo steps by ``d`` from the texel to its neighbours,
    a view's ``I_sss`` is moved by ``w d`` times the unit-albedo image; the
    fitted albedo takes up the mean of ``w``, and the rest, ``(w - mean w) d``,
    is a residual that no per-texel albedo can fit, caused by a real feature,
    not by light the model lacks. Its mean square is at most the largest
    variance of a weight in [0, 1], 1/4 (:data:`FEATURE_MIXING_VARIANCE`),
    times ``d^2`` times the texel's :attr:`TexelStatistics.albedo_sensitivity`;
    averaged over bands like ``chi_square``.

    Parameters
    ----------
    step : (n_bands, T, T) array
        :func:`albedo_step`.
    sensitivity : (T, T) array
        :attr:`TexelStatistics.albedo_sensitivity` (NaN where unseen: 0 is returned).
    """
    explained = (FEATURE_MIXING_VARIANCE * np.mean(np.square(np.asarray(step, np.float64)), axis=0)
                 * np.asarray(sensitivity, np.float64))
    return np.where(np.isfinite(explained), explained, 0.0)


def texel_confidence(counts, chi_square, valid, config, explained=None):
    """``min(1, n / 8)``; 0 below ``min_views``, off the mesh, and where the model does not fit.

    A texel whose texel-views' mean chi-square exceeds ``residual_limit`` times
    the median over texels, plus the part its own albedo feature explains
    (``explained``, :func:`feature_chi_square`; none when not given), is light
    the per-texel model cannot explain (glossy interreflection in concave
    regions, a shadow edge, a wrong geometry): its values are replaced by its
    neighbours'. A freckle leaves a high residual too, but one that its step
    from the neighbours' albedo accounts for, so it keeps its values.
    """
    confidence = np.where(counts >= config.min_views,
                          np.minimum(1.0, counts / FULL_CONFIDENCE_VIEWS), 0.0)
    seen = (counts > 0) & np.isfinite(chi_square)
    if config.residual_limit > 0 and seen.any():
        limit = config.residual_limit * max(float(np.median(chi_square[seen])), 1e-12)
        if explained is not None:
            limit = limit + np.asarray(explained, np.float64)
        confidence = np.where(seen & (chi_square > limit), 0.0, confidence)
    return np.where(valid, confidence, 0.0)


def screening_confidence(statistics, rho_sss, valid, config):
    """:func:`texel_confidence` of a fit, its albedo features (:func:`albedo_step`) explained."""
    explained = None
    if statistics.albedo_sensitivity is not None:
        measured = (valid & (statistics.counts >= config.min_views)
                    & np.isfinite(statistics.chi_square))
        explained = feature_chi_square(albedo_step(rho_sss, measured),
                                       statistics.albedo_sensitivity)
    return texel_confidence(statistics.counts, statistics.chi_square, valid, config, explained)


def confidence_summary(confidence, valid) -> dict:
    """``confident_fraction`` (of the texels on the mesh), ``confident_texels``,
    ``surface_texels`` of a confidence map."""
    surface = int(np.count_nonzero(valid))
    confident = int(np.count_nonzero((confidence > 0) & valid))
    return {"confident_fraction": round(confident / surface, 4) if surface else 0.0,
            "confident_texels": confident, "surface_texels": surface}


def check_some_confident(summary, statistics, valid, config) -> None:
    """Raise :class:`NoConfidentTexelError`, with the reason, when no texel is confident."""
    if summary["confident_texels"]:
        return
    counts = statistics.counts[valid] if np.any(valid) else np.zeros(1)
    enough = int(np.count_nonzero(counts >= config.min_views))
    if enough == 0:
        why = (f"no texel has the {config.min_views} usable texel-views min_views asks for (at "
               f"most {int(counts.max())}): too few cameras see each texel with its light, or "
               "min_cosine is too high")
    else:
        why = (f"the {enough} texels with {config.min_views} or more usable texel-views all "
               f"leave residuals above residual_limit = {config.residual_limit:g} times the "
               "median texel's, beyond what their albedo's step from their neighbours explains")
    raise NoConfidentTexelError(f"no texel of the surface is confident ({why}): every map "
                                "value would be a guess")


def fill_from_confident(values, confident, sigma=2.0):
    """Replace non-confident texels by the Gaussian-weighted mean of confident ones (growing)."""

    return fill_from_neighbours(values, confident, sigma).astype(np.float32)


def final_maps(params, atlas, confidence, band_names, specular_peak_angle=None, std=None):
    """The result channels: maps filled where confidence is 0, normals, confidence and
    (when given) the specular peak angle and the posterior std channels ``<map>_std``.

    A filled texel's std is its confident neighbours' combined with the map's spread over
    the confident texels (the fill guesses a value the views did not measure).
    """

    confident = (confidence > 0) & atlas.valid
    maps = params.to_numpy()
    channels = {}
    for name in OPTIMIZED:
        channels[name] = fill_from_confident(maps[name], confident)
    for band, name in enumerate(band_names):
        channels[f"rho_sss.{name}"] = fill_from_confident(params.rho_sss[band], confident)
    for name, values in (std or {}).items():
        measured = confident & np.isfinite(values)
        if not measured.any():
            continue
        spread = float(np.std(channels[name[:-len("_std")]][confident]))
        filled = fill_from_confident(np.where(measured, values, 0.0), measured)
        channels[name] = np.where(measured, filled, np.hypot(filled, spread)).astype(np.float32)
    normal = normals_from_height(channels["displacement"] * atlas.valid, atlas)
    for axis, component in zip("xyz", np.moveaxis(normal, -1, 0)):
        channels[f"normal.{axis}"] = component.astype(np.float32)
    channels["confidence"] = confidence.astype(np.float32)
    if specular_peak_angle is not None:
        channels["specular_peak_angle"] = np.where(atlas.valid, specular_peak_angle,
                                                   UNSEEN_PEAK_ANGLE_DEG).astype(np.float32)
    return channels


def set_relief_at_prior_level(params, valid):
    """Shift each chart's displacement to the magnitude prior's level, mean 0
    (:mod:`~polarbssrdf.inverse.polarimetric.relief_level`): no view sees the level, and
    the edge's tie to the base mesh and the optimizer's path leave it off the truth's."""
    maps = params.to_numpy()
    maps["displacement"] = relief_at_prior_level(maps["displacement"], valid).astype(np.float32)
    variables = params.variables_of(maps)
    params.optimizer["displacement"] = to_jit(params.TensorXf, variables["displacement"],
                                              np.float32)


def blur_in_texels(blur_mm, atlas):
    """``(s_u, s_v)``: the variance (texels^2) along ``u`` and ``v`` of a blur of std
    ``blur_mm`` at the atlas's median texel size; ``None`` for ``None``."""
    if blur_mm is None:
        return None
    texel_mm = np.median(np.asarray(atlas.texel_size_mm, np.float64)[atlas.valid], axis=0)
    return tuple(float(blur_mm) ** 2 / np.maximum(texel_mm, 1e-12) ** 2)


def run_polarimetric_fit(store, atlas, config, *, start=None, checkpoint=None, progress=True,
                         weights=None, optimized=OPTIMIZED, description="fit", params=None):
    """Optimize maps on a store and return :class:`StageResult` (maps in the result format)."""
    maps, rho_sss = initial_parameters(config, atlas.resolution, len(store.bands), start)
    if start is not None:
        for band, name in enumerate(store.bands):
            if f"rho_sss.{name}" in start:
                rho_sss[band] = np.asarray(start[f"rho_sss.{name}"], np.float32)
    external_start = params is not None
    if params is None:
        params = MapParameters(maps, rho_sss, config.learning_rates, optimized, config.optimizer,
                               config.initial["eta"] if config.glossy_amplitudes else None)
    # a run from the config's constants may start at the face's levels
    # (face_level_evaluations); a run handed its start maps (the dynamic frames: the static
    # maps) starts there
    face_levels = () if external_start else tuple(
        name for name in GLOSSY_PARAMETERS if name in optimized and name not in (start or {}))
    history, cache, face_start = optimize_maps(store, atlas, config, params, checkpoint, progress,
                                               weights, description, face_levels)
    if "displacement" in params.optimized:
        set_relief_at_prior_level(params, atlas.valid)
    patches = texture_patches(atlas.resolution, config.patch_size, store.block_size)
    statistics = texel_statistics(params, cache, patches, config)
    confidence = screening_confidence(statistics, params.rho_sss, atlas.valid, config)
    summary = confidence_summary(confidence, atlas.valid)
    check_some_confident(summary, statistics, atlas.valid, config)
    weights, noise = active_weights(config, weights), epoch_noise(config, history)
    std = map_posterior_std(params, cache, patches, config, weights, noise, store.bands,
                            blur_in_texels(config.capture_blur_mm, atlas))
    if "displacement_std" in std:
        level = chart_level_variance(params.to_numpy()["displacement"], atlas.valid)
        std["displacement_std"] = np.sqrt(np.square(std["displacement_std"].astype(np.float64))
                                          + level).astype(np.float32)
    maps = final_maps(params, atlas, confidence, store.bands, statistics.specular_peak_angle, std)
    confident = (confidence > 0) & atlas.valid
    held = unresolved_maps(maps, confident,
                           [name for name in params.optimized if name in FALLBACK_MAPS])
    if held:
        hold_at_face_level(params, held)
        maps = final_maps(params, atlas, confidence, store.bands, statistics.specular_peak_angle,
                          std)
        held_std_channels(maps, held)
    return StageResult(maps, history, confidence=summary, held=held, face_levels=face_start)
