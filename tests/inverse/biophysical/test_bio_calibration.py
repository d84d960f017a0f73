"""The biophysical fit on faces it was not made from, with their face values known: issue 31's
figures, map by map.

The six faces of :mod:`polarbssrdf.synth.unseen_faces` (issue 31 item 4): a truth seed per
face, the bases one across-rows spread off Table 2, the within-face spreads at 0.5x synth's
default on the foreheads and 2x on the cheeks, the cheeks with a second field family
(3 mm fields, sharp-edged freckles and blood patches), the thickness and oxygenation
varying within the face by 0.01 mm and 0.02, the input index off the truth's by a smooth
error of 0.013 (``eta_std`` given), 1% white noise on the band integral, 128^2 texels.
The fit is told the face values (thickness 0.25 mm, oxygenation 0.75, held) and nothing
else. With the face values unknown no face meets the figures either
(``bench/bio_off_prior.py``, bench/RESULTS.md).

Thresholds are issue 31's: MAE at most 0.5 of the constant map's for C_m, C_h_out and
C_h_in, at most the constant map's for beta_m; 2-std coverage in [0.90, 0.98]. Where a face
misses one (measured on the date its list gives), the case is a strict expected failure that
names the measured figure, so a change that reaches it shows as an unexpected pass. What
limits them is in docs/biophysical.md: the oxygenation and thickness within the face and
the index error, which six bands cannot tell from the chromophores, and beta_m's spread,
which the bands hardly see, so that its coverage is the ratio of the truth's spread to the
prior's.
"""

import numpy as np
import pytest

import mitsuba as mi

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
LIMITS = {"C_m": 0.5, "beta_m": 1.0, "C_h_out": 0.5, "C_h_in": 0.5}
COVERAGE = (0.90, 0.98)
FACES = range(6)

MISSED_MAE = {
    (0, "C_m"): 0.89, (0, "beta_m"): 4.15, (0, "C_h_out"): 0.59, (0, "C_h_in"): 3.78,
    (1, "beta_m"): 1.025, (1, "C_h_in"): 0.63,
    (2, "C_m"): 0.98, (2, "beta_m"): 2.32, (2, "C_h_out"): 0.51, (2, "C_h_in"): 3.71,
    (3, "beta_m"): 1.43, (3, "C_h_in"): 1.00,
    (4, "C_m"): 1.06, (4, "beta_m"): 2.30, (4, "C_h_out"): 0.69, (4, "C_h_in"): 4.67,
    (5, "C_h_in"): 0.94,
}
"""MAE / constant map's MAE where it is over the figure (2026-12-04, unless
:data:`MAE_MEASURED_ON` says otherwise)."""

MAE_MEASURED_ON = {(1, "beta_m"): "2026-12-06", (1, "C_h_in"): "2026-12-07",
                   (3, "beta_m"): "2026-12-07", (3, "C_h_in"): "2026-12-07", (5, "C_h_in"): "2026-12-07"}
"""MAE misses measured later than 2026-12-04: on the cheeks the local-feature prior
(:func:`~polarbssrdf.inverse.biophysical.prior.feature_coupling`) frees every map at the
freckles and the blood patches' edges (bench/RESULTS.md, 2026-12-06). The cheeks' figures
that moved with it were measured again on 2026-12-07 (0.59, 1.35, 0.92 and 0.81 on
2026-12-04)."""

MISSED_COVERAGE = {
    (0, "beta_m"): 0.834,
    (1, "beta_m"): 0.740,
    (2, "beta_m"): 0.992, (2, "C_h_out"): 0.981, (2, "C_h_in"): 0.998,
    (3, "beta_m"): 0.566, (3, "C_h_in"): 0.863,
    (4, "C_h_in"): 0.987,
    (5, "beta_m"): 0.745,
}
"""2-std coverage where it is outside [0.90, 0.98] (2026-12-07). Since the fit's within-face
thickness spread is the measured 0.018 mm (:data:`~polarbssrdf.skin.nuisances.DEFAULT_NUISANCE_STD`,
0.01 mm before), these faces, which vary by 0.01 mm, get a std wider than their error where
the thickness moves a map: face 0's and face 5's C_h_in reach the figure (0.886 and 0.891
before), face 2's C_h_out and face 4's C_h_in, inside the window before, cover a little more than
0.98 of their errors (bench/RESULTS.md, 2026-12-07)."""

COVERAGE_MEASURED_ON = "2026-12-07"


def _cases(missed, what, measured_on=None, default="2026-12-04"):
    cases = []
    for face in FACES:
        for name in PARAMETERS:
            marks = ()
            if (face, name) in missed:
                measured = (measured_on or {}).get((face, name), default)
                marks = pytest.mark.xfail(strict=True, reason=f"{what} {missed[face, name]} ({measured})")
            cases.append(pytest.param(face, name, marks=marks, id=f"face{face}-{name}"))
    return cases


def _known_face_values():
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig

    # the face values told, the spreads within the face left to the std (the defaults)
    return BiophysicalConfig(oxygenation="held", thickness_mm=0.25, gamma=0.75,
                             nuisance_mean={"thickness_mm": [0.25, 0.0], "gamma": [0.75, 0.0]})


_FITS = {}


def fitted(face):
    """``(result, scores)`` of face ``face`` (fitted once, shared by the tests)."""
    from polarbssrdf.inverse.biophysical.fit import fit_biophysical
    from polarbssrdf.inverse.evaluation.scores import biophysical_scores
    from polarbssrdf.synth.unseen_faces import unseen_face

    if face not in _FITS:
        mi.set_variant("llvm_ad_mono_polarized")
        atlas, truth, bands, inputs = unseen_face(face, 128, 0.01, thickness_mm=0.25, gamma=0.75)
        result = fit_biophysical(inputs, bands, atlas, _known_face_values())
        scores, _ = biophysical_scores(result.channels(), truth, atlas.valid)
        for name in PARAMETERS:
            score = scores[name]
            print(face, name, f"MAE {score['mae_of_range'] / score['constant_mae_of_range']:.3f} of the "
                  f"constant map's, within 2 std {score['coverage']:.3f}")
        _FITS[face] = result, scores
    return _FITS[face]


@pytest.mark.parametrize("face,name", _cases(MISSED_MAE, "MAE / constant map's", MAE_MEASURED_ON))
def test_unseen_faces_beat_the_constant_map(face, name):
    _, scores = fitted(face)
    score = scores[name]
    assert score["mae_of_range"] <= LIMITS[name] * score["constant_mae_of_range"]


@pytest.mark.parametrize("face,name", _cases(MISSED_COVERAGE, "2-std coverage", default=COVERAGE_MEASURED_ON))
def test_unseen_faces_have_calibrated_std(face, name):
    _, scores = fitted(face)
    low, high = COVERAGE
    assert low <= scores[name]["coverage"] <= high


MISSED_NOISE = {1: "0.0077-0.0125", 3: "0.0075-0.0126", 5: "0.0081-0.0125"}
"""The bands' noise the fit estimated where one is more than 0.002 off the 1% given (2026-12-04):
on the cheeks (2x spreads, freckles) the reddest band's is low and the others' high."""


NOISE_CASES = [pytest.param(face, marks=pytest.mark.xfail(strict=True, reason=f"noise estimates "
                                                          f"{MISSED_NOISE[face]} (2026-12-04)"))
               if face in MISSED_NOISE else face for face in FACES]


@pytest.mark.parametrize("face", NOISE_CASES)
def test_the_noise_the_fit_estimates_is_the_one_it_was_given(face):
    """Each band's relative noise within 0.002 of the 1% the albedo was given."""
    result, _ = fitted(face)
    sigma = np.array(list(result.noise["relative_sigma"].values()))
    assert np.all(np.abs(sigma - 0.01) < 0.002), sigma
