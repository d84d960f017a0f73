"""Calibration toolkit (supplement section 3.2): camera geometry from ChArUco
boards (OpenCV), a 3 x 3 colour matrix from a colour checker (colour-science),
camera spectral response and filter transmittance, cross-camera gains from a
white sphere. Lengths in mm, wavelengths in nm. See ``docs/calibration.md``.

OpenCV (``opencv-contrib-python-headless``) is imported lazily, by the
functions that need it.
"""

from .board import BoardSpec, aruco_dictionary_names, board_image, read_board
from .colour_matrix import ColourFit, apply_colour_matrix, checker_reference, fit_colour_matrix
from .detect import Detection, detect_charuco, read_gray_image
from .geometry import (CAMERA_MODELS, MIN_VIEWS, CameraCalibration, RigCalibration, calibrate_camera,
                       calibrate_rig, relative_pose_error)
from .normalization import sphere_gains, sphere_statistic
from .rig_io import cameras_document, detect_image_tree, list_image_tree, read_cameras, write_cameras
from .spectral_response import (calibrated_bands, estimate_response, filter_transmittance,
                                second_difference_matrix)
from .synthetic import (board_pose_in_camera, random_board_poses, render_board_view, rotation_xyz,
                        synthetic_detections)

__all__ = [
    "CAMERA_MODELS", "MIN_VIEWS", "BoardSpec", "CameraCalibration", "ColourFit", "Detection",
    "RigCalibration", "apply_colour_matrix", "aruco_dictionary_names", "board_image",
    "board_pose_in_camera", "calibrate_camera", "calibrate_rig", "calibrated_bands",
    "cameras_document", "checker_reference", "detect_charuco", "detect_image_tree",
    "estimate_response", "filter_transmittance", "fit_colour_matrix", "list_image_tree",
    "read_board", "read_cameras", "read_gray_image", "relative_pose_error", "render_board_view",
    "random_board_poses", "rotation_xyz", "second_difference_matrix", "sphere_gains",
    "sphere_statistic", "synthetic_detections", "write_cameras",
]
