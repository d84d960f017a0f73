"""Render a ChArUco board with Mitsuba through a calibrated camera.

Checks the OpenCV -> Mitsuba camera conversion of
:func:`polarbssrdf.io.mitsuba_camera.mitsuba_sensor_dict` end to end: the
board is a ``rectangle`` carrying an ``area`` emitter whose radiance is the
board image (a ``bitmap`` texture, linear values in [0, 1]), in front of a
grey ``constant`` background; the camera is the calibrated
:class:`~polarbssrdf.io.manifest.Camera`. Detecting the board in the render
must give the corners that ``camera.project`` predicts.

Board placement: the rectangle's local ``[-1, 1]^2`` maps to the board frame
as ``X = W/2 (1 + x)``, ``Y = H/2 (1 - y)``, ``Z = -z``, so its emitting side
(local +z) faces the camera (board -z) and texture row 0 (``v = 0``, local
``y = -1``) is the board's bottom row: the image is flipped vertically before
upload.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.io.manifest import Camera

from .board import BoardSpec, board_image

__all__ = ["DEFAULT_VARIANT", "board_scene_dict", "render_board_mitsuba"]

DEFAULT_VARIANT = "llvm_ad_rgb"
"""Mitsuba variant used by :func:`render_board_mitsuba` when none is active."""


def board_scene_dict(board: BoardSpec, camera: Camera, board_to_world, *, px_per_mm: float = 8.0,
                     spp: int = 64, background: float = 0.35) -> dict:
    """A Mitsuba scene dict: the board (4 x 4 pose ``board_to_world``, mm) seen by ``camera``.

    Needs an active Mitsuba variant; ``spp`` must be a square (stratified sampler).
    """
    import mitsuba as mi

    from polarbssrdf.io.mitsuba_camera import mitsuba_sensor_dict

    width_mm, height_mm = board.size_mm
    placement = np.array([[width_mm / 2, 0.0, 0.0, width_mm / 2],
                          [0.0, -height_mm / 2, 0.0, height_mm / 2],
                          [0.0, 0.0, -1.0, 0.0],
                          [0.0, 0.0, 0.0, 1.0]])
    to_world = np.asarray(board_to_world, dtype=np.float64) @ placement
    texture = np.ascontiguousarray(np.flipud(board_image(board, px_per_mm)).astype(np.float32) / 255.0)
    bitmap = mi.Bitmap(texture[..., None], mi.Bitmap.PixelFormat.Y)
    return {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": mitsuba_sensor_dict(camera, spp, sampler="stratified"),
        "background": {"type": "constant", "radiance": {"type": "rgb", "value": background}},
        "board": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f(to_world.tolist()),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area",
                        "radiance": {"type": "bitmap", "bitmap": bitmap, "raw": True,
                                     "filter_type": "bilinear", "wrap_mode": "clamp"}},
        },
    }


def render_board_mitsuba(board: BoardSpec, camera: Camera, board_to_world, *, px_per_mm: float = 8.0,
                         spp: int = 64, variant: str | None = None) -> np.ndarray:
    """Grey uint8 image of the board rendered by Mitsuba with ``camera``.

    Parameters
    ----------
    board, camera, board_to_world:
        As in :func:`board_scene_dict`; ``camera`` must be a pinhole (``fx == fy``,
        no skew, no distortion).
    px_per_mm:
        Texture resolution.
    spp:
        Samples per pixel (a square: stratified sampling, box filter).
    variant:
        Mitsuba variant to switch to; default: keep the active one if it is an RGB
        variant, else :data:`DEFAULT_VARIANT`.
    """
    import mitsuba as mi

    active = mi.variant()
    if variant is not None:
        mi.set_variant(variant)
    elif active is None or not active.endswith("_rgb"):
        mi.set_variant(DEFAULT_VARIANT)
    scene = mi.load_dict(board_scene_dict(board, camera, board_to_world, px_per_mm=px_per_mm, spp=spp))
    image = np.asarray(mi.render(scene, seed=1), dtype=np.float32)
    gray = image.mean(axis=2) if image.ndim == 3 else image
    return np.clip(np.rint(gray * 255.0), 0, 255).astype(np.uint8)
