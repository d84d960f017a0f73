"""Capture cameras as Mitsuba sensors: rendered points land where K, R, t project them."""

import math

import mitsuba as mi
import numpy as np
import pytest

from polarbssrdf.io import Camera
from polarbssrdf.io.mitsuba_camera import (
    camera_from_look_at,
    camera_to_world,
    look_at_parameters,
    mitsuba_sensor_dict,
)


@pytest.fixture
def rgb():
    mi.set_variant("llvm_ad_rgb")
    return mi


def _rotation_about(axis, degrees):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _points_at_pixels(camera, pixels, depths_mm):
    """World points that project (OpenCV, no distortion) to ``pixels`` at ``depths_mm``."""
    pixels, depths = np.asarray(pixels, float), np.asarray(depths_mm, float)
    rays = np.linalg.solve(camera.K, np.column_stack([pixels, np.ones(len(pixels))]).T).T
    in_camera = rays * depths[:, None]
    return (in_camera - camera.t) @ camera.R  # R^T (X_cam - t)


def _render_emitting_spheres(camera, points, radius_px=2.0, spp=64):
    """Luminance image of small uniformly emitting spheres of about ``radius_px`` pixels."""
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 1},
             "sensor": mitsuba_sensor_dict(camera, spp=spp)}
    for i, point in enumerate(points):
        depth = float((camera.R @ point + camera.t)[2])
        scene[f"sphere{i}"] = {"type": "sphere", "center": point.tolist(),
                               "radius": radius_px * depth / camera.K[0, 0],
                               "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}
    return np.array(mi.render(mi.load_dict(scene)))[..., 0]


def _centroids(image, predicted, window=5):
    """Intensity centroids (OpenCV pixel coordinates: pixel centres at integers) near each
    predicted ``(u, v)``."""
    result = []
    for u, v in predicted:
        row, column = int(round(v)), int(round(u))
        rows, columns = np.mgrid[row - window:row + window + 1, column - window:column + window + 1]
        weights = image[rows, columns]
        assert weights.sum() > 5.0, "sphere not found near its predicted pixel"
        result.append([(weights * columns).sum() / weights.sum(),
                       (weights * rows).sum() / weights.sum()])
    return np.array(result)


PIXELS = [[12.0, 10.0], [47.3, 9.6], [83.0, 12.5], [10.5, 52.0], [46.0, 33.2], [84.7, 53.0],
          [30.2, 31.0]]


def test_rotated_camera_with_off_centre_principal_point(rgb):
    rotation = _rotation_about([0.3, 1.0, 0.2], 25.0) @ _rotation_about([0, 0, 1], 30.0)
    centre = np.array([40.0, -30.0, -400.0])
    camera = Camera("cam01", [[110.0, 0.0, 41.3], [0.0, 110.0, 27.8], [0.0, 0.0, 1.0]],
                    np.zeros(5), rotation, -rotation @ centre, (96, 64))
    points = _points_at_pixels(camera, PIXELS, [380, 420, 450, 400, 500, 430, 470])
    predicted = camera.project(points)
    assert np.allclose(predicted, PIXELS)
    found = _centroids(_render_emitting_spheres(camera, points), predicted)
    error = np.abs(found - predicted).max()
    assert error < 0.15, f"largest centroid error {error:.3f} px"


def test_look_at_camera_renders_where_it_projects(rgb):
    camera = camera_from_look_at([200.0, 150.0, 500.0], [0.0, 10.0, 0.0], [0.1, 1.0, 0.0], 40.0,
                                 (96, 64), principal_point=(52.25, 28.5))
    points = _points_at_pixels(camera, PIXELS, [500, 520, 560, 600, 610, 540, 580])
    predicted = camera.project(points)
    found = _centroids(_render_emitting_spheres(camera, points), predicted)
    error = np.abs(found - predicted).max()
    assert error < 0.15, f"largest centroid error {error:.3f} px"


def test_image_orientation(rgb):
    """A point up and to the right of the target shows in the upper right of the image."""
    camera = camera_from_look_at([0.0, 0.0, 500.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 30.0, (64, 48))
    point = np.array([[60.0, 40.0, 0.0]])  # looking along -z with +y up: image right is world +x
    u, v = camera.project(point)[0]
    assert u > 31.5 and v < 23.5
    image = _render_emitting_spheres(camera, point)
    row, column = np.unravel_index(np.argmax(image), image.shape)
    assert abs(column - u) <= 2 and abs(row - v) <= 2


def test_look_at_matches_mitsuba_look_at(rgb):
    origin, target, up = [120.0, -40.0, 380.0], [5.0, 12.0, -3.0], [0.2, 1.0, 0.1]
    camera = camera_from_look_at(origin, target, up, 35.0, (80, 60))
    ours = mitsuba_sensor_dict(camera)
    reference = mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up)
    assert np.allclose(np.array(ours["to_world"].matrix), np.array(reference.matrix), atol=1e-4)
    assert ours["fov"] == pytest.approx(35.0, abs=1e-9)
    assert ours["principal_point_offset_x"] == pytest.approx(0.0, abs=1e-12)
    assert ours["principal_point_offset_y"] == pytest.approx(0.0, abs=1e-12)
    # a proper rotation: Mitsuba rejects scale and handedness changes in cameras
    assert np.linalg.det(camera_to_world(camera)[:3, :3]) == pytest.approx(1.0)


def test_look_at_round_trip():
    camera = camera_from_look_at([10.0, 20.0, 300.0], [-4.0, 0.0, 2.0], [0.0, 0.3, 1.0], 50.0,
                                 (32, 24), name="camX", sensor="IMX250MZR")
    origin, target, up, fov = look_at_parameters(camera, distance_mm=250.0)
    again = camera_from_look_at(origin, target, up, fov, camera.image_size, name="camX",
                                sensor="IMX250MZR")
    assert np.allclose(again.K, camera.K, rtol=1e-12)
    assert np.allclose(again.R, camera.R, atol=1e-12)
    assert np.allclose(again.t, camera.t, atol=1e-9)
    assert np.allclose(origin, [10.0, 20.0, 300.0])
    assert fov == pytest.approx(50.0)
    assert camera.K[0, 2] == 15.5 and camera.K[1, 2] == 11.5  # image centre, OpenCV convention
    assert Camera.from_json(camera.to_json()) == camera


def test_unsupported_cameras_are_refused(rgb):
    camera = camera_from_look_at([0, 0, 100], [0, 0, 0], [0, 1, 0], 30.0, (16, 16))
    distorted = Camera("d", camera.K, [0.1, 0, 0, 0, 0], camera.R, camera.t, camera.image_size)
    with pytest.raises(ValueError, match="non-zero distortion .* undistort"):
        mitsuba_sensor_dict(distorted)
    K = camera.K.copy()
    K[1, 1] *= 1.01
    with pytest.raises(ValueError, match="square pixels"):
        mitsuba_sensor_dict(Camera("s", K, np.zeros(5), camera.R, camera.t, camera.image_size))
    K = camera.K.copy()
    K[0, 1] = 0.5
    with pytest.raises(ValueError, match="skew"):
        mitsuba_sensor_dict(Camera("k", K, np.zeros(5), camera.R, camera.t, camera.image_size))
    with pytest.raises(ValueError, match="parallel"):
        camera_from_look_at([0, 0, 100], [0, 0, 0], [0, 0, 1], 30.0, (16, 16))
    with pytest.raises(ValueError, match="fov_x_deg"):
        camera_from_look_at([0, 0, 100], [0, 0, 0], [0, 1, 0], 180.0, (16, 16))


def test_field_of_view_formula():
    camera = camera_from_look_at([0, 0, 100], [0, 0, 0], [0, 1, 0], 60.0, (200, 100))
    assert camera.K[0, 0] == pytest.approx(100.0 / math.tan(math.radians(30.0)))
