"""Issue 31's test faces (:mod:`polarbssrdf.synth.unseen_faces`): the within-face skin spreads
and the band set a caller may change (``bench/bio_off_prior.py --oracle`` and ``--bands``)."""

import numpy as np
import pytest

import mitsuba as mi


def _face(**kwargs):
    from polarbssrdf.synth.unseen_faces import unseen_face

    mi.set_variant("llvm_ad_mono_polarized")
    return unseen_face(1, 32, 0.0, thickness_mm=0.3, gamma=0.7, eta_error=0.0, **kwargs)


def test_the_skin_varies_within_the_face_by_default_and_not_when_told():
    from polarbssrdf.synth.unseen_faces import WITHIN_FACE

    atlas, truth, _, _ = _face()
    varying = {n: float(np.std(truth[n][atlas.valid])) for n in WITHIN_FACE}
    assert all(v > 0.3 * WITHIN_FACE[n] for n, v in varying.items()), varying
    atlas, truth, _, _ = _face(within_face={"thickness_mm": 0.0, "gamma": 0.0})
    for name, value in (("thickness_mm", 0.3), ("gamma", 0.7)):
        np.testing.assert_allclose(truth[name][atlas.valid], value, rtol=1e-6)


def test_the_albedo_is_integrated_over_the_bands_given():
    from polarbssrdf.spectral import bandpass_bands, default_bands
    from polarbssrdf.synth.synthesize import subsurface_albedo

    _, truth, shipped, _ = _face()
    narrow = bandpass_bands([420, 470, 540, 590, 600, 680], 10.0)
    _, truth_narrow, bands, inputs_narrow = _face(bands=narrow)
    assert [b.name for b in bands] == [b.name for b in narrow]
    assert (sorted(k for k in inputs_narrow if k.startswith("rho_sss."))
            == sorted(f"rho_sss.{b.name}" for b in narrow))
    # the same truth, seen through other filters: blue (420 nm) darker than the red (680 nm)
    np.testing.assert_array_equal(truth_narrow["C_m"], truth["C_m"])
    assert [b.name for b in shipped] == [b.name for b in default_bands()]
    # noise-free, each input is synth's band integral of the truth over that filter
    expected = subsurface_albedo(truth_narrow, narrow)
    for index, band in enumerate(narrow):
        np.testing.assert_array_equal(inputs_narrow[f"rho_sss.{band.name}"], expected[index])
    valid = np.isfinite(inputs_narrow["rho_sss.bp420"]) & (inputs_narrow["rho_sss.bp680"] > 0)
    assert np.median(inputs_narrow["rho_sss.bp420"][valid]) < 0.8 * np.median(inputs_narrow["rho_sss.bp680"][valid])


def test_the_texel_blur_keeps_a_constant_albedo_and_spreads_a_spot_by_its_sigma():
    """:func:`texel_blurred_albedo` normalizes over the surface (a constant stays constant up to
    the edge), spreads a one-texel spot with the second moment of a Gaussian of the given sigma,
    draws the given relative noise, and leaves NaN off the surface."""
    from polarbssrdf.synth.unseen_faces import texel_blurred_albedo

    atlas, _, bands, inputs = _face()
    valid = atlas.valid
    flat = {f"rho_sss.{b.name}": np.full(valid.shape, 0.4) for b in bands}
    out = texel_blurred_albedo(atlas, flat, bands, 1.5, 0.0, seed=1)
    band = f"rho_sss.{bands[0].name}"
    np.testing.assert_allclose(out[band][valid], 0.4, rtol=1e-6)
    assert np.all(np.isnan(out[band][~valid]))
    rows, cols = np.nonzero(valid)
    centre = (int(np.median(rows)), int(np.median(cols)))
    spot = np.zeros(valid.shape)
    spot[centre] = 1.0
    blurred = texel_blurred_albedo(atlas, {band: spot}, bands[:1], 1.5, 0.0, seed=1)[band]
    grid_rows = np.arange(valid.shape[0])[:, None] - centre[0]
    weights = np.nan_to_num(blurred)
    assert np.sum(weights * grid_rows ** 2) / np.sum(weights) == pytest.approx(1.5 ** 2, rel=0.05)
    noisy = texel_blurred_albedo(atlas, flat, bands, 1.5, 0.01, seed=1)[band][valid]
    assert np.std(noisy / 0.4 - 1.0) == pytest.approx(0.01, rel=0.1)
