"""Issue 31's test faces (:mod:`polarbssrdf.synth.unseen_faces`): the within-face skin spreads
and the band set a caller may change (``bench/bio_off_prior.py --oracle`` and ``--bands``)."""

import numpy as np

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
