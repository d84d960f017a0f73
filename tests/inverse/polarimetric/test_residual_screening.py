"""Residual screening (``residual_limit``) tells a freckle from light the model cannot explain.

Issue 32, item 3: on a freckled cheek the screening gave 92% of the freckle
texels confidence 0, so their albedo (and melanin) was replaced by the
surrounding skin's. A camera pixel mixes a small feature's light with its
surroundings' by weights that change from view to view, so a freckle leaves
a residual no per-texel albedo fits; it also stands out from its neighbours
in the albedo, which light the model lacks (a shadow edge, interreflection
in one view) in smooth skin does not. The issue's figure: at least 90% of the
freckle texels stay confident, while such outliers are still screened.
"""

import numpy as np
import pytest
from synthetic_texel_views import InMemoryStore, sphere_views

T = 32
BANDS = ("b0", "b1", "b2")
FRECKLE_FACTOR = 0.5
"""Albedo inside a freckle relative to the skin around it (a melanin spot halves it in these bands)."""


def _freckled_sphere(seed=5):
    """A sphere whose texel-views mix each freckle texel's light with the skin around it, plus
    single texel-views brightened (interreflection) or darkened (a shadow edge) in smooth skin.

    Returns ``(atlas, store, freckle, outliers)``: (T, T) masks of the freckle texels and
    of the texels given one unexplained view.
    """
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import texel_atlas, to_mitsuba, uv_sphere

    rng = np.random.default_rng(seed)
    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=48, segments=96)), T)
    truth = {"eta": 1.45, "alpha_s": 0.4, "rho_s": 0.8, "rho_ss": 0.3, "alpha_ss": 0.97}
    truth = {k: np.full((T, T), v, np.float32) for k, v in truth.items()}
    truth["normal"] = atlas.normal
    rows, cols = np.mgrid[0:T, 0:T]
    skin = np.stack([0.35 + 0.03 * np.sin(2 * np.pi * cols / T + b) for b in range(3)])
    skin = skin.astype(np.float32)
    # 2 x 2 texel freckles on the camera ring's band of the sphere (rows near the equator)
    freckle = np.zeros((T, T), bool)
    for row, col in ((13, 3), (16, 10), (13, 17), (17, 24), (14, 29)):
        freckle[row:row + 2, col:col + 2] = True
    freckle &= atlas.valid
    freckled = np.where(freckle, FRECKLE_FACTOR * skin, skin).astype(np.float32)
    views = sphere_views(atlas, truth, freckled, n_cameras=12)
    around = sphere_views(atlas, truth, skin, n_cameras=12)
    # each texel-view of a freckle mixes in the surrounding skin's light by its own weight
    weight = rng.uniform(0.0, 0.6, len(views.texel))[:, None, None]
    in_freckle = freckle.ravel()[views.texel][:, None, None]
    views.analyser = np.where(in_freckle, (1 - weight) * views.analyser + weight * around.analyser,
                              views.analyser).astype(np.float32)
    views.analyser *= (1.0 + 0.01 * rng.standard_normal(views.analyser.shape)).astype(np.float32)
    # one unexplained view each on texels of smooth skin, away from the freckles: 60% more
    # light (interreflection) or 60% less (the texel in a shadow edge in that view)
    outliers = np.zeros((T, T), bool)
    for row, col, gain in ((15, 6, 1.6), (14, 13, 0.4), (16, 20, 1.6), (15, 27, 0.4),
                           (17, 14, 1.6), (12, 22, 0.4)):
        texel_views = np.flatnonzero(views.texel == row * T + col)
        # the view that sees the texel most head-on: one the fit surely uses
        facing = np.sum(views.to_camera[texel_views] * atlas.normal[row, col], axis=-1)
        views.analyser[texel_views[np.argmax(facing)]] *= gain
        outliers[row, col] = True
    return atlas, InMemoryStore(views, T, BANDS), freckle, outliers


@pytest.fixture(scope="module")
def freckled_fit():
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.polarimetric.fit import run_polarimetric_fit

    atlas, store, freckle, outliers = _freckled_sphere()
    result = run_polarimetric_fit(store, atlas, static_config(iterations=25), progress=False)
    return result.maps, freckle, outliers


def test_freckle_texels_stay_confident(freckled_fit):
    maps, freckle, _ = freckled_fit
    confident = maps["confidence"] > 0
    # the figure: at least 90% of the freckle texels keep their own values
    assert freckle.sum() >= 15
    assert np.mean(confident[freckle]) >= 0.9
    # and those values are the freckle's: darker than the skin around it
    skin = np.median(maps["rho_sss.b0"][~freckle & confident])
    assert np.median(maps["rho_sss.b0"][freckle & confident]) < 0.85 * skin


def test_light_the_model_cannot_explain_is_still_screened(freckled_fit):
    maps, _, outliers = freckled_fit
    assert np.all(maps["confidence"][outliers] == 0)
    # and the screen is not throwing away smooth skin wholesale
    from scipy.ndimage import binary_dilation

    smooth = (maps["confidence"] >= 0) & ~binary_dilation(outliers, iterations=1)
    seen = smooth & (maps["confidence"] > 0)
    assert seen.sum() > 0.5 * smooth.sum()


def test_an_albedo_step_explains_only_what_view_mixing_can_cause():
    """The screening function on a constructed case (no fit): residuals against the limit plus
    the freckle's share."""
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.polarimetric.fit import (
        FEATURE_MIXING_VARIANCE,
        albedo_step,
        feature_chi_square,
        texel_confidence,
    )

    n = 12
    rho = np.full((2, n, n), 0.4)
    rho[:, 5:7, 5:7] = 0.2  # a 2 x 2 freckle
    rho[:, 2, 9] = 0.37  # a texel fitted on a shadow edge: its albedo barely moved
    measured = np.ones((n, n), bool)
    measured[:, 0] = False  # the edge of what the cameras see
    rho[:, 4, 1] = 0.1  # a wild albedo next to it (grazing views)
    step = albedo_step(rho, measured)
    # the freckle texel's median neighbour difference is the full step (5 of 8 neighbours are skin)
    np.testing.assert_allclose(step[:, 5, 5], 0.2)
    assert np.all(step[:, 8, 8] == 0.0)  # smooth skin
    assert np.all(step[:, 4, 2] == 0.0)  # the wild texel is one neighbour of 8: the median holds
    assert np.all(step[:, 4, 1] == 0.0)  # a neighbour unmeasured: no comparison, no excuse
    sensitivity = np.full((n, n), 2500.0)  # (I_sss per unit albedo / sigma)^2
    explained = feature_chi_square(step, sensitivity)
    np.testing.assert_allclose(explained[5, 5], FEATURE_MIXING_VARIANCE * 0.04 * 2500.0)
    assert explained[2, 9] < 1.0

    counts = np.full((n, n), 8.0)
    chi_square = np.ones((n, n))
    chi_square[5:7, 5:7] = 0.6 * explained[5, 5]  # 15 times the median: mixing at the freckle
    chi_square[2, 9] = 15.0  # the shadow edge
    chi_square[4, 1] = 15.0  # the wild texel
    # a freckle texel whose residual is more than its step can cause: light the model lacks
    chi_square[6, 6] = 9.0 + explained[6, 6] + 5.0
    config = static_config()
    before = texel_confidence(counts, chi_square, measured, config)
    assert np.all(before[5:7, 5:7] == 0)  # the residual alone screens the freckle
    confidence = texel_confidence(counts, chi_square, measured, config, explained)
    assert confidence[5, 5] == confidence[5, 6] == confidence[6, 5] == 1.0
    assert confidence[6, 6] == 0 and confidence[2, 9] == 0 and confidence[4, 1] == 0
    assert confidence[8, 8] == 1.0
    # residual_limit 0 still turns the test off
    off = texel_confidence(counts, chi_square, measured, static_config(residual_limit=0), explained)
    assert np.all(off[measured] == 1.0)
