"""Reading a calibration image tree and writing/reading ``CAMERAS.json``.

Image tree: ``DIR/<camera>/<shot>.<ext>``, one folder per camera (its name
is the camera name), images named by shot; the same shot name in several
folders is one simultaneous view of the board. Extensions:
:data:`~polarbssrdf.calibration.detect.IMAGE_SUFFIXES`.

``CAMERAS.json`` (schema ``polarbssrdf.calibration.cameras``, version 1)::

    {"schema": "polarbssrdf.calibration.cameras", "schema_version": 1,
     "units": {"length": "mm"}, "board": {...BOARD.json...},
     "model": "opencv", "reference_camera": "cam00",
     "cameras": [{"name", "K", "dist", "R", "t", "image_size", "sensor",   # capture.json fields
                  "rms_px", "views": {shot: rms_px}, "rejected_views": [...],
                  "no_board": [...]}],
     "links": [{"from", "to", "shared_views", "rms_px"}]}

``R``, ``t`` map world to OpenCV camera coordinates (mm), the reference (first)
camera is the world frame. :func:`read_cameras` returns the entries as
:class:`~polarbssrdf.io.manifest.Camera` (the extra quality fields dropped), ready
for the ``cameras`` block of ``capture.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.manifest import Camera

from .board import BoardSpec
from .detect import IMAGE_SUFFIXES, Detection, detect_charuco, read_gray_image
from .geometry import RigCalibration

__all__ = ["CAMERAS_SCHEMA", "CAMERAS_SCHEMA_VERSION", "cameras_document", "detect_image_tree",
           "list_image_tree", "read_cameras", "write_cameras"]

CAMERAS_SCHEMA = "polarbssrdf.calibration.cameras"
CAMERAS_SCHEMA_VERSION = 1
_CAMERA_FIELDS = ("name", "K", "dist", "R", "t", "image_size", "sensor")


def list_image_tree(directory) -> dict[str, dict[str, Path]]:
    """``{camera: {shot: image path}}`` of ``DIR/<camera>/<shot>.<ext>``; clear errors otherwise."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"image directory not found: {directory}")
    tree: dict[str, dict[str, Path]] = {}
    for folder in sorted(p for p in directory.iterdir() if p.is_dir() and not p.name.startswith(".")):
        shots: dict[str, Path] = {}
        for path in sorted(folder.iterdir()):
            if not path.is_file() or path.suffix.lower() not in IMAGE_SUFFIXES:
                continue
            if path.stem in shots:
                raise ValueError(f"{folder}: two images for shot {path.stem!r}: "
                                 f"{shots[path.stem].name} and {path.name}")
            shots[path.stem] = path
        if shots:
            tree[folder.name] = shots
    if not tree:
        raise ValueError(f"{directory}: no camera folders with images "
                         f"({', '.join(IMAGE_SUFFIXES)}) -- expected DIR/<camera>/<shot>.<ext>")
    return tree


def detect_image_tree(directory, board: BoardSpec) -> dict[str, dict[str, Detection | None]]:
    """Detect the board in every image of the tree: ``{camera: {shot: Detection or None}}``.

    Raises ``ValueError`` when a camera's images differ in size (naming them)
    and when no image of a camera shows the board.
    """
    tree = list_image_tree(directory)
    result: dict[str, dict[str, Detection | None]] = {}
    for camera, shots in tree.items():
        detections: dict[str, Detection | None] = {}
        sizes: dict[tuple[int, int], list[str]] = {}
        for shot, path in shots.items():
            image = read_gray_image(path)
            sizes.setdefault((image.shape[1], image.shape[0]), []).append(path.name)
            detections[shot] = detect_charuco(image, board)
        if len(sizes) > 1:
            listing = "; ".join(f"{w} x {h}: {', '.join(names[:4])}" + (" ..." if len(names) > 4 else "")
                                for (w, h), names in sizes.items())
            raise ValueError(f"camera {camera}: images have inconsistent sizes (width x height) -- "
                             f"{listing}")
        if all(d is None for d in detections.values()):
            raise ValueError(f"camera {camera}: no ChArUco board ({board.squares_x} x "
                             f"{board.squares_y} squares, {board.dictionary}) found in any of its "
                             f"{len(shots)} image(s) -- check the board file and the images")
        result[camera] = detections
    return result


def cameras_document(rig: RigCalibration, board: BoardSpec,
                     detections: dict[str, dict[str, Detection | None]] | None = None) -> dict:
    """The JSON document of ``CAMERAS.json`` for a rig calibration."""
    entries = []
    for camera in rig.cameras:
        calibration = rig.intrinsics[camera.name]
        entry = camera.to_json()
        entry["rms_px"] = calibration.rms_px
        entry["views"] = calibration.view_rms_px
        entry["rejected_views"] = list(calibration.rejected)
        entry["no_board"] = sorted(shot for shot, d in (detections or {}).get(camera.name, {}).items()
                                   if d is None)
        entries.append(entry)
    model = next(iter(rig.intrinsics.values())).model if rig.intrinsics else "opencv"
    return {"schema": CAMERAS_SCHEMA, "schema_version": CAMERAS_SCHEMA_VERSION,
            "units": {"length": "mm"}, "board": board.to_json(), "model": model,
            "reference_camera": rig.cameras[0].name if rig.cameras else None,
            "cameras": entries, "links": rig.links}


def write_cameras(path, document: dict, *, overwrite: bool = False) -> Path:
    """Write ``CAMERAS.json`` atomically; refuses to replace a file unless ``overwrite``."""
    return atomic_write_text(path, json.dumps(document, indent=2) + "\n", overwrite=overwrite)


def read_cameras(path) -> list[Camera]:
    """The cameras of a ``CAMERAS.json`` as :class:`Camera` objects (validated)."""
    from polarbssrdf.io.jsonfile import read_json_file

    path = Path(path)
    data = read_json_file(path, "cameras file")
    if not isinstance(data, dict) or data.get("schema") != CAMERAS_SCHEMA:
        raise ValueError(f"{path}: not a cameras file (schema must be {CAMERAS_SCHEMA!r})")
    if data.get("schema_version") != CAMERAS_SCHEMA_VERSION:
        raise ValueError(f"{path}: unsupported schema_version {data.get('schema_version')!r} "
                         f"(this code reads {CAMERAS_SCHEMA_VERSION})")
    cameras = data.get("cameras")
    if not isinstance(cameras, list):
        raise ValueError(f"{path}: 'cameras' must be a list")
    result = []
    for i, entry in enumerate(cameras):
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: cameras[{i}] must be an object")
        fields = {key: entry[key] for key in _CAMERA_FIELDS if key in entry}
        result.append(Camera.from_json(fields, where=f"{path}: cameras[{i}]"))
    return result
