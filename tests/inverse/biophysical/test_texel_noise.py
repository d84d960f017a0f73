"""The biophysical stage weighs each texel by the noise its input std says (issue 33, item 5).

The static stage's albedo std varies over a face with the views that see each texel (2-3x
between the 10th and 90th percentile texel of the demo). A face whose albedo noise is 0.5% on
one half and 2% on the other, the fit told each texel's std: the chromophores' 2-std coverage
is within the issue's [0.90, 0.98] on both halves (not yet: the quiet half is over-covered,
strict expected failure). Told nothing, the fit takes one noise level for the whole face
(about 1.5%); told, it recovers each half's noise and every map's error drops.

The skin's other unknowns are held out of the way (thickness and oxygenation constant and
given, the index exact), so what is measured is the noise model alone.
"""

import numpy as np
import pytest

import mitsuba as mi

SIZE = 96
THICKNESS_MM, GAMMA = 0.28, 0.71
QUIET, NOISY = 0.005, 0.02
"""Relative albedo noise of the face's left and right halves (texture columns)."""


@pytest.fixture(scope="module")
def split_noise_face():
    from polarbssrdf.synth.unseen_faces import unseen_face

    mi.set_variant("llvm_ad_mono_polarized")
    atlas, truth, bands, inputs = unseen_face(2, SIZE, 0.0, THICKNESS_MM, GAMMA, eta_error=0.0,
                                              within_face={"thickness_mm": 0.0, "gamma": 0.0})
    relative = np.where(np.arange(SIZE)[None, :] < SIZE // 2, QUIET, NOISY) * np.ones((SIZE, 1))
    rng = np.random.default_rng(11)  # not a seed any default was tuned on
    noisy = dict(inputs)
    for band in bands:
        key = f"rho_sss.{band.name}"
        clean = np.asarray(inputs[key], np.float64)
        noisy[key] = (clean * (1.0 + relative * rng.standard_normal(clean.shape))).astype(np.float32)
        noisy[f"{key}_std"] = (relative * clean).astype(np.float32)
    return atlas, truth, bands, noisy, relative


def _fit(face, with_std):
    from polarbssrdf.inverse.biophysical.config import bio_config
    from polarbssrdf.inverse.biophysical.fit import fit_biophysical

    atlas, _, bands, inputs, _ = face
    if not with_std:
        inputs = {k: v for k, v in inputs.items() if not k.endswith("_std")}
    config, _ = bio_config({"thickness_mm": THICKNESS_MM, "gamma": GAMMA, "oxygenation": "held",
                            "nuisance_std": {"thickness_mm": 0.0, "gamma": 0.0, "eta": 0.0},
                            "nuisance_mean": {"thickness_mm": [THICKNESS_MM, 0.0], "gamma": [GAMMA, 0.0]}})
    return fit_biophysical(inputs, bands, atlas, config)


def _coverage(face, result, name):
    """2-std coverage of map ``name`` on the quiet and the noisy half."""
    atlas, truth, _, _, relative = face
    inside = np.abs(result.maps[name] - truth[name]) < 2.0 * result.std[name]
    return tuple(float(np.mean(inside[atlas.valid & (relative == level)])) for level in (QUIET, NOISY))


@pytest.fixture(scope="module")
def fits(split_noise_face):
    return {with_std: _fit(split_noise_face, with_std) for with_std in (True, False)}


def test_the_fit_reads_each_texels_noise_from_the_input_std(fits):
    """The bands' noise the fit calibrates on its residuals, times each half's scale from the
    input std, is the noise each half was given; told nothing, one level sits between them."""
    scale = fits[True].noise["texel_noise_scale"]
    assert scale["from"] == "input std"
    level = float(np.mean(list(fits[True].noise["relative_sigma"].values())))
    assert level * scale["q10"] == pytest.approx(QUIET, rel=0.1)
    assert level * scale["q90"] == pytest.approx(NOISY, rel=0.1)
    assert fits[False].noise["texel_noise_scale"]["from"] == "none"
    pooled = float(np.mean(list(fits[False].noise["relative_sigma"].values())))
    assert 2 * QUIET < pooled < 0.9 * NOISY


@pytest.mark.parametrize("name", ["C_m", "beta_m", "C_h_out", "C_h_in"])
def test_weighing_each_texel_by_its_noise_lowers_every_maps_error(split_noise_face, fits, name):
    """Weighted least squares is the more efficient estimate when the noise differs per texel:
    the face's RMS error of every map is lower with the input std than without."""
    atlas, truth, _, _, _ = split_noise_face
    rms = {with_std: float(np.sqrt(np.mean((fit.maps[name] - truth[name])[atlas.valid] ** 2)))
           for with_std, fit in fits.items()}
    assert rms[True] < rms[False], (name, rms)


@pytest.mark.xfail(strict=True, reason="quiet half over-covered: C_m 0.986, C_h_out 0.994 (noisy "
                   "half 0.944 / 0.980) on 2026-12-05; this face over-covers with uniform noise too "
                   "(C_m 0.974 / 0.979, C_h_out 0.990 / 0.994 at 0.5% / 2%)")
@pytest.mark.parametrize("name", ["C_m", "C_h_out"])
def test_coverage_is_right_on_both_halves_with_the_texels_noise(split_noise_face, fits, name):
    quiet, noisy = _coverage(split_noise_face, fits[True], name)
    assert 0.90 <= quiet <= 0.98, (name, quiet)
    assert 0.90 <= noisy <= 0.98, (name, noisy)
