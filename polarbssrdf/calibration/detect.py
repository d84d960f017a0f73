"""ChArUco corner detection (OpenCV ``CharucoDetector``), for OpenCV 4.7+ and 5.x.

OpenCV 4.x returns corners as ``(N, 1, 2)`` and ids as ``(N, 1)``; 5.x as
``(N, 2)`` and ``(N,)``. Everything here is normalized to ``(N, 2)`` float64
pixels (OpenCV convention: pixel centres at integer coordinates) and ``(N,)``
int32 corner ids.

OpenCV releases before the fix of opencv/opencv issue 25539 (pull request
28380, January 2026; e.g. 4.10) return ChArUco corners shifted by +0.5 px in
x and y (a half-pixel shift around ``cornerSubPix``). Rather than trusting
version numbers, :func:`detector_pixel_offset` measures the installed
detector once on a synthetic board whose corners are known exactly, and
:func:`detect_charuco` subtracts that offset.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .board import BoardSpec, _cv2

__all__ = ["IMAGE_SUFFIXES", "MIN_CORNERS", "Detection", "detect_charuco", "detector_pixel_offset",
           "read_gray_image"]

MIN_CORNERS = 8
"""Fewest ChArUco corners a view needs to be used (non-collinear)."""

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".exr")
"""Image files the geometry calibration reads (EXR via :mod:`polarbssrdf.io.exr`)."""


@dataclass(frozen=True)
class Detection:
    """ChArUco corners found in one image.

    Attributes
    ----------
    ids:
        ``(N,)`` corner ids (index into :meth:`BoardSpec.corner_points_mm`).
    corners_px:
        ``(N, 2)`` sub-pixel positions ``(u, v)``, OpenCV pixel centres (corrected for
        :func:`detector_pixel_offset`).
    image_size:
        ``(width, height)`` of the image.
    """

    ids: np.ndarray
    corners_px: np.ndarray
    image_size: tuple[int, int]

    def object_points(self, board: BoardSpec) -> np.ndarray:
        """``(N, 3)`` board-frame points (mm) matching :attr:`corners_px` (``matchImagePoints``)."""
        objects, _ = board.cv_board().matchImagePoints(
            self.corners_px.reshape(-1, 1, 2).astype(np.float32), self.ids.reshape(-1, 1))
        objects = np.asarray(objects, dtype=np.float64).reshape(-1, 3)
        if len(objects) != len(self.ids):
            raise ValueError(f"corner ids {self.ids.tolist()} do not all belong to the board")
        return objects


def _to_uint8_gray(image: np.ndarray) -> np.ndarray:
    """Grey uint8 view of an image for detection (float images: scaled to their 99.5th percentile)."""
    cv2 = _cv2()
    image = np.asarray(image)
    if image.ndim == 3:
        if image.shape[2] == 1:
            image = image[..., 0]
        elif image.shape[2] in (3, 4):
            image = image[..., :3].astype(np.float32).mean(axis=2)
        else:
            raise ValueError(f"image has {image.shape[2]} channels; expected 1, 3 or 4")
    elif image.ndim != 2:
        raise ValueError(f"image must be H x W or H x W x C, got shape {image.shape}")
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    values = image.astype(np.float32)
    if image.dtype == np.uint16:
        values = values / 257.0
    else:
        finite = values[np.isfinite(values)]
        top = float(np.percentile(finite, 99.5)) if finite.size else 0.0
        values = np.nan_to_num(values) * (255.0 / top if top > 0 else 1.0)
    return cv2.convertScaleAbs(np.clip(values, 0, 255))


def read_gray_image(path) -> np.ndarray:
    """A grey uint8 image from PNG/JPEG/TIFF/... (OpenCV) or float EXR (mean of channels)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    if path.suffix.lower() == ".exr":
        from polarbssrdf.io.exr import read_exr

        channels, _ = read_exr(path)
        if not channels:
            raise ValueError(f"{path}: EXR has no channels")
        return _to_uint8_gray(np.mean([np.asarray(c, np.float32) for c in channels.values()], axis=0))
    cv2 = _cv2()
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: OpenCV cannot read this image")
    return _to_uint8_gray(image)


@functools.lru_cache(maxsize=1)
def detector_pixel_offset() -> float:
    """Systematic shift (px, same in x and y) of the installed OpenCV's ChArUco corners.

    Detects the corners of a flat 5 x 4 board image (20 px squares, known corner
    positions ``20 k - 0.5`` in OpenCV pixel-centre coordinates, plus the margin)
    and returns their mean offset rounded to a multiple of 0.5 px: 0 for a correct
    detector, 0.5 for releases with opencv/opencv issue 25539.
    """
    cv2 = _cv2()
    board = BoardSpec(5, 4, 20.0, 14.0, "DICT_4X4_50")
    margin = 10
    image = np.pad(board.cv_board().generateImage((100, 80), marginSize=0, borderBits=1), margin,
                   constant_values=255)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv_board()).detectBoard(image)
    if corners is None or ids is None or len(ids) < 4:
        raise RuntimeError(f"OpenCV {cv2.__version__}: cannot detect a synthetic ChArUco board; "
                           "the aruco module does not work as expected")
    ids = np.asarray(ids).reshape(-1)
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    expected = board.corner_points_mm()[ids, :2] - 0.5 + margin
    return float(np.round(2.0 * np.mean(corners - expected)) / 2.0)


def detect_charuco(image: np.ndarray, board: BoardSpec, *, min_corners: int = MIN_CORNERS
                   ) -> Detection | None:
    """Detect the ChArUco corners of ``board`` in ``image``.

    Parameters
    ----------
    image:
        H x W (x C) array, uint8/uint16/float.
    board:
        The board to look for.
    min_corners:
        Fewer corners than this (or collinear ones) count as "no board".

    Returns
    -------
    Detection or None
        None when the board is not (sufficiently) visible.
    """
    cv2 = _cv2()
    gray = _to_uint8_gray(image)
    cv_board = board.cv_board()
    detector = cv2.aruco.CharucoDetector(cv_board)
    corners, ids, _marker_corners, _marker_ids = detector.detectBoard(gray)
    if corners is None or ids is None or len(ids) < min_corners:
        return None
    ids = np.asarray(ids, dtype=np.int32).reshape(-1)
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2) - detector_pixel_offset()
    if cv_board.checkCharucoCornersCollinear(ids.reshape(-1, 1)):
        return None
    order = np.argsort(ids)
    return Detection(ids[order], corners[order], (gray.shape[1], gray.shape[0]))
