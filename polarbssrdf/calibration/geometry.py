"""Camera intrinsics and rig extrinsics from ChArUco detections (OpenCV).

Single camera: Zhang's method (Z. Zhang, "A flexible new technique for camera
calibration", IEEE TPAMI 2000) as implemented by ``cv2.calibrateCamera``,
minimizing the reprojection error of the ChArUco corners.

Outlier rule (:func:`calibrate_camera`): after each calibration the RMS
reprojection error of every view is computed; the worst view is rejected if
its RMS exceeds ``max(outlier_factor x median view RMS, outlier_floor_px)``
(defaults 3 and 1 px), and the camera is calibrated again, until no view
exceeds the threshold or only ``min_views`` views are left.

Rig: each camera is calibrated alone, then cameras are linked along a
maximum spanning tree of the "shared views" graph (the weight of a pair is
the number of shots both cameras saw the board in), starting at the
reference camera (the world frame). Each tree edge is solved with
``cv2.stereoCalibrate`` with fixed intrinsics, and poses are chained
through the tree: if ``X_c = R_pc X_p + T_pc`` and world -> p is
``(R_p, t_p)`` then world -> c is ``(R_pc R_p, R_pc t_p + T_pc)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from polarbssrdf.io.manifest import Camera

from .board import BoardSpec, _cv2
from .detect import MIN_CORNERS, Detection

__all__ = [
    "CAMERA_MODELS",
    "MIN_VIEWS",
    "CameraCalibration",
    "RigCalibration",
    "calibrate_camera",
    "calibrate_rig",
    "relative_pose_error",
]

MIN_VIEWS = 4
"""Fewest views with a detected board a camera needs (after outlier rejection)."""

CAMERA_MODELS = ("opencv", "pinhole")
"""``opencv``: fx, fy, cx, cy and distortion k1, k2, p1, p2, k3. ``pinhole``:
square pixels (fx = fy), no skew, no distortion -- what a Mitsuba
``perspective`` sensor can represent (see :mod:`polarbssrdf.io.mitsuba_camera`)."""


@dataclass
class CameraCalibration:
    """Result of :func:`calibrate_camera` (pixels; board poses in mm).

    Attributes
    ----------
    K, dist:
        3 x 3 intrinsics and the 5 OpenCV distortion coefficients.
    image_size:
        ``(width, height)``.
    rms_px:
        RMS reprojection error over all corners of the kept views.
    views:
        Names of the kept views, in the order of ``board_poses``.
    board_poses:
        ``{view: 4 x 4 board -> camera transform}`` of the kept views.
    view_rms_px:
        RMS reprojection error of *every* view with a board (kept and rejected),
        evaluated with the final intrinsics (rejected views: pose by ``solvePnP``).
    rejected:
        Views rejected as outliers, in rejection order.
    model:
        One of :data:`CAMERA_MODELS`.
    """

    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    rms_px: float
    views: list[str]
    board_poses: dict[str, np.ndarray]
    view_rms_px: dict[str, float]
    rejected: list[str] = field(default_factory=list)
    model: str = "opencv"


@dataclass
class RigCalibration:
    """Result of :func:`calibrate_rig`.

    Attributes
    ----------
    cameras:
        :class:`~polarbssrdf.io.manifest.Camera` per camera, world = reference camera.
    intrinsics:
        ``{camera name: CameraCalibration}``.
    links:
        One record per spanning-tree edge: ``{"from", "to", "shared_views", "rms_px"}``.
    """

    cameras: list[Camera]
    intrinsics: dict[str, CameraCalibration]
    links: list[dict]


def _pose_matrix(rvec, tvec) -> np.ndarray:
    cv2 = _cv2()
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    pose[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    return pose


def _view_rms(object_points, image_points, rvec, tvec, K, dist) -> float:
    cv2 = _cv2()
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, K, dist)
    residual = projected.reshape(-1, 2) - image_points.reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))


def _flags(model: str):
    cv2 = _cv2()
    if model == "opencv":
        return 0
    if model == "pinhole":
        return (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1
                | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    raise ValueError(f"unknown camera model {model!r} (known: {', '.join(CAMERA_MODELS)})")


def _check_image_sizes(detections: dict[str, Detection], what: str) -> tuple[int, int]:
    sizes: dict[tuple[int, int], list[str]] = {}
    for view, detection in detections.items():
        sizes.setdefault(tuple(detection.image_size), []).append(view)
    if len(sizes) > 1:
        listing = "; ".join(f"{w} x {h}: {', '.join(sorted(views)[:4])}"
                            + (" ..." if len(views) > 4 else "")
                            for (w, h), views in sorted(sizes.items(), key=lambda s: -len(s[1])))
        raise ValueError(f"{what}: images have inconsistent sizes (width x height) -- {listing}")
    return next(iter(sizes))


def _run_calibration(board, detections, views, image_size, model):
    cv2 = _cv2()
    objects = [detections[v].object_points(board).astype(np.float32) for v in views]
    images = [detections[v].corners_px.astype(np.float32).reshape(-1, 1, 2) for v in views]
    K0 = np.eye(3)
    dist0 = np.zeros(5)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, image_size, K0, dist0,
                                                     flags=_flags(model), criteria=criteria)
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).reshape(-1)[:5]
    if model == "pinhole":
        K[1, 1] = K[0, 0]
        dist = np.zeros(5)
    K[0, 1] = 0.0
    poses = {v: _pose_matrix(r, t) for v, r, t in zip(views, rvecs, tvecs)}
    per_view = {v: _view_rms(o, i, r, t, K, dist)
                for v, o, i, r, t in zip(views, objects, images, rvecs, tvecs)}
    return float(rms), K, dist, poses, per_view


def calibrate_camera(detections: dict[str, Detection], board: BoardSpec, *, model: str = "opencv",
                     min_views: int = MIN_VIEWS, outlier_factor: float = 3.0,
                     outlier_floor_px: float = 1.0, name: str = "camera") -> CameraCalibration:
    """Calibrate one camera from its ChArUco detections (``cv2.calibrateCamera``, Zhang 2000).

    Parameters
    ----------
    detections:
        ``{view name: Detection}``; views without a board are left out by the caller
        (``None`` values are ignored).
    board:
        The board seen.
    model:
        ``opencv`` or ``pinhole`` (see :data:`CAMERA_MODELS`).
    min_views:
        Fewest usable views; fewer raise ``ValueError``.
    outlier_factor, outlier_floor_px:
        The rejection rule of this module's docstring.
    name:
        Used in error messages.

    Returns
    -------
    CameraCalibration

    Raises
    ------
    ValueError
        Too few views, inconsistent image sizes, unknown model.
    """
    cv2 = _cv2()
    _flags(model)
    usable = {v: d for v, d in detections.items() if d is not None and len(d.ids) >= MIN_CORNERS}
    if len(usable) < min_views:
        raise ValueError(f"camera {name}: too few views with a detected board: {len(usable)} "
                         f"(need at least {min_views}; each with >= {MIN_CORNERS} ChArUco corners)")
    image_size = _check_image_sizes(usable, f"camera {name}")
    views = sorted(usable)
    rejected: list[str] = []
    while True:
        rms, K, dist, poses, per_view = _run_calibration(board, usable, views, image_size, model)
        threshold = max(outlier_factor * float(np.median(list(per_view.values()))), outlier_floor_px)
        worst = max(views, key=per_view.get)
        if per_view[worst] <= threshold or len(views) <= min_views:
            break
        views = [v for v in views if v != worst]
        rejected.append(worst)
    view_rms = dict(per_view)
    for view in rejected:
        detection = usable[view]
        objects = detection.object_points(board)
        ok, rvec, tvec = cv2.solvePnP(objects, detection.corners_px, K, dist)
        view_rms[view] = (_view_rms(objects, detection.corners_px, rvec, tvec, K, dist)
                          if ok else float("inf"))
    return CameraCalibration(K, dist, image_size, rms, views, poses,
                             {v: view_rms[v] for v in sorted(view_rms)}, rejected, model)


def _common_points(board, first: Detection, second: Detection):
    ids = np.intersect1d(first.ids, second.ids)
    if len(ids) < MIN_CORNERS:
        return None
    a = first.corners_px[np.searchsorted(first.ids, ids)]
    b = second.corners_px[np.searchsorted(second.ids, ids)]
    return board.corner_points_mm()[ids], a, b


def _stereo(board, det_p, det_c, cal_p, cal_c, shots):
    """``(R, T, rms)`` with ``X_c = R X_p + T`` from the shots both cameras kept."""
    cv2 = _cv2()
    objects, points_p, points_c = [], [], []
    for shot in shots:
        common = _common_points(board, det_p[shot], det_c[shot])
        if common is None:
            continue
        objects.append(common[0].astype(np.float32))
        points_p.append(common[1].astype(np.float32).reshape(-1, 1, 2))
        points_c.append(common[2].astype(np.float32).reshape(-1, 1, 2))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    result = cv2.stereoCalibrate(objects, points_p, points_c, cal_p.K, cal_p.dist, cal_c.K,
                                 cal_c.dist, cal_p.image_size, flags=cv2.CALIB_FIX_INTRINSIC,
                                 criteria=criteria)
    rms, R, T = result[0], result[5], result[6]
    return np.asarray(R, dtype=np.float64), np.asarray(T, dtype=np.float64).reshape(3), float(rms), \
        len(objects)


def calibrate_rig(detections: dict[str, dict[str, Detection | None]], board: BoardSpec, *,
                  reference: str | None = None, model: str = "opencv", sensor: str = "ideal",
                  min_views: int = MIN_VIEWS, outlier_factor: float = 3.0,
                  outlier_floor_px: float = 1.0) -> RigCalibration:
    """Calibrate several cameras and their poses in the reference camera's frame.

    Parameters
    ----------
    detections:
        ``{camera name: {shot name: Detection or None}}``; the same shot name
        in several cameras is one simultaneous view of the board.
    board:
        The board.
    reference:
        Camera whose frame is the world (default: the first camera in sorted order).
    model, sensor:
        Camera model (:data:`CAMERA_MODELS`) and the ``sensor`` written into each
        :class:`~polarbssrdf.io.manifest.Camera`.
    min_views, outlier_factor, outlier_floor_px:
        As in :func:`calibrate_camera`.

    Returns
    -------
    RigCalibration
        Reference camera first (``R = I``, ``t = 0``), then the others in sorted name order;
        world -> camera ``R``, ``t`` in mm.

    Raises
    ------
    ValueError
        A camera with too few views, or one that shares no view with the others.
    """
    names = sorted(detections)
    if not names:
        raise ValueError("no cameras to calibrate")
    reference = names[0] if reference is None else reference
    if reference not in detections:
        raise ValueError(f"reference camera {reference!r} not among {', '.join(names)}")
    intrinsics = {name: calibrate_camera(detections[name], board, model=model, min_views=min_views,
                                         outlier_factor=outlier_factor,
                                         outlier_floor_px=outlier_floor_px, name=name)
                  for name in names}

    def shared(a, b):
        kept_b = set(intrinsics[b].views)
        return [s for s in intrinsics[a].views if s in kept_b
                and _common_points(board, detections[a][s], detections[b][s]) is not None]

    # Prim's maximum spanning tree from the reference camera.
    poses = {reference: (np.eye(3), np.zeros(3))}
    links = []
    while len(poses) < len(names):
        best = None
        for parent in poses:
            for child in names:
                if child in poses:
                    continue
                shots = shared(parent, child)
                if len(shots) >= 1 and (best is None or len(shots) > len(best[2])):
                    best = (parent, child, shots)
        if best is None:
            lonely = [n for n in names if n not in poses]
            raise ValueError(f"camera(s) {', '.join(lonely)} share no view of the board (same shot "
                             f"name, >= {MIN_CORNERS} common corners) with {', '.join(sorted(poses))}")
        parent, child, shots = best
        R, T, rms, count = _stereo(board, detections[parent], detections[child],
                                   intrinsics[parent], intrinsics[child], shots)
        R_p, t_p = poses[parent]
        rotation = R @ R_p
        # re-orthonormalize against round-off before the strict Camera check
        u, _, vt = np.linalg.svd(rotation)
        poses[child] = (u @ vt, R @ t_p + T)
        links.append({"from": parent, "to": child, "shared_views": count, "rms_px": rms})
    order = [reference] + [name for name in names if name != reference]
    cameras = [Camera(name, intrinsics[name].K, intrinsics[name].dist, poses[name][0], poses[name][1],
                      intrinsics[name].image_size, sensor) for name in order]
    return RigCalibration(cameras, intrinsics, links)


def relative_pose_error(estimate_a: Camera, estimate_b: Camera, truth_a: Camera, truth_b: Camera
                        ) -> tuple[float, float]:
    """Rotation (degrees) and translation (mm) error of the pose of b relative to a."""
    def relative(a, b):
        R = b.R @ a.R.T
        return R, b.t - R @ a.t

    R_e, t_e = relative(estimate_a, estimate_b)
    R_t, t_t = relative(truth_a, truth_b)
    cos = (np.trace(R_e @ R_t.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))), float(np.linalg.norm(t_e - t_t))
