"""The chromophores' face means (inverse/biophysical/start.py) when the face's own skin is not the
model's: their std carries the face thickness and oxygenation the fit holds.

A face of its own seed whose epidermis is 0.03 mm thicker than the 0.25 mm the fit holds
(within the 0.05 mm the thickness hyperprior allows), its oxygenation known, its band-integrated
albedo noise-free, the index the truth's. Held at 0.25 mm, the blocks' inversion moves the face
means (on this face dermal blood's by more than the range of its linearization), and the spread
of the blocks alone does not say so.
"""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.spectral import default_bands

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
HELD_MM = 0.25
TRUE_MM = 0.28


@pytest.fixture(scope="module")
def thicker_face():
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.render.subsurface import subsurface_exit_fraction
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import table2_offset_settings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), 64)
    layers = {"thickness_mm": (TRUE_MM, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}
    settings = table2_offset_settings(("forehead", "II"), 1.0, spread="rows", skin_layers=layers)
    truth = truth_maps(atlas, settings, np.random.default_rng(4107))
    bands = default_bands()
    rbar = subsurface_albedo(truth, bands).astype(np.float64) * subsurface_exit_fraction(truth["eta"])[None]
    return atlas, bands, rbar, truth


def test_the_face_means_std_carries_the_held_thickness(thicker_face):
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
    from polarbssrdf.inverse.biophysical.start import block_face_means, face_mean_skin_shifts

    atlas, bands, rbar, truth = thicker_face
    config = BiophysicalConfig()
    valid = np.asarray(atlas.valid, bool)
    thickness_std = config.nuisance_mean["thickness_mm"][1]
    means = block_face_means(rbar, valid, atlas, bands, truth["eta"], config, HELD_MM, 0.75)
    shifts = face_mean_skin_shifts(rbar, valid, atlas, bands, truth["eta"], config, HELD_MM, 0.75,
                                   {"thickness_mm": thickness_std})
    errors = {n: means[n][0] - float(np.mean(truth[n][valid])) for n in PARAMETERS}
    # the face discriminates: the blocks' own spread misses what the held thickness moved
    assert any(abs(errors[n]) > 2.0 * means[n][1] for n in PARAMETERS), (errors, means)
    for name in PARAMETERS:
        assert abs(errors[name]) <= 2.0 * np.hypot(means[name][1], shifts[name]), (name, errors, means, shifts)


def test_a_known_face_value_adds_nothing(thicker_face):
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
    from polarbssrdf.inverse.biophysical.start import face_mean_skin_shifts

    atlas, bands, rbar, truth = thicker_face
    shifts = face_mean_skin_shifts(rbar, atlas.valid, atlas, bands, truth["eta"], BiophysicalConfig(), HELD_MM,
                                   0.75, {"thickness_mm": 0.0, "gamma": 0.0})
    assert shifts == {name: 0.0 for name in PARAMETERS}
