"""Issue 31's test faces: biophysical inputs drawn unlike the fit's prior, for the tests and benches.

Three Table 2 skin rows x two regions (:data:`UNSEEN_ROWS`, face ``index`` 0-5). Each face has
its own truth seed (:data:`SEED_BASE` + index), and its chromophores' bases sit one
across-rows spread off Table 2 (:func:`~polarbssrdf.synth.truth.table2_offset_settings`).
The within-face spreads are 0.5x synth's default on even faces and 2x on odd ones (2x capped
at 0.45 of the base, where a field would be clipped at 0). The odd faces also use a second
field family: a 3 mm correlation plus sharp-edged freckles on ``C_m`` and blood patches on
``C_h_in`` (:data:`FEATURES`). The epidermal thickness and oxygenation have face values of
the caller's choosing with 0.01 mm and 0.02 within the face. The input index is the truth's
plus a smooth error of the static stage's typical size, with ``eta_std`` at that size. The
albedo is the band integral of the truth (synth's) with relative white noise.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
from polarbssrdf.skin.parameters import TABLE2, table2_spread_across_rows
from polarbssrdf.spectral import default_bands
from polarbssrdf.synth.synthesize import subsurface_albedo
from polarbssrdf.synth.truth import DEFAULT_BIOPHYSICAL_STD, smooth_field, table2_offset_settings, truth_maps

UNSEEN_ROWS = [(region, skin) for skin in ("II", "III", "IV") for region in ("forehead", "cheek")]
"""The Table 2 row of each face index."""

FEATURES = [{"map": "C_m", "factor": 1.8, "diameter_mm": 3.0, "edge_mm": 0.3, "count": 25},
            {"map": "C_h_in", "factor": 1.6, "diameter_mm": 12.0, "edge_mm": 1.0, "count": 4}]
"""The odd faces' localized features: freckles (melanin x1.8, 3 mm) and blood patches."""

SEED_BASE = 3100
"""Face ``index`` draws its truth, noise and index error from ``default_rng(SEED_BASE + index)``."""

WITHIN_FACE = {"thickness_mm": 0.01, "gamma": 0.02}
"""Spread of the thickness (mm) and oxygenation within each face: the thickness's below the fit's
default ``nuisance_std`` (0.018 mm, the measured spread between facial sites), the
oxygenation's at it."""

INDEX_ERROR = 0.013
"""The input index's error: the static stage's typical MAE on the demo."""

INDEX_ERROR_LENGTH_MM = 5.0
"""Correlation length (mm) of the input index's error."""


def unseen_face(index, size=128, noise=0.01, thickness_mm=0.28, gamma=0.71, eta_error=INDEX_ERROR,
                within_face=None, bands=None):
    """``(atlas, truth, bands, inputs)`` of face ``index`` (module docstring).

    Parameters
    ----------
    index : int
        0-5, the row :data:`UNSEEN_ROWS` ``[index]``.
    size : int
        Texels per side of the face mesh's atlas.
    noise : float
        Relative white noise on the albedo.
    thickness_mm, gamma : float
        The face's epidermal thickness (mm) and blood oxygenation; each varies within the
        face by :data:`WITHIN_FACE`.
    eta_error : float
        Spread of the smooth error added to the truth's index in ``inputs["eta"]`` (0: the
        truth's index and no ``eta_std``).
    within_face : dict, optional
        ``{"thickness_mm": mm, "gamma": fraction}``: their spread within the face (default
        :data:`WITHIN_FACE`; 0 makes them constant over the face).
    bands : list of Band, optional
        The bands the albedo is integrated over (default: the shipped six).

    ``inputs`` holds ``rho_sss.<band>`` per band, ``eta`` and, with an index error,
    ``eta_std``: what :func:`~polarbssrdf.inverse.biophysical.fit.fit_biophysical` reads.
    """

    if not 0 <= int(index) < len(UNSEEN_ROWS):
        raise ValueError(f"face index must be 0-{len(UNSEEN_ROWS) - 1}, got {index}")
    row_key = UNSEEN_ROWS[index]
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), size)
    scale = 0.5 if index % 2 == 0 else 2.0
    fields = {"correlation_mm": 3.0, "features": FEATURES} if index % 2 else {}
    fields.update(wrinkles=[], pores=None)  # albedo only: the relief would only move the noise draws
    within = {**WITHIN_FACE, **(within_face or {})}
    layers = {"thickness_mm": (thickness_mm, within["thickness_mm"], 0.10, 0.40),
              "gamma": (gamma, within["gamma"], 0.50, 0.95)}
    row = TABLE2[row_key]
    across = table2_spread_across_rows()
    # 2x where the base allows it (a field is refused within two of its std of 0)
    std = {k: min(v * scale, 0.45 * (getattr(row, k) + across[k]))
           for k, v in DEFAULT_BIOPHYSICAL_STD.items()}
    settings = table2_offset_settings(row_key, 1.0, spread="rows", skin_layers=layers,
                                      biophysical_std=std, **fields)
    rng = np.random.default_rng(SEED_BASE + index)
    truth = truth_maps(atlas, settings, rng)
    bands = default_bands() if bands is None else list(bands)
    albedo = subsurface_albedo(truth, bands)
    noisy = albedo * (1.0 + noise * rng.standard_normal(albedo.shape))
    inputs = {f"rho_sss.{b.name}": noisy[i] for i, b in enumerate(bands)}
    T = atlas.valid.shape[0]
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    inputs["eta"] = truth["eta"] + eta_error * smooth_field((T, T), INDEX_ERROR_LENGTH_MM / texel, rng)
    if eta_error > 0:
        inputs["eta_std"] = np.full((T, T), eta_error)
    return atlas, truth, bands, inputs


def texel_blurred_albedo(atlas, inputs, bands, blur_texels, noise, seed):
    """``inputs`` with each band's albedo blurred as a capture blurs it, then noisy: a Gaussian of
    ``blur_texels`` (sigma, in texel units: SciPy's, not the fit's blur, which works in mm over
    the atlas's texel sizes) normalized over the surface, times ``1 + noise N(0, 1)`` (seed
    ``seed``); NaN off the surface. The albedo a fit told a capture blur is tested on
    (tests/inverse/biophysical/test_freckles.py, bench/freckle_blur.py)."""
    weight = gaussian_filter(atlas.valid.astype(np.float64), blur_texels)
    rng = np.random.default_rng(seed)
    blurred = dict(inputs)
    for band in bands:
        key = f"rho_sss.{band.name}"
        clean = np.where(atlas.valid, np.asarray(inputs[key], np.float64), 0.0)
        seen = gaussian_filter(clean, blur_texels) / np.maximum(weight, 1e-9)
        noisy = seen * (1.0 + noise * rng.standard_normal(seen.shape))
        blurred[key] = np.where(atlas.valid, noisy, np.nan).astype(np.float32)
    return blurred


__all__ = ["UNSEEN_ROWS", "FEATURES", "SEED_BASE", "WITHIN_FACE", "INDEX_ERROR", "unseen_face", "texel_blurred_albedo"]
