"""The light-stage rig: coaxial geometry, polarizer orientation, validation."""

import numpy as np
import pytest

from polarbssrdf.render.lightstage import (
    PAPER_LIGHT_OFFSET_DEG,
    LightStage,
    RigCamera,
    coaxial_light,
    ring_light_stage,
)


def test_each_light_sits_at_the_paper_offset_and_polarizes_along_image_x():
    stage = ring_light_stage(n_cameras=6, distance_mm=600.0)
    assert len(stage.cameras) == 6 and len(stage.lights) == 6
    for camera in stage.cameras:
        light = stage.light(stage.light_for_camera[camera.name])
        to_camera = np.asarray(camera.origin) - np.asarray(camera.target)
        to_light = np.asarray(light.position) - np.asarray(camera.target)
        angle = np.degrees(np.arccos(np.dot(to_camera, to_light)
                                     / np.linalg.norm(to_camera) / np.linalg.norm(to_light)))
        assert angle == pytest.approx(PAPER_LIGHT_OFFSET_DEG, abs=0.01)
        np.testing.assert_allclose(light.polarization_axis, camera.right, atol=1e-12)
        np.testing.assert_allclose(light.polarizer_normal, camera.forward, atol=1e-12)
        # image x, image y and the viewing direction form a right-handed frame
        np.testing.assert_allclose(np.cross(camera.right, camera.image_up), -camera.forward,
                                   atol=1e-12)


def test_cameras_look_at_the_target_from_in_front():
    stage = ring_light_stage(n_cameras=5, azimuth_span_deg=90.0)
    for camera in stage.cameras:
        assert camera.origin[2] > 0  # the face looks along +z
        assert camera.distance_mm == pytest.approx(600.0)


def test_mitsuba_look_at_right_vector_is_image_x():
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    camera = RigCamera("c", (100.0, 50.0, 500.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 20.0, 32, 32)
    to_world = mi.ScalarTransform4f().look_at(origin=list(camera.origin),
                                              target=list(camera.target), up=list(camera.up))
    # Mitsuba's camera-space +x points to the image's left
    image_left = np.array(to_world @ mi.ScalarVector3f(1, 0, 0))
    np.testing.assert_allclose(image_left / np.linalg.norm(image_left), -camera.right, atol=1e-6)


@pytest.mark.parametrize("change,message", [
    (dict(up=(-100.0, -50.0, -500.0)), "parallel"),
    (dict(target=(100.0, 50.0, 500.0)), "target - origin"),
    (dict(fov_x_deg=0.0), "fov"),
    (dict(width=0), "image size"),
])
def test_bad_cameras(change, message):
    values = dict(name="c", origin=(100.0, 50.0, 500.0), target=(0.0, 0.0, 0.0),
                  up=(0.0, 1.0, 0.0), fov_x_deg=20.0, width=8, height=8)
    with pytest.raises(ValueError, match=message):
        RigCamera(**{**values, **change})


def test_bad_stage_pairs_and_duplicate_names():
    camera = RigCamera("c", (0.0, 0.0, 500.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 20.0, 8, 8)
    light = coaxial_light(camera, "l")
    with pytest.raises(ValueError, match="unknown pair"):
        LightStage((camera,), (light,), {"c": "missing"})
    with pytest.raises(ValueError, match="duplicate camera"):
        LightStage((camera, camera), (light,), {})
    with pytest.raises(ValueError, match="intensity"):
        coaxial_light(camera, "l", intensity=-1.0)


def test_the_lightstage_scene_file_matches_the_builder_and_renders():
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    import pathlib

    path = pathlib.Path(__file__).resolve().parents[2] / "scenes" / "lightstage.xml"
    scene = mi.load_file(str(path), resolution=48, spp=2)
    stage = ring_light_stage(n_cameras=8)
    assert len(scene.sensors()) == len(stage.cameras)
    params = mi.traverse(scene)
    light = stage.light(stage.light_for_camera["cam00"])
    np.testing.assert_allclose(np.array(params["light00.position"]).ravel(), light.position,
                               atol=1e-3)
    image = np.array(mi.render(scene, sensor=0))
    S0 = image[..., 1]
    assert np.all(np.isfinite(image)) and (S0 > 0).mean() > 0.2
