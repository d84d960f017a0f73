"""BOARD.json validation, the board image and ChArUco detection conventions."""

import json

import numpy as np
import pytest

from polarbssrdf.calibration import board_image, detect_charuco, read_board
from polarbssrdf.calibration.detect import detector_pixel_offset


def test_board_geometry_and_json_round_trip(tmp_path, board):
    assert board.size_mm == (330.0, 240.0) and board.corner_count == 70
    corners = board.corner_points_mm()
    # corner ids run along x first; corner 0 sits one square in from the top-left
    np.testing.assert_allclose(corners[0], [30.0, 30.0, 0.0])
    np.testing.assert_allclose(corners[1] - corners[0], [30.0, 0.0, 0.0])
    np.testing.assert_allclose(corners[10] - corners[0], [0.0, 30.0, 0.0])
    path = tmp_path / "board.json"
    path.write_text(json.dumps(board.to_json()))
    assert read_board(path) == board


def test_detected_corners_of_the_flat_board_image_follow_the_pixel_convention(board):
    """Board point (X, Y) mm lies at pixel (X, Y) * px_per_mm - 0.5 (OpenCV pixel centres);
    OpenCV releases with the half-pixel ChArUco bug (opencv/opencv#25539) are corrected."""
    assert detector_pixel_offset() in (0.0, 0.5)
    image = np.pad(board_image(board, 3.0), 20, constant_values=255)
    detection = detect_charuco(image, board)
    assert detection is not None and len(detection.ids) == board.corner_count
    expected = detection.object_points(board)[:, :2] * 3.0 - 0.5 + 20
    np.testing.assert_allclose(detection.corners_px, expected, atol=0.1)


def test_an_image_without_a_board_gives_no_detection(board):
    rng = np.random.default_rng(0)
    assert detect_charuco(rng.integers(0, 255, (480, 640), dtype=np.uint8), board) is None
    assert detect_charuco(np.full((480, 640), 128, np.uint8), board) is None


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ('{"squares_x": 5, "squares_y": 4, "square_mm": 30}', "missing field\\(s\\) marker_mm, dictionary"),
    ('{"squares_x": 5, "squares_y": 4, "square_mm": 30, "marker_mm": 22, "dictionary": "DICT_9X9_50"}',
     "unknown ArUco dictionary 'DICT_9X9_50'"),
    ('{"squares_x": 5, "squares_y": 4, "square_mm": 30, "marker_mm": 32, "dictionary": "DICT_4X4_50"}',
     "marker_mm \\(32\\) must be smaller than square_mm \\(30\\)"),
    ('{"squares_x": 1, "squares_y": 4, "square_mm": 30, "marker_mm": 22, "dictionary": "DICT_4X4_50"}',
     "squares_x must be an integer >= 2"),
    ('{"squares_x": 5, "squares_y": 4, "square_mm": -3, "marker_mm": 22, "dictionary": "DICT_4X4_50"}',
     "square_mm must be a positive number"),
    ('{"squares_x": 20, "squares_y": 20, "square_mm": 30, "marker_mm": 22, "dictionary": "DICT_4X4_50"}',
     "needs 200 markers but dictionary DICT_4X4_50 has only 50"),
    ('{"squares_x": 5, "squares_y": 4, "square_mm": 30, "marker_mm": 22, "dictionary": "DICT_4X4_50", '
     '"colour": "red"}', "unexpected field\\(s\\) colour"),
    ("[1, 2]", "must be a JSON object"),
])
def test_malformed_board_files_are_clear_errors(tmp_path, content, message):
    path = tmp_path / "BOARD.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as info:
        read_board(path)
    assert str(path) in str(info.value)


def test_missing_board_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="board file not found"):
        read_board(tmp_path / "nope.json")
