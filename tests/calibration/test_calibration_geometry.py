"""Camera and rig calibration from synthetic ChArUco views of known cameras."""

import dataclasses

import cv2
import numpy as np
import pytest

from polarbssrdf.calibration import Detection, calibrate_camera, calibrate_rig, relative_pose_error


def test_single_camera_intrinsics_are_recovered(board, true_camera, single_camera_detections):
    assert sum(d is not None for d in single_camera_detections.values()) >= 12
    result = calibrate_camera(single_camera_detections, board)
    K = true_camera.K
    assert abs(result.K[0, 0] / K[0, 0] - 1) < 0.005
    assert abs(result.K[1, 1] / K[1, 1] - 1) < 0.005
    assert np.hypot(*(result.K[:2, 2] - K[:2, 2])) < 2.0
    assert result.rms_px < 0.5
    assert result.rejected == []
    assert set(result.view_rms_px) == set(single_camera_detections)
    # the calibrated model projects the board corners where the true camera does (whole image)
    grid = np.stack(np.meshgrid(np.linspace(40, 600, 8), np.linspace(40, 440, 6)), -1).reshape(-1, 2)
    rays = cv2.undistortPoints(grid.reshape(-1, 1, 2), K, true_camera.dist).reshape(-1, 2)
    points = np.column_stack([rays, np.ones(len(rays))]) * 500.0
    reprojected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), result.K, result.dist)
    assert np.abs(reprojected.reshape(-1, 2) - grid).max() < 2.0


def test_board_poses_match_the_rendered_ones(board, true_camera, single_camera_detections):
    result = calibrate_camera(single_camera_detections, board)
    # the pose of each view places the corners at the detected positions: check one view's
    # board distance against the projection geometry (z of the board centre in 430-560 mm)
    for pose in result.board_poses.values():
        centre = pose[:3, :3] @ np.array([165.0, 120.0, 0.0]) + pose[:3, 3]
        assert 425.0 < centre[2] < 565.0


def test_an_outlier_view_is_rejected(board, single_camera_detections):
    rng = np.random.default_rng(3)
    detections = dict(single_camera_detections)
    bad = detections["shot03"]
    # a view whose corners are wrong by several pixels (e.g. a moved board or a misdetection)
    detections["shot03"] = dataclasses.replace(
        bad, corners_px=bad.corners_px + rng.normal(0.0, 4.0, bad.corners_px.shape))
    result = calibrate_camera(detections, board)
    assert result.rejected == ["shot03"]
    assert "shot03" not in result.views
    assert result.view_rms_px["shot03"] > 3.0
    assert result.rms_px < 0.5


def test_too_few_views_is_a_clear_error(board, single_camera_detections):
    few = dict(list(single_camera_detections.items())[:3])
    few["blank"] = None
    with pytest.raises(ValueError, match="camera cam7: too few views with a detected board: 3"):
        calibrate_camera(few, board, name="cam7")


def test_inconsistent_image_sizes_are_a_clear_error(board, single_camera_detections):
    detections = dict(single_camera_detections)
    odd = detections["shot05"]
    detections["shot05"] = Detection(odd.ids, odd.corners_px, (800, 600))
    with pytest.raises(ValueError, match=r"inconsistent sizes.*800 x 600: shot05"):
        calibrate_camera(detections, board)


def test_unknown_model_is_rejected(board, single_camera_detections):
    with pytest.raises(ValueError, match="unknown camera model 'fisheye'"):
        calibrate_camera(single_camera_detections, board, model="fisheye")


def test_three_camera_rig_relative_poses(board, rig_truth, rig_detections):
    rig = calibrate_rig(rig_detections, board)
    names = [camera.name for camera in rig.cameras]
    assert names == ["cam0", "cam1", "cam2"]
    np.testing.assert_allclose(rig.cameras[0].R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rig.cameras[0].t, 0.0, atol=1e-12)
    for i in (1, 2):
        angle_deg, offset_mm = relative_pose_error(rig.cameras[0], rig.cameras[i],
                                                   rig_truth[0], rig_truth[i])
        assert angle_deg < 0.2 and offset_mm < 2.0, (i, angle_deg, offset_mm)
    # and between the two non-reference cameras (chained through cam0)
    angle_deg, offset_mm = relative_pose_error(rig.cameras[1], rig.cameras[2], rig_truth[1], rig_truth[2])
    assert angle_deg < 0.2 and offset_mm < 2.0
    # camera centres: 160 mm baseline either side of cam0
    assert abs(np.linalg.norm(rig.cameras[1].center - rig.cameras[2].center) - 320.0) < 2.0
    assert all(link["rms_px"] < 0.5 for link in rig.links)


def test_rig_with_a_disconnected_camera_is_a_clear_error(board, rig_detections):
    detections = {name: dict(shots) for name, shots in rig_detections.items()}
    # cam2's shots get names no other camera has: it shares no view with the rig
    detections["cam2"] = {f"other{shot}": d for shot, d in detections["cam2"].items()}
    with pytest.raises(ValueError, match="camera\\(s\\) cam2 share no view"):
        calibrate_rig(detections, board)


def test_rig_reference_camera_is_the_world(board, rig_truth, rig_detections):
    rig = calibrate_rig(rig_detections, board, reference="cam1")
    assert rig.cameras[0].name == "cam1"
    np.testing.assert_allclose(rig.cameras[0].R, np.eye(3), atol=1e-12)
    angle_deg, offset_mm = relative_pose_error(rig.cameras[0], rig.cameras[1], rig_truth[1], rig_truth[0])
    assert angle_deg < 0.2 and offset_mm < 2.0
