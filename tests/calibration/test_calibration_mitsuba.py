"""Round trip into Mitsuba: a calibrated camera, converted to a Mitsuba sensor, sees the board
where the OpenCV model predicts."""

import numpy as np
import pytest

from polarbssrdf.calibration import board_pose_in_camera, calibrate_camera, detect_charuco
from polarbssrdf.calibration.mitsuba_board import render_board_mitsuba
from polarbssrdf.calibration.synthetic import random_board_poses, synthetic_detections
from polarbssrdf.io.manifest import Camera
from polarbssrdf.io.mitsuba_camera import camera_from_look_at

IMAGE_SIZE = (640, 480)


@pytest.fixture(scope="module")
def calibrated_pinhole(board):
    """A pinhole calibrated from 12 OpenCV-rendered views of a known distortion-free camera."""
    K = np.array([[575.0, 0.0, 317.2], [0.0, 575.0, 243.9], [0.0, 0.0, 1.0]])
    truth = Camera("pin", K, np.zeros(5), np.eye(3), np.zeros(3), IMAGE_SIZE)
    detections = synthetic_detections(board, truth, random_board_poses(board, 12, 31), 32)
    result = calibrate_camera(detections, board, model="pinhole")
    assert result.K[0, 0] == result.K[1, 1] and not np.any(result.dist)
    assert abs(result.K[0, 0] / 575.0 - 1) < 0.005
    assert np.hypot(result.K[0, 2] - 317.2, result.K[1, 2] - 243.9) < 2.0
    return result


def test_mitsuba_render_redetects_at_the_projected_corners(board, calibrated_pinhole):
    # put the calibrated intrinsics on a camera somewhere in the world (non-trivial R, t)
    look = camera_from_look_at([120.0, -80.0, -300.0], [0.0, 0.0, 200.0], [0.1, -1.0, 0.0], 60.0,
                               IMAGE_SIZE, name="cam")
    camera = Camera("cam", calibrated_pinhole.K, np.zeros(5), look.R, look.t, IMAGE_SIZE)
    board_in_camera = board_pose_in_camera(board, [15.0, -10.0, 520.0], (18.0, -22.0, 8.0))
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = camera.R.T
    camera_to_world[:3, 3] = camera.center
    board_to_world = camera_to_world @ board_in_camera
    image = render_board_mitsuba(board, camera, board_to_world, spp=64)
    detection = detect_charuco(image, board)
    assert detection is not None and len(detection.ids) >= 50
    world_points = detection.object_points(board) @ board_to_world[:3, :3].T + board_to_world[:3, 3]
    error = np.linalg.norm(camera.project(world_points) - detection.corners_px, axis=1)
    assert error.max() < 0.5, error.max()
    # no systematic offset (e.g. a half-pixel convention slip) hides inside that bound
    assert np.linalg.norm((camera.project(world_points) - detection.corners_px).mean(axis=0)) < 0.1


def test_a_mirrored_board_is_not_detected(board, calibrated_pinhole):
    """Seen from behind, the board is mirrored: no detection (the front side is the printed one)."""
    camera = Camera("cam", calibrated_pinhole.K, np.zeros(5), np.eye(3), np.zeros(3), IMAGE_SIZE)
    flipped = board_pose_in_camera(board, [0.0, 0.0, 520.0], (0.0, 180.0, 0.0))
    image = render_board_mitsuba(board, camera, flipped, spp=4)
    assert detect_charuco(image, board) is None
