"""Raw synthetic captures record their exposure: calibrated DN reproduce the rendered radiance."""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.capture import IMX250MZR, expected_raw_mean, mosaic_images
from polarbssrdf.synth.synthesize import (
    ANALYSER,
    RAW_BLACK_LEVEL_DN,
    SynthesisSettings,
    raw_calibration,
    raw_sensor,
    synthesize,
)

TINY = dict(object="sphere", views=2, resolution=64, texture=32, spp=4, seed=11)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """``(analyser capture, raw capture)`` of the same rig and seed."""
    from polarbssrdf.io import load_capture

    mi.set_variant("llvm_ad_mono_polarized")
    root = tmp_path_factory.mktemp("raw_exposure")
    for raw in (False, True):
        synthesize(root / str(raw), SynthesisSettings(**TINY, raw=raw), progress=False)
    return load_capture(root / "False"), load_capture(root / "True")


def test_every_raw_record_carries_its_cameras_fixed_exposure(captures):
    from polarbssrdf.synth.synthesize import prepare_capture

    _, raw = captures
    manifest = raw.manifest
    stage = prepare_capture(SynthesisSettings(**TINY, raw=True), manifest.bands).stage
    for _, record in manifest.records():
        assert record.kind == "raw" and record.calibrated
        assert set(record.radiance_per_dn) == set(manifest.band_names)
        noise = raw_sensor(stage, record.camera)  # a function of the rig: fixed per camera
        calibration = raw_calibration(noise, manifest.band_names)
        assert record.radiance_per_dn == calibration["radiance_per_dn"]
        assert record.black_level_dn == calibration["black_level_dn"]
        assert record.saturation_dn == calibration["saturation_dn"]
        assert record.black_level_dn == RAW_BLACK_LEVEL_DN and record.saturation_dn == 4095
        # the mean response inverts exactly: (E[DN] - black) * radiance_per_dn = radiance
        for band in manifest.band_names:
            assert record.radiance(band, expected_raw_mean(2.5, noise)) == pytest.approx(2.5,
                                                                                         rel=1e-12)


def test_calibrated_raw_reproduces_the_analyser_radiance(captures):
    """Mosaic level (noise only) and after demosaicking (plus interpolation), no fitted scale."""
    from polarbssrdf.inverse.observations.build import analyser_images

    analyser, raw = captures
    bands = analyser.manifest.band_names
    for frame, record in analyser.manifest.records():
        raw_record = raw.manifest.frame(frame.index).image(record.camera, record.light)
        reference = analyser.images(frame.index, record.camera, record.light)
        dn = raw.images(frame.index, record.camera, record.light)
        for band in bands:
            truth = mosaic_images({a: np.maximum(reference[f"{band}.{a}"], 0.0) for a in ANALYSER},
                                  IMX250MZR)
            assert np.all(dn[f"{band}.raw"] < raw_record.saturation_dn)  # exposure has headroom
            measured = raw_record.radiance(band, dn[f"{band}.raw"])
            lit = truth > 0.05 * truth.max()
            assert lit.sum() > 500
            ratio = measured[lit].mean() / truth[lit].mean()
            assert ratio == pytest.approx(1.0, abs=0.01), (record.camera, band, ratio)
        # demosaicked: the observation stage's analyser images are radiance, as the analyser ones
        demosaicked = np.stack(analyser_images(raw, raw_record))
        rendered = np.stack(analyser_images(analyser, record))
        lit = rendered > 0.05 * rendered.max()
        for b in range(len(bands)):
            part, band = lit[4 * b:4 * b + 4], slice(4 * b, 4 * b + 4)
            ratio = demosaicked[band][part].mean() / rendered[band][part].mean()
            assert ratio == pytest.approx(1.0, abs=0.03), (record.camera, bands[b], ratio)
