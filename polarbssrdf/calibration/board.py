"""ChArUco board description (``BOARD.json``) and its OpenCV objects.

A ChArUco board is a chessboard whose white squares carry ArUco markers
(Garrido-Jurado et al. 2014, "Automatic generation and detection of highly
reliable fiducial markers under occlusion"; OpenCV's ``aruco`` module). Its
inner chessboard corners are the calibration points; the markers identify
them, so partly visible boards still give labelled corners.

Board frame (OpenCV's): origin at the outer top-left corner of the board as
printed, x along the ``squares_x`` direction (image right in
:func:`board_image`), y along ``squares_y`` (image down), z = x cross y
(into the board, away from a camera that sees its printed side); mm.

``BOARD.json``::

    {"squares_x": 9, "squares_y": 6, "square_mm": 25.0, "marker_mm": 18.0,
     "dictionary": "DICT_4X4_50", "legacy_pattern": false}

``legacy_pattern`` (optional, default false) selects the layout OpenCV < 4.6
drew for boards with an even number of rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["BOARD_FIELDS", "BoardSpec", "aruco_dictionary_names", "board_image", "read_board"]

BOARD_FIELDS = ("squares_x", "squares_y", "square_mm", "marker_mm", "dictionary")
"""Required fields of ``BOARD.json``; ``legacy_pattern`` is optional."""


def _cv2():
    try:
        import cv2
    except ImportError as error:  # pragma: no cover - environment problem
        raise ImportError("polarbssrdf.calibration needs OpenCV with the aruco module: "
                          "pip install 'opencv-contrib-python-headless>=4.8,<6'") from error
    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "CharucoBoard"):
        raise ImportError(f"OpenCV {cv2.__version__} lacks cv2.aruco.CharucoBoard (needs >= 4.7 "
                          "with the contrib/objdetect aruco module)")
    return cv2


def aruco_dictionary_names() -> list[str]:
    """Names of the predefined ArUco dictionaries of the installed OpenCV (``DICT_4X4_50``, ...)."""
    cv2 = _cv2()
    return sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_"))


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares per side, square and marker edge (mm), ArUco dictionary.

    Parameters
    ----------
    squares_x, squares_y:
        Number of chessboard squares along x (columns) and y (rows), >= 2 each.
    square_mm, marker_mm:
        Edge lengths in mm; ``0 < marker_mm < square_mm``.
    dictionary:
        Name of a predefined OpenCV ArUco dictionary, e.g. ``DICT_4X4_50``.
    legacy_pattern:
        Use the pre-4.6 OpenCV layout (boards with an even number of rows).
    """

    squares_x: int
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str
    legacy_pattern: bool = False

    def __post_init__(self):
        for name in ("squares_x", "squares_y"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 2:
                raise ValueError(f"board: {name} must be an integer >= 2, got {value!r}")
        for name in ("square_mm", "marker_mm"):
            value = getattr(self, name)
            if (not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool)
                    or not math.isfinite(float(value)) or float(value) <= 0):
                raise ValueError(f"board: {name} must be a positive number (mm), got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.marker_mm >= self.square_mm:
            raise ValueError(f"board: marker_mm ({self.marker_mm:g}) must be smaller than "
                             f"square_mm ({self.square_mm:g})")
        if not isinstance(self.legacy_pattern, bool):
            raise ValueError(f"board: legacy_pattern must be true or false, got {self.legacy_pattern!r}")
        names = aruco_dictionary_names()
        if not isinstance(self.dictionary, str) or self.dictionary not in names:
            raise ValueError(f"board: unknown ArUco dictionary {self.dictionary!r} "
                             f"(known: {', '.join(names)})")
        markers = (self.squares_x * self.squares_y) // 2
        size = self.cv_dictionary().bytesList.shape[0]
        if markers > size:
            raise ValueError(f"board: a {self.squares_x} x {self.squares_y} board needs {markers} "
                             f"markers but dictionary {self.dictionary} has only {size}")

    # --- derived
    @property
    def size_mm(self) -> tuple[float, float]:
        """Board width and height in mm."""
        return self.squares_x * self.square_mm, self.squares_y * self.square_mm

    @property
    def corner_count(self) -> int:
        """Number of inner chessboard corners (ChArUco corners)."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    def corner_points_mm(self) -> np.ndarray:
        """``(corner_count, 3)`` board-frame coordinates (mm) of the corners, indexed by id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    def cv_dictionary(self):
        """The OpenCV ``aruco.Dictionary``."""
        cv2 = _cv2()
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self):
        """The OpenCV ``aruco.CharucoBoard`` (lengths in mm)."""
        cv2 = _cv2()
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm,
                                       self.marker_mm, self.cv_dictionary())
        if self.legacy_pattern:
            board.setLegacyPattern(True)
        return board

    # --- JSON
    def to_json(self) -> dict:
        return {"squares_x": self.squares_x, "squares_y": self.squares_y,
                "square_mm": self.square_mm, "marker_mm": self.marker_mm,
                "dictionary": self.dictionary, "legacy_pattern": self.legacy_pattern}

    @classmethod
    def from_json(cls, data) -> BoardSpec:
        """Validate a parsed ``BOARD.json``; errors name the missing/unknown/bad field."""
        if not isinstance(data, dict):
            raise ValueError(f"board: must be a JSON object, got {type(data).__name__}")
        missing = [key for key in BOARD_FIELDS if key not in data]
        if missing:
            raise ValueError(f"board: missing field(s) {', '.join(missing)} "
                             f"(required: {', '.join(BOARD_FIELDS)})")
        unknown = [key for key in data if key not in (*BOARD_FIELDS, "legacy_pattern", "schema_version")]
        if unknown:
            raise ValueError(f"board: unexpected field(s) {', '.join(unknown)} "
                             f"(allowed: {', '.join(BOARD_FIELDS)}, legacy_pattern)")
        return cls(data["squares_x"], data["squares_y"], data["square_mm"], data["marker_mm"],
                   data["dictionary"], data.get("legacy_pattern", False))


def read_board(path) -> BoardSpec:
    """Read and validate ``BOARD.json``; every error names the file."""
    from polarbssrdf.io.jsonfile import read_json_file

    path = Path(path)
    data = read_json_file(path, "board file")
    try:
        return BoardSpec.from_json(data)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def board_image(board: BoardSpec, px_per_mm: float) -> np.ndarray:
    """The printable board as a uint8 image, ``px_per_mm`` pixels per mm, no margin.

    Pixel ``(column i, row j)`` covers board coordinates
    ``[i, i + 1) / px_per_mm`` x ``[j, j + 1) / px_per_mm``: the board point
    ``(X, Y)`` mm lies at OpenCV pixel coordinates ``(X, Y) * px_per_mm - 0.5``.
    """
    width_mm, height_mm = board.size_mm
    width, height = round(width_mm * px_per_mm), round(height_mm * px_per_mm)
    if abs(width - width_mm * px_per_mm) > 1e-6 or abs(height - height_mm * px_per_mm) > 1e-6:
        raise ValueError(f"px_per_mm={px_per_mm:g} does not give a whole number of pixels for a "
                         f"{width_mm:g} x {height_mm:g} mm board")
    return board.cv_board().generateImage((width, height), marginSize=0, borderBits=1)
