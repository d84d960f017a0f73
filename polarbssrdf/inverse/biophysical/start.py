"""The biophysical fit's input and start (supplement sec. 5.3, eq. 47): checked albedo maps and a
per-texel inversion on block means.

* :func:`albedo_stack`: the ``rho_sss.<band>`` maps of a result or truth file, with errors that
  name the missing or misshapen channel;
* :func:`start_maps`: step (a) of the fit, the fast per-texel inversion
  (:func:`polarbssrdf.skin.invert_bands`) of albedo averaged over blocks of about
  ``start_texel_mm`` (where the blur is negligible), upsampled bilinearly.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import zoom

from polarbssrdf.inverse.biophysical.model import PARAMETERS
from polarbssrdf.inverse.results.fill import fill_from_neighbours as fill
from polarbssrdf.skin.inversion import invert_bands

START_ETA_STEP = 0.02
"""Texels of the start's inversion share one eta per bin of this width."""


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


def block_mean(values, weight, factor):
    """Weighted means over factor x factor blocks (edge padded) and which blocks have weight."""
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


def block_inversion(rbar, valid, atlas, bands, eta, config, block_mm, thickness_mm=None, gamma=None,
                    table_size="default"):
    """The per-texel inversion of eq. 47 on means over blocks of about ``block_mm``, at
    ``thickness_mm`` and ``gamma`` (default the config's); ``table_size`` that of the
    inversion's start table (:func:`~polarbssrdf.skin.inversion.invert_bands`).

    Returns ``(maps, ok, factor)``: per block the four parameters and the relative residual
    of every band (``"residual"``, (n_bands, ...); NaN where the block has no valid texel),
    which blocks have one, and the block size in texels."""

    T = valid.shape[0]
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    factor = max(1, int(round(block_mm / max(texel, 1e-9)))) if block_mm > 0 else 1
    factor = min(factor, T)
    means, ok = block_mean(rbar, valid, factor)
    eta_means, _ = block_mean(eta, valid, factor)
    # invert_bands takes one eta: invert blocks in bins of START_ETA_STEP
    bins = np.round(eta_means / START_ETA_STEP) * START_ETA_STEP
    coarse_maps = {name: np.full(ok.shape, np.nan) for name in PARAMETERS}
    coarse_maps["residual"] = np.full(means.shape, np.nan)
    for value in np.unique(bins[ok]):
        members = ok & (bins == value)
        result = invert_bands(np.moveaxis(means[:, members], 0, -1), bands,
                              thickness_mm=config.thickness_mm if thickness_mm is None else thickness_mm,
                              eta=float(value), table_size=table_size, method=config.spectral,
                              gamma=config.gamma if gamma is None else gamma)
        for name in PARAMETERS:
            coarse_maps[name][members] = getattr(result, name)
        observed = np.moveaxis(means[:, members], 0, -1)
        coarse_maps["residual"][:, members] = np.moveaxis((result.predicted - observed) / np.maximum(observed, 1e-4),
                                                          -1, 0)
    return coarse_maps, ok, factor


def start_maps(rbar, valid, atlas, bands, eta, config, thickness_mm=None, gamma=None):
    """The per-texel inversion of eq. 47 on block means (of ``start_texel_mm``), upsampled;
    (T, T) maps and the block size in texels."""

    T = valid.shape[0]
    coarse_maps, ok, factor = block_inversion(rbar, valid, atlas, bands, eta, config, config.start_texel_mm,
                                              thickness_mm, gamma)
    out = {}
    for name in PARAMETERS:
        coarse = fill_from_neighbours(coarse_maps[name], ok, np.ones_like(ok))
        # block centres -> texel centres
        fine = zoom(coarse, factor, order=1, mode="nearest", grid_mode=True)[:T, :T] if factor > 1 else coarse
        low, high = config.bounds[name]
        out[name] = np.clip(fine, low, high)
    return out, factor



FACE_MEAN_BLOCK_MM = 16.0
"""Block size (mm) of :func:`block_face_means`."""

MINIMUM_BLOCK_FILL = 0.5
"""A block enters the face means if at least this fraction of its texels has valid input."""


def block_face_means(rbar, valid, atlas, bands, eta, config, thickness_mm=None, gamma=None,
                     table_size="default"):
    """``name -> (mean, std of the mean)`` of each chromophore from blocks of
    :data:`FACE_MEAN_BLOCK_MM`, at ``thickness_mm`` and ``gamma`` (default the config's);
    ``table_size`` that of the inversion's start table (:func:`block_inversion`).

    Each block's albedo is averaged before it is inverted, so the per-texel noise is
    averaged out before the model's curvature can turn it into bias (without these means
    as the face means' hyperprior, 1% noise moved beta_m's face mean by +0.07 on a
    forehead II face, 6x the constant map's error); the face mean is the texel-weighted
    mean of the blocks' values, its std their weighted spread over the square root of
    the number of blocks."""

    maps, ok, factor = block_inversion(rbar, valid, atlas, bands, eta, config, FACE_MEAN_BLOCK_MM, thickness_mm,
                                       gamma, table_size=table_size)
    texels = block_mean(valid.astype(np.float64), np.ones_like(valid, dtype=np.float64), factor)[0] * factor ** 2
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


SHIFT_TABLE = "small"
"""Start table of :func:`face_mean_skin_shifts`' inversions: its build dominates one (1.1-1.4 s
with the default table, a third of it with this one)."""


def face_mean_skin_shifts(rbar, valid, atlas, bands, eta, config, thickness_mm, gamma, face_std):
    """``name -> std`` that the face's own thickness and oxygenation, known only to ``face_std``
    (``{"thickness_mm": mm, "gamma": fraction}``; 0 or absent: known), add to each
    chromophore's block face mean (:func:`block_face_means`): the larger change of the means
    with the skin value one std below or above the held one (sigma points, not a derivative,
    and the larger side, not their mean: the response is far from linear and one-sided where
    a map meets its bound; on a forehead II face 0.03 mm thicker than held, C_h_in's face mean
    moved by 0.028 where half the change between -1 and +1 std said 0.010), the two skin
    values in quadrature.

    The chromophores' face means hold the maps' level, so without this the std of a map
    the bands tell only together with the thickness missed that shift (beta_m 2-std
    coverage 0.62 on a face 0.03 mm thicker than held, bench/RESULTS.md)."""
    total = {name: 0.0 for name in PARAMETERS}
    unknown = {nuisance: std for nuisance, std in face_std.items() if std > 0}
    if not unknown:
        return total
    centre = block_face_means(rbar, valid, atlas, bands, eta, config, thickness_mm, gamma, table_size=SHIFT_TABLE)
    for nuisance, std in unknown.items():
        sides = []
        for sign in (-1.0, 1.0):
            point = {"thickness_mm": thickness_mm, "gamma": gamma}
            point[nuisance] = point[nuisance] + sign * std
            sides.append(block_face_means(rbar, valid, atlas, bands, eta, config, **point, table_size=SHIFT_TABLE))
        for name in PARAMETERS:
            total[name] += max(abs(side[name][0] - centre[name][0]) for side in sides) ** 2
    return {name: float(np.sqrt(value)) for name, value in total.items()}
