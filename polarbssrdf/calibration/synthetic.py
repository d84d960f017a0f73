"""Synthetic ChArUco views: a printed board seen through a known OpenCV camera.

Each output pixel (sampled ``supersample`` x ``supersample`` times, then
box-averaged) casts its ray through the camera model (distortion inverted
iteratively, :meth:`Camera.normalized_rays`), intersects the board plane and
looks the board image up bilinearly; optional Gaussian blur and noise
imitate optics and sensor. Used by the tests and to check a calibration
pipeline end to end.
"""

from __future__ import annotations

import math

import numpy as np

from polarbssrdf.io.manifest import Camera

from .board import BoardSpec, _cv2, board_image

__all__ = ["board_pose_in_camera", "random_board_poses", "render_board_view", "rotation_xyz",
           "synthetic_detections"]


def rotation_xyz(angles_deg) -> np.ndarray:
    """Rotation ``Rz @ Ry @ Rx`` from angles (degrees) about x, y, z."""
    ax, ay, az = (math.radians(a) for a in angles_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def board_pose_in_camera(board: BoardSpec, center_mm, angles_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4 x 4 board -> camera transform (mm) placing the board's centre at ``center_mm``.

    With zero angles the board faces the camera upright (board x = image right,
    y = image down); ``angles_deg`` rotate it about its centre (x, y, z axes).
    """
    rotation = rotation_xyz(angles_deg)
    width, height = board.size_mm
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = np.asarray(center_mm, dtype=np.float64) - rotation @ np.array([width / 2, height / 2, 0.0])
    return pose


def _pixel_rays(camera: Camera, supersample: int) -> np.ndarray:
    """Normalized camera-frame ray directions ``(x, y)`` (z = 1) of all sub-pixel samples."""
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.image_size, supersample)
    if key not in _RAY_CACHE:
        if len(_RAY_CACHE) >= 8:
            _RAY_CACHE.pop(next(iter(_RAY_CACHE)))
        _RAY_CACHE[key] = _compute_pixel_rays(camera, supersample)
    return _RAY_CACHE[key]


_RAY_CACHE: dict = {}
"""Rays of the last few camera models (views of one camera share them)."""


def _compute_pixel_rays(camera: Camera, supersample: int) -> np.ndarray:
    width, height = camera.image_size
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    u = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1)
    v = (np.arange(height)[:, None] + offsets[None, :]).reshape(-1)
    uu, vv = np.meshgrid(u, v)
    return camera.normalized_rays(uu, vv)


def render_board_view(board: BoardSpec, camera: Camera, board_to_world, *, supersample: int = 2,
                      px_per_mm: float = 8.0, background: float = 90.0, blur_sigma_px: float = 0.0,
                      noise_dn: float = 0.0, rng=None) -> np.ndarray:
    """Grey uint8 image of ``board`` (pose ``board_to_world``, 4 x 4, mm) seen by ``camera``.

    Parameters
    ----------
    board, camera:
        The board and the camera (K, distortion, world -> camera R, t).
    board_to_world:
        4 x 4 board-frame -> world transform (mm).
    supersample:
        Sub-pixel samples per axis (box filter).
    px_per_mm:
        Resolution of the board texture.
    background:
        Grey level (0-255) where the ray misses the board or hits its back.
    blur_sigma_px, noise_dn:
        Gaussian blur (px) and additive Gaussian noise (digital numbers).
    rng:
        ``numpy.random.Generator`` for the noise.
    """
    cv2 = _cv2()
    pose = np.asarray(board_to_world, dtype=np.float64)
    texture = board_image(board, px_per_mm).astype(np.float32)
    # board -> camera
    rotation = camera.R @ pose[:3, :3]
    translation = camera.R @ pose[:3, 3] + camera.t
    normal = rotation[:, 2]
    rays = _pixel_rays(camera, supersample)
    directions = np.concatenate([rays, np.ones(rays.shape[:-1] + (1,))], axis=-1)
    # ray X = s d meets the plane n . (X - translation) = 0
    denominator = directions @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (normal @ translation) / denominator
    points = s[..., None] * directions - translation
    board_xy = points @ rotation[:, :2]          # board-frame (X, Y) in mm
    valid = (s > 0) & np.isfinite(s) & (denominator > 0)   # printed side faces the camera
    map_x = np.where(valid, board_xy[..., 0] * px_per_mm - 0.5, -10.0).astype(np.float32)
    map_y = np.where(valid, board_xy[..., 1] * px_per_mm - 0.5, -10.0).astype(np.float32)
    fine = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float(background))
    width, height = camera.image_size
    image = fine.reshape(height, supersample, width, supersample).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
    if noise_dn > 0:
        rng = np.random.default_rng() if rng is None else rng
        image = image + rng.normal(0.0, noise_dn, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def random_board_poses(board: BoardSpec, count: int, rng, *, distance_mm=(430.0, 560.0),
                       tilt_deg: float = 32.0, offset_mm=(50.0, 35.0)) -> list[np.ndarray]:
    """``count`` board -> camera poses (4 x 4, mm) for a calibration sequence.

    The board centre lies within ``offset_mm`` (x, y) of the optical axis at a depth drawn
    from ``distance_mm``; it is tilted about its x and y axes by up to ``tilt_deg`` and
    rolled by up to 15 degrees. ``rng`` is a ``numpy.random.Generator`` or a seed.
    """
    rng = np.random.default_rng(rng)
    poses = []
    for _ in range(count):
        angles = (rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-tilt_deg, tilt_deg),
                  rng.uniform(-15.0, 15.0))
        centre = (rng.uniform(-offset_mm[0], offset_mm[0]), rng.uniform(-offset_mm[1], offset_mm[1]),
                  rng.uniform(*distance_mm))
        poses.append(board_pose_in_camera(board, centre, angles))
    return poses


def synthetic_detections(board: BoardSpec, camera: Camera, poses, rng, *, blur_sigma_px: float = 0.6,
                         noise_dn: float = 2.0) -> dict:
    """``{"shot00": Detection or None, ...}``: the board at each pose (board -> world) seen by
    ``camera``, rendered by :func:`render_board_view` and detected."""
    from .detect import detect_charuco

    rng = np.random.default_rng(rng)
    detections = {}
    for i, pose in enumerate(poses):
        image = render_board_view(board, camera, pose, blur_sigma_px=blur_sigma_px, noise_dn=noise_dn,
                                  rng=rng)
        detections[f"shot{i:02d}"] = detect_charuco(image, board)
    return detections
