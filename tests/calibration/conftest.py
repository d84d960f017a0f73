"""Shared synthetic ChArUco scenes for the calibration tests (rendered once per session)."""

import numpy as np
import pytest

from polarbssrdf.calibration import BoardSpec
from polarbssrdf.calibration.synthetic import random_board_poses, synthetic_detections
from polarbssrdf.io.manifest import Camera
from polarbssrdf.io.mitsuba_camera import camera_from_look_at

IMAGE_SIZE = (640, 480)


@pytest.fixture(scope="session")
def board():
    """11 x 8 squares of 30 mm, 22 mm markers: 330 x 240 mm, fills a good part of a 640 x 480 view."""
    return BoardSpec(11, 8, 30.0, 22.0, "DICT_4X4_50")


@pytest.fixture(scope="session")
def true_camera():
    """A distorted camera with fx != fy and an off-centre principal point (world = camera)."""
    K = np.array([[612.0, 0.0, 326.4], [0.0, 607.5, 234.1], [0.0, 0.0, 1.0]])
    return Camera("cam0", K, [-0.08, 0.05, 0.0006, -0.0004, 0.0], np.eye(3), np.zeros(3), IMAGE_SIZE)


@pytest.fixture(scope="session")
def single_camera_detections(board, true_camera):
    """14 views of the board by ``true_camera`` (mild blur, 2 DN noise)."""
    poses = random_board_poses(board, 14, 7)
    return synthetic_detections(board, true_camera, poses, 8)


@pytest.fixture(scope="session")
def rig_truth():
    """Three converging cameras 160 mm apart looking at a point 500 mm ahead of cam0 (world = cam0)."""
    cameras = []
    for i, (x, focal, dist) in enumerate([(0.0, 600.0, [-0.05, 0.02, 0, 0, 0]),
                                          (160.0, 620.0, [-0.03, 0.0, 0, 0, 0]),
                                          (-160.0, 590.0, [-0.06, 0.03, 0, 0, 0])]):
        look = camera_from_look_at([x, 0.0, 0.0], [0.0, 0.0, 500.0], [0.0, -1.0, 0.0], 60.0,
                                   IMAGE_SIZE, name=f"cam{i}")
        K = look.K.copy()
        K[0, 0] = K[1, 1] = focal
        K[0, 2] += 3.0 * i
        K[1, 2] -= 2.0 * i
        cameras.append(Camera(look.name, K, dist, look.R, look.t, IMAGE_SIZE))
    return cameras


@pytest.fixture(scope="session")
def rig_detections(board, rig_truth):
    """``{camera: {shot: Detection}}``: 12 simultaneous shots seen by all three cameras."""
    poses = random_board_poses(board, 12, 11, distance_mm=(450.0, 540.0), tilt_deg=28.0)
    return {camera.name: synthetic_detections(board, camera, poses, 20 + i)
            for i, camera in enumerate(rig_truth)}
