"""Synthetic light-stage views of the face: highlights live in I0 and vanish in I90."""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.render.subsurface import layered_exitance, transmitted_irradiance
from polarbssrdf.render.view import render_analyser_images, view_scene
from polarbssrdf.spectral import default_bands
from polarbssrdf.synth.synthesize import (
    SynthesisSettings,
    prepare_capture,
    prepare_frame,
    render_frame_view,
)


@pytest.fixture(scope="module")
def face():
    mi.set_variant("llvm_ad_mono_polarized")
    settings = SynthesisSettings(object="face", views=2, resolution=96, texture=128, spp=4)
    prepared = prepare_capture(settings, default_bands()[:2])
    return prepared, prepare_frame(prepared, 0)


def render(prepared, state, camera, maps, exitance):
    light = prepared.stage.light(prepared.stage.light_for_camera[camera.name])
    scene = view_scene(state.mesh, camera, light, maps, exitance, spp=8, seed=1)
    images, _ = render_analyser_images(scene, 8, seed=1)
    return images, scene


def test_specular_highlights_appear_in_I0_and_vanish_in_I90(face):
    prepared, state = face
    camera = prepared.stage.cameras[0]
    zero = np.zeros_like(state.maps["eta"])
    glossy, scene = render(prepared, state, camera, state.maps, zero)
    irradiance = transmitted_irradiance(scene, state.atlas, state.maps["eta"])
    exitance = layered_exitance(irradiance, state.layers[0], prepared.kernels[0], state.atlas)
    full, _ = render(prepared, state, camera, state.maps, exitance)
    lit = full["I0"] > 0.05 * full["I0"].max()
    assert lit.sum() > 500
    # the coaxial light's highlights are a visible part of I0 ...
    assert (glossy["I0"][lit] / full["I0"][lit]).max() > 0.2
    # ... and, 5.7 degrees off coaxial, leave less than 1% of their strength in I90
    assert np.abs(glossy["I90"][lit]).max() < 0.01 * glossy["I0"][lit].max()
    # subsurface light is (nearly) depolarized, specular light polarized: I0 >= I90
    assert np.all(full["I0"][lit] - full["I90"][lit] > -1e-3 * full["I0"].max())


def test_rendered_channels_cover_every_band(face):
    prepared, state = face
    channels = render_frame_view(prepared, state, prepared.stage.cameras[1])
    names = {f"{band.name}.{a}" for band in prepared.bands for a in ("I0", "I45", "I90", "I135")}
    assert set(channels) == names
    for band in prepared.bands:
        I0, I45, I90, I135 = (channels[f"{band.name}.{a}"] for a in ("I0", "I45", "I90", "I135"))
        np.testing.assert_allclose(I0 + I90, I45 + I135, atol=1e-5 * I0.max())
        assert I0.max() > 0 and np.all(np.isfinite(I0))


def test_hemoglobin_changes_over_a_dynamic_sequence(face):
    prepared, _ = face
    settings = SynthesisSettings(object="face", views=1, frames=3, resolution=32, texture=64, spp=1)
    dynamic = prepare_capture(settings, default_bands()[:2], prepared.truth_settings)
    first, middle, last = dynamic.maps(0), dynamic.maps(1), dynamic.maps(2)
    assert np.all(middle["C_h_in"] >= first["C_h_in"]) and np.all(last["C_h_in"] >= middle["C_h_in"])
    positive = first["C_h_in"] > 0
    # the flush is strongest on the cheeks, where it reaches the full swing at the last frame
    assert (last["C_h_in"][positive] / first["C_h_in"][positive]).max() == pytest.approx(
        1 + dynamic.truth_settings.hemoglobin_swing, rel=1e-3)
    np.testing.assert_array_equal(last["C_m"], first["C_m"])


def test_capture_cameras_reproduce_the_rendering_cameras(face):
    """The cameras written to capture.json (OpenCV K, R, t) give the rays the synthesizer rendered."""
    from polarbssrdf.io import mitsuba_sensor_dict
    from polarbssrdf.synth.synthesize import capture_manifest

    prepared, _ = face
    manifest = capture_manifest(prepared)
    uv = np.random.default_rng(2).uniform(0.02, 0.98, size=(2, 200))
    for rig_camera in prepared.stage.cameras:
        rendered = mi.load_dict(rig_camera.sensor_dict(spp=1))
        stored = mi.load_dict(mitsuba_sensor_dict(manifest.camera(rig_camera.name), spp=1))
        rays = [sensor.sample_ray(0.0, 0.5, mi.Point2f(uv), mi.Point2f(0.5))[0]
                for sensor in (rendered, stored)]
        d = np.array(rays[0].d)
        np.testing.assert_allclose(np.array(rays[1].d), d, atol=1e-5)
        # the same line (origins sit on different near planes)
        offset = np.array(rays[0].o) - np.array(rays[1].o)
        np.testing.assert_allclose(np.cross(offset.T, d.T), 0.0, atol=1e-3)
