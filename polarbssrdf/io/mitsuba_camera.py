"""Capture cameras (OpenCV model) as Mitsuba ``perspective`` sensors, and back.

Pixel-centre convention
-----------------------
OpenCV puts the centre of pixel ``(column u, row v)`` at the integer
coordinates ``(u, v)``; Mitsuba's film puts it at ``(u + 0.5, v + 0.5)``
(pixel ``u`` covers ``[u, u + 1)``). The capture format uses OpenCV's
convention for ``K``, so a world point ``X`` lands, in the Mitsuba render, in
the pixel whose Mitsuba film coordinates are ``K (R X + t)`` (dehomogenized)
``+ 0.5``: pixel index ``round(u)``, ``round(v)``. The image centre of a
``W x H`` camera is ``((W - 1) / 2, (H - 1) / 2)`` in OpenCV coordinates.

Axes
----
OpenCV camera axes are x right, y down, z forward. Mitsuba's camera looks
along local +z with local +x to the *left* of the image and +y up, so
``camera-to-world = [R^T diag(-1, -1, 1) | -R^T t]`` (a proper rotation).

Mitsuba's ``principal_point_offset_x/y`` shift the sample position of every
ray by a fraction of the film width/height: the optical axis appears at film
fraction ``0.5 - offset``. Hence ``offset_x = 0.5 - (cx + 0.5) / W`` and
``offset_y = 0.5 - (cy + 0.5) / H``. The field of view is horizontal,
``fov_x = 2 atan(W / (2 fx))``; Mitsuba has square pixels, so ``fx`` must equal
``fy``, the skew must be zero and, since undistortion is out of scope, the
distortion coefficients must be zero.
"""

from __future__ import annotations

import math

import numpy as np

from polarbssrdf.io.manifest import Camera

__all__ = [
    "SQUARE_PIXEL_TOLERANCE",
    "camera_from_look_at",
    "camera_to_world",
    "look_at_parameters",
    "mitsuba_sensor_dict",
]

SQUARE_PIXEL_TOLERANCE = 1e-6
"""Largest relative difference ``|fx - fy| / fx`` Mitsuba's square pixels accept."""

_OPENCV_TO_MITSUBA_AXES = np.diag([-1.0, -1.0, 1.0])


def camera_to_world(camera: Camera) -> np.ndarray:
    """4 x 4 Mitsuba camera-to-world matrix (local +x image left, +y up, +z forward), mm."""
    matrix = np.eye(4)
    matrix[:3, :3] = camera.R.T @ _OPENCV_TO_MITSUBA_AXES
    matrix[:3, 3] = camera.center
    return matrix


def _check_pinhole(camera: Camera) -> None:
    if np.any(camera.dist != 0):
        raise ValueError(f"camera {camera.name!r} has non-zero distortion {camera.dist.tolist()}; "
                         "Mitsuba renders an ideal pinhole: undistort the images and set dist to "
                         "zeros (undistortion is not part of polarbssrdf)")
    if camera.K[0, 1] != 0:
        raise ValueError(f"camera {camera.name!r} has skew K[0, 1] = {camera.K[0, 1]:g}; "
                         "Mitsuba's perspective sensor has none")
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    if abs(fx - fy) > SQUARE_PIXEL_TOLERANCE * fx:
        raise ValueError(f"camera {camera.name!r} has fx = {fx:.9g} != fy = {fy:.9g}; Mitsuba's "
                         "perspective sensor has square pixels")


def mitsuba_sensor_dict(camera: Camera, spp: int = 16, *, sampler: str = "independent",
                        seed: int = 0, rfilter: str = "box", pixel_format: str | None = None,
                        film: dict | None = None, near_clip_mm: float = 1.0,
                        far_clip_mm: float = 1.0e6) -> dict:
    """A ``perspective`` sensor dict whose image matches the OpenCV projection of ``camera``.

    Needs an active Mitsuba variant (the transform is a ``mi.ScalarTransform4f``).

    Parameters
    ----------
    camera:
        The capture camera; distortion and skew must be zero and ``fx == fy``.
    spp:
        Samples per pixel.
    sampler, seed:
        Mitsuba sampler type and its seed.
    rfilter:
        Reconstruction filter; ``box`` keeps each pixel an average over its own area.
    pixel_format:
        ``hdrfilm`` pixel format (``rgb``, ``luminance``, ...); default ``luminance``
        in monochrome variants and ``rgb`` otherwise.
    film:
        Extra ``hdrfilm`` entries (override the ones above).
    near_clip_mm, far_clip_mm:
        Clip distances in mm.

    Raises
    ------
    ValueError
        Non-zero distortion or skew, non-square pixels, or no Mitsuba variant set.
    """
    import mitsuba as mi

    if mi.variant() is None:
        raise ValueError("mitsuba_sensor_dict needs an active Mitsuba variant (mi.set_variant)")
    _check_pinhole(camera)
    width, height = camera.image_size
    fx, cx, cy = camera.K[0, 0], camera.K[0, 2], camera.K[1, 2]
    if pixel_format is None:
        pixel_format = "luminance" if mi.is_monochromatic else "rgb"
    film_dict = {"type": "hdrfilm", "width": width, "height": height,
                 "rfilter": {"type": rfilter}, "pixel_format": pixel_format}
    film_dict.update(film or {})
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(width / (2.0 * fx))),
        "principal_point_offset_x": 0.5 - (cx + 0.5) / width,
        "principal_point_offset_y": 0.5 - (cy + 0.5) / height,
        "near_clip": float(near_clip_mm),
        "far_clip": float(far_clip_mm),
        "to_world": mi.ScalarTransform4f(camera_to_world(camera).tolist()),
        "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)},
        "film": film_dict,
    }


def _unit(vector, what: str) -> np.ndarray:
    vector = np.asarray(vector, dtype=np.float64)
    norm = np.linalg.norm(vector)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)) or norm == 0:
        raise ValueError(f"{what} must be a finite non-zero 3-vector, got {vector.tolist()}")
    return vector / norm


def camera_from_look_at(origin, target, up, fov_x_deg: float, image_size, *, name: str = "cam00",
                        sensor: str = "ideal", principal_point=None) -> Camera:
    """A distortion-free :class:`Camera` from Mitsuba-style look-at parameters.

    Parameters
    ----------
    origin, target:
        Camera centre and a point on the optical axis, world mm.
    up:
        World direction that appears up in the image (need not be orthogonal
        to the view direction, must not be parallel to it).
    fov_x_deg:
        Horizontal field of view in degrees, in (0, 180).
    image_size:
        ``(width, height)`` in pixels.
    name, sensor:
        Camera name and sensor (``ideal``, ``IMX250MZR``, ``IMX250MYR``).
    principal_point:
        ``(cx, cy)`` in OpenCV pixels; default the image centre
        ``((W - 1) / 2, (H - 1) / 2)``.

    Returns
    -------
    Camera
        ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` with ``f = W / (2 tan(fov_x / 2))``;
        its :func:`mitsuba_sensor_dict` equals Mitsuba's ``look_at`` camera.
    """
    if not 0.0 < float(fov_x_deg) < 180.0:
        raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
    origin = np.asarray(origin, dtype=np.float64)
    forward = _unit(np.asarray(target, dtype=np.float64) - origin, "target - origin")
    right = np.cross(forward, _unit(up, "up"))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("up must not be parallel to the viewing direction target - origin")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    width, height = (int(size) for size in image_size)
    focal = width / (2.0 * math.tan(math.radians(fov_x_deg) / 2.0))
    cx, cy = ((width - 1) / 2.0, (height - 1) / 2.0) if principal_point is None \
        else (float(principal_point[0]), float(principal_point[1]))
    K = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
    return Camera(name, K, np.zeros(5), rotation, -rotation @ origin, (width, height), sensor)


def look_at_parameters(camera: Camera, distance_mm: float = 1.0):
    """``(origin, target, up, fov_x_deg)`` that :func:`camera_from_look_at` turns back into
    ``camera``'s pose and horizontal field of view (target ``distance_mm`` ahead)."""
    fov_x_deg = math.degrees(2.0 * math.atan(camera.width / (2.0 * camera.K[0, 0])))
    origin = camera.center
    return origin, origin + distance_mm * camera.forward, -camera.down, fov_x_deg
