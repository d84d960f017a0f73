"""Texture-space observations: every visible (texel, view) pair of one frame, on disk.

For one frame of a capture and a ``T x T`` texel atlas of its mesh, each image
(one camera with one light) contributes a *texel-view* for every texel that

* lies on the mesh (the atlas says the texel centre is valid),
* faces the camera and the light: ``cos(normal, to_camera) > min_cosine`` and
  ``cos(normal, to_light) > min_cosine``,
* sees both unoccluded (Mitsuba ``ray_test`` on a scene of the mesh alone,
  rays leaving a small offset along the normal, relative to the mesh size),
* projects (OpenCV model with distortion, :meth:`Camera.project` of the
  world position; pixel centres at integers) inside the image with a
  1-pixel margin,
* samples only pixels that see the mesh alone, evenly lit
  (:func:`mixed_pixels`): a pixel whose area reaches past the mesh's outline,
  straddles an occluding contour or a shadow's edge holds light the
  per-texel model does not describe (the black background around synth's face mask made rim
  texel-views 11% darker on average, and the fit bent the relief to explain
  them), and
* has finite analyser samples in every band (NaN pixels drop only the
  texel-views that touch them; the count is kept in the store's statistics).

A texel-view keeps its geometry in OBJECT space (the atlas frame, ``world =
pose @ object``): directions to the camera and the light, the light's
distance, intensity and field direction at the texel (``ppoint``'s model),
the image's Stokes x axis for the ray, and the four analyser samples per band
(bilinear at the projected texel centre). Analyser samples are radiance,
W/(sr mm^2), for both image kinds: ``raw`` images are first converted from
digital numbers with their record's calibration, ``radiance = (DN -
black_level_dn) * radiance_per_dn[band]`` (``docs/capture_format.md``), pixels
at or above ``saturation_dn`` becoming NaN (so, like NaN pixels, they drop only
the texel-views they reach), and then demosaicked with the
residual-interpolation demosaicker
(:func:`polarbssrdf.capture.demosaic_residual`). Converting first matters for
the black level (the demosaicker is scale- but not offset-invariant: its
guided-filter regularization is relative to the image's mean). A raw record
without ``radiance_per_dn`` (captures written before the format had it) is
refused with an :class:`ObservationError`: its DN cannot be compared with
predicted radiance.

Storage: a zarr v3 group chunked by texel block (see
:mod:`polarbssrdf.inverse.observations.store` for the layout and why zarr).
The build never holds all views in memory: pass 1 writes each view's
texel-views, sorted by block, as one packed array into a temporary group
(``<path>.partial``); pass 2 merges one strip (a run of consecutive blocks
holding about :data:`STRIP_ROWS` texel-views) at a time across views into
the final arrays. Peak memory is one view's texel-views plus a few copies of
one strip, plus the atlas' positions and normals and one image's channels. The store is built under
``<path>.building`` and renamed at the end, so the final name only ever holds
a complete store.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import sys
from pathlib import Path

import mitsuba as mi
import numpy as np
from scipy.ndimage import binary_dilation
from tqdm import tqdm

from polarbssrdf._arrays import to_jit
from polarbssrdf.capture import channel_name, demosaic_residual
from polarbssrdf.geometry.atlas import texel_atlas
from polarbssrdf.geometry.mesh import to_mitsuba
from polarbssrdf.inverse.observations.store import (
    FIELDS,
    FORMAT_VERSION,
    ROWS_PER_CHUNK,
    ChunkedAppender,
    ObservationStore,
    TexelViews,
    block_of_texel,
    compressor,
    create_field_arrays,
    field_shape,
)
from polarbssrdf.io.capture import MANIFEST_NAME, Capture, check_image_channels, load_capture
from polarbssrdf.io.exr import read_exr
from polarbssrdf.io.identity import DIGEST_NAME, file_digest
from polarbssrdf.variants import ensure_jit_variant

__all__ = [
    "ObservationError",
    "ObservationStore",
    "TexelViews",
    "build_observations",
    "camera_stokes_x_axis",
    "demosaicked_analyser",
    "load_or_build_observations",
    "observation_fingerprint",
    "polarization_field",
    "rig_in_object_space",
]

logger = logging.getLogger(__name__)

SHADOW_EPSILON_RELATIVE = 1e-4
"""Ray origins leave the surface by this fraction of the mesh's bounding-box diagonal
(0.02 mm on a 60 mm sphere): far above float32 rounding, far below a texel."""

IMAGE_MARGIN_PX = 1.0
"""Projections closer than this to the image border are dropped (border pixels are the
least reliable after demosaicking, and the bilinear stencil must stay inside)."""

TEXELS_PER_CHUNK = 1 << 18
"""Texels evaluated together per view: bounds the temporaries of one view's evaluation."""

STRIP_ROWS = 1 << 19
"""Texel-views merged together in pass 2 (about 80 MB per copy with 6 bands): few reads of
each view's partial array, bounded memory."""

ANALYSER_ANGLES = (0, 45, 90, 135)

CORNER_OFFSET_PX = 0.0137
"""Pixel-corner rays leave the exact half-integers by this much: a principal point at a
half-integer puts a row and a column of corners on the mesh's symmetry planes, where its
edges lie and a ray can slip between two triangles (seen on the test sphere's meridian)."""

MIXED_DEPTH_SLACK = 2.0
"""A pixel straddles an occluding contour when its corners' ray depths spread by more than
this many times the most a surface kept by ``min_cosine`` can slope across one pixel."""


class ObservationError(ValueError):
    """The capture cannot give observations (missing polarization images, mesh, views...)."""

# --------------------------------------------------------------------------- geometry helpers
def _unit(vectors: np.ndarray) -> np.ndarray:
    """Rows of ``vectors`` scaled to unit length (zero rows stay zero)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.maximum(norm, 1e-30)


def rig_in_object_space(pose, camera, light) -> dict[str, np.ndarray]:
    """A camera and a light moved into the object (atlas) frame of a posed frame.

    Parameters
    ----------
    pose : (4, 4) array
        The frame's rigid object -> world transform (mm).
    camera : Camera
    light : Light

    Returns
    -------
    dict
        ``camera_centre`` (mm), ``camera_down`` (unit), ``light_position`` (mm),
        ``polarization_axis`` (unit) and ``polarizer_normal`` (unit, or None),
        all in object space: points through ``pose^-1``, directions through
        its rotation's transpose.
    """
    pose = np.asarray(pose, dtype=np.float64)
    rotation, translation = pose[:3, :3], pose[:3, 3]

    def point(world):
        return rotation.T @ (np.asarray(world, dtype=np.float64) - translation)

    def direction(world):
        vector = rotation.T @ np.asarray(world, dtype=np.float64)
        return vector / np.linalg.norm(vector)

    return {"camera_centre": point(camera.center),
            "camera_down": direction(camera.down),
            "light_position": point(light.position),
            "polarization_axis": direction(light.polarization_axis),
            "polarizer_normal": (None if light.polarizer_normal is None
                                 else direction(light.polarizer_normal))}


def polarization_field(forward, axis, polarizer_normal=None) -> np.ndarray:
    """Unit field direction of light travelling along ``forward`` (N x 3) behind a polarizer.

    The NumPy twin of :func:`polarbssrdf.plugins.ppoint.polarization_direction`:
    the projection model (``axis`` made perpendicular to ``forward``) or, with
    ``polarizer_normal``, the dichroic sheet with absorption axis
    ``b = normalize(polarizer_normal x axis)`` and field ``normalize(forward x b)``.
    ``axis`` and ``polarizer_normal`` are unit 3-vectors.
    """
    forward = np.asarray(forward, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64)
    if polarizer_normal is None:
        field = axis[None, :] - np.sum(forward * axis, axis=1, keepdims=True) * forward
    else:
        absorption = np.cross(np.asarray(polarizer_normal, dtype=np.float64), axis)
        absorption /= np.linalg.norm(absorption)
        field = np.cross(forward, absorption[None, :])
    return _unit(field)


def camera_stokes_x_axis(ray_direction, camera_up) -> np.ndarray:
    """Unit Stokes x axis of an image ray: ``normalize(ray_direction x camera_up)``.

    This is Mitsuba's ``stokes`` sensor frame (x = image right, y = image up);
    ``ray_direction`` (N x 3) goes from the camera to the surface.
    """
    return _unit(np.cross(np.asarray(ray_direction, dtype=np.float64),
                          np.asarray(camera_up, dtype=np.float64)[None, :]))


def project_to_image(camera, world_points) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV pixel ``(u, v)`` of world points (mm) and whether each lies in front of the camera."""
    world_points = np.asarray(world_points, dtype=np.float64)
    depth = world_points @ camera.R[2] + camera.t[2]
    return camera.project(world_points), depth > 0


def bilinear_samples(images, u, v) -> np.ndarray:
    """Bilinear samples of several same-size images at pixel coordinates.

    Parameters
    ----------
    images : list of (H, W) arrays
    u, v : (M,) arrays
        Column and row, pixel centres at integers; the 2 x 2 stencil
        ``floor(u)..floor(u)+1`` x ``floor(v)..floor(v)+1`` must lie inside.

    Returns
    -------
    (M, len(images)) float32; NaN where a stencil pixel with non-zero weight
    (or any, at exact integers: ``0 * NaN`` is NaN) is not finite.
    """
    column, row = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - column, v - row
    width = images[0].shape[1]
    top_left = row * width + column
    # the four stencil pixels as flat indices and their weights, shared by all images
    corners = (top_left, top_left + 1, top_left + width, top_left + width + 1)
    weights = ((1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv)
    samples = np.empty((len(u), len(images)), dtype=np.float32)
    for c, image in enumerate(images):
        flat = image.reshape(-1)
        samples[:, c] = sum(w * flat[i].astype(np.float64) for w, i in zip(weights, corners))
    return samples


def pixel_corner_rays(camera, pose) -> tuple[np.ndarray, np.ndarray]:
    """Object-space rays through the corners of every pixel of ``camera``.

    Pixel centres are at integers, so the ``(H + 1) x (W + 1)`` corners lie at
    half-integers from ``-0.5`` to ``W - 0.5`` (``H - 0.5``), moved by
    :data:`CORNER_OFFSET_PX`. Lens distortion is inverted by
    :meth:`Camera.normalized_rays`.

    Returns
    -------
    origin : (3,) float64
        The centre of projection in object space (mm).
    directions : (H + 1, W + 1, 3) float64
        Unit directions in object space.
    """
    width, height = camera.image_size
    u, v = np.meshgrid(np.arange(width + 1) - 0.5 + CORNER_OFFSET_PX,
                       np.arange(height + 1) - 0.5 + CORNER_OFFSET_PX)
    normalized = camera.normalized_rays(u, v).reshape(-1, 2)
    camera_rays = np.concatenate([normalized, np.ones((len(normalized), 1))], axis=1)
    pose = np.asarray(pose, dtype=np.float64)
    # camera -> world is R^T, world -> object the pose rotation's transpose
    directions = camera_rays @ camera.R @ pose[:3, :3]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    origin = pose[:3, :3].T @ (camera.center - pose[:3, 3])
    return origin, directions.reshape(height + 1, width + 1, 3)


def mixed_pixels(surface, camera, pose, min_cosine, light_position=None) -> np.ndarray:
    """(H, W) bool: pixels whose area does not see one continuous, evenly lit piece of the mesh.

    A pixel is *mixed* when a ray through one of its four corners misses the
    mesh (its area reaches past the outline: in synth the background is
    black, in a real capture it is hair, an ear or the room), or when the
    corners' hit distances spread by more than
    ``MIXED_DEPTH_SLACK * t * tan(theta_max) / f``: the most a surface that
    ``min_cosine`` keeps (``cos theta > min_cosine``) can recede across one
    pixel of angular size ``1 / f`` at distance ``t``, twice (an occluding
    contour, such as the nose's side over the cheek, jumps by far more).
    With ``light_position`` (object space, mm) a pixel is also mixed when its
    corners see the mesh but some of them lie in the light's shadow and some
    do not: a shadow's edge crosses it (the texel-view's own shadow test looks
    at its centre only). Texel-views whose bilinear stencil touches a mixed
    pixel are dropped.
    """

    origin, directions = pixel_corner_rays(camera, pose)
    shape = directions.shape[:2]
    flat = directions.reshape(-1, 3)
    rays = mi.Ray3f(mi.Point3f(np.broadcast_to(origin, flat.shape).T.astype(np.float32)),
                    mi.Vector3f(flat.T.astype(np.float32)))
    intersection = surface.scene.ray_intersect(rays)
    hit = np.array(intersection.is_valid(), dtype=bool).reshape(shape)
    distance = np.where(hit, np.array(intersection.t, dtype=np.float64).reshape(shape), np.inf)
    corners = np.stack([distance[:-1, :-1], distance[:-1, 1:], distance[1:, :-1],
                        distance[1:, 1:]])
    nearest, farthest = corners.min(axis=0), corners.max(axis=0)
    cosine = max(float(min_cosine), 0.05)
    steepest = np.sqrt(1.0 - cosine * cosine) / cosine
    focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    with np.errstate(invalid="ignore"):
        contour = (farthest - nearest) > MIXED_DEPTH_SLACK * nearest * steepest / focal
    mixed = ~np.isfinite(farthest) | contour
    if light_position is not None and hit.any():
        shadowed = np.zeros(shape, bool)
        # back off toward the camera, which sees the point: above the surface, below a texel
        points = origin + flat[hit.ravel()] * (distance[hit] - surface.epsilon_mm)[:, None]
        shadowed[hit] = surface.occluded(points, np.broadcast_to(light_position, points.shape))
        corners = np.stack([shadowed[:-1, :-1], shadowed[:-1, 1:], shadowed[1:, :-1],
                            shadowed[1:, 1:]])
        mixed |= corners.any(axis=0) & ~corners.all(axis=0)
    return mixed


# --------------------------------------------------------------------------- images
def _nan_reach_px(layout, radius: int) -> int:
    """How far (pixels) one raw sample can influence the residual demosaicker's output."""
    period = max(layout.period)
    # bilinear guide (one period), guided filter window (2 radius + 1), residual tent (one period)
    return 2 * period + 2 * radius + 1


def demosaicked_analyser(raw, layout) -> dict[str, np.ndarray]:
    """``I0, I45, I90, I135`` (float32, the mosaic's units) of a mono polarization mosaic.

    Uses the residual-interpolation demosaicker. NaN/inf raw pixels are
    replaced by zero for demosaicking and every output pixel they can reach is
    set to NaN, so only the texel-views that touch them are dropped.
    """


    if layout.is_colour:
        raise ObservationError("raw images of colour polarization sensors are not supported "
                               "yet: give analyser images per band")
    raw = np.asarray(raw, dtype=np.float64)
    bad = ~np.isfinite(raw)
    radius = max(layout.period)
    images = demosaic_residual(np.where(bad, 0.0, raw), layout, radius=radius)
    if bad.any():
        reach = _nan_reach_px(layout, radius)
        spoiled = binary_dilation(bad, structure=np.ones((2 * reach + 1, 2 * reach + 1), bool))
    result = {}
    for angle in ANALYSER_ANGLES:
        image = images[channel_name(angle)].astype(np.float32)
        if bad.any():
            image[spoiled] = np.nan
        result[f"I{angle}"] = image
    return result


def _raw_radiance(record, band: str, raw) -> np.ndarray:
    """Radiance (float64, W/(sr mm^2)) of a raw mosaic; saturated pixels are NaN."""
    dn = np.asarray(raw, dtype=np.float64)
    radiance = record.radiance(band, dn)
    if record.saturation_dn is not None:
        radiance[dn >= record.saturation_dn] = np.nan
    return radiance


def analyser_images(capture, record) -> list[np.ndarray]:
    """The image's analyser channels, ``[band0.I0, band0.I45, ..., bandK.I135]`` (H x W float32).

    Radiance for both kinds: raw mosaics are calibrated (``radiance_per_dn``,
    ``black_level_dn``; saturated pixels NaN) and then demosaicked; a raw
    record without calibration raises :class:`ObservationError`. The pixels are
    checked as :func:`~polarbssrdf.io.capture.load_capture` checks them, with its
    messages (:func:`~polarbssrdf.io.capture.check_image_channels`), except that
    NaN pixels of real captures pass: they drop texel-views, not the whole image.
    """

    manifest = capture.manifest
    camera = manifest.camera(record.camera)
    path = capture.directory / record.path
    channels, _ = read_exr(path)
    # the loader's checks (channel set, size, no infinity, no negative radiance) on the
    # pixels read here, so a run fits only what load_capture(check_images=True) accepts
    check_image_channels(channels, manifest.expected_channels(record), camera.image_size,
                         record.kind, f"'{path}'", allow_nan=True)
    if record.kind == "raw" and not record.calibrated:
        raise ObservationError(f"'{path}': raw image without a radiometric calibration: the "
                               "capture lacks radiance_per_dn (and black_level_dn) for it in "
                               "capture.json, so its digital numbers cannot be turned into "
                               "radiance; add them (docs/capture_format.md) or give analyser "
                               "images")
    images = []
    for band in manifest.band_names:
        if record.kind == "raw":
            analyser = demosaicked_analyser(_raw_radiance(record, band, channels[f"{band}.raw"]),
                                            camera.layout)
            images += [analyser[f"I{angle}"] for angle in ANALYSER_ANGLES]
        else:
            images += [np.asarray(channels[f"{band}.I{angle}"], dtype=np.float32)
                       for angle in ANALYSER_ANGLES]
    return images


# --------------------------------------------------------------------------- capture checks
def _as_capture(capture):
    """A :class:`~polarbssrdf.io.capture.Capture` (paths are loaded without reading images)."""

    return capture if isinstance(capture, Capture) else load_capture(capture, check_images=False)


def _check_texture_size(texture_size) -> int:
    if isinstance(texture_size, bool) or int(texture_size) != texture_size or texture_size < 1:
        raise ValueError(f"texture_size must be a positive integer, got {texture_size!r}")
    return int(texture_size)


def _frame_records(capture, frame_index: int, exclude_cameras) -> list:
    """The frame's polarization image records, without the excluded cameras; clear errors."""
    manifest = capture.manifest
    indices = [frame.index for frame in manifest.frames]
    if frame_index not in indices:
        raise ObservationError(f"capture '{capture.directory}' has no frame {frame_index} "
                               f"(frames: {', '.join(map(str, indices))})")
    known = {camera.name for camera in manifest.cameras}
    unknown = sorted(set(exclude_cameras) - known)
    if unknown:
        raise ObservationError(f"exclude_cameras names unknown cameras {unknown} "
                               f"(known: {', '.join(sorted(known))})")
    frame = manifest.frame(frame_index)
    polarized = [record for record in frame.images if record.kind in ("analyser", "raw")]
    if not polarized:
        raise ObservationError(f"frame {frame_index} of capture '{capture.directory}' has no "
                               "polarization images (neither analyser nor raw): nothing to observe")
    records = [record for record in polarized if record.camera not in set(exclude_cameras)]
    if not records:
        raise ObservationError(f"frame {frame_index}: every camera with polarization images is "
                               f"excluded ({', '.join(sorted(set(exclude_cameras)))})")
    return records


def observation_fingerprint(capture, frame_index, texture_size, *, exclude_cameras=(),
                            block_size=32, min_cosine=0.1) -> tuple[str, dict]:
    """``(sha256 hex, inputs)`` of everything a store depends on.

    The inputs: the content hash of ``capture.json``, of the mesh and of every
    image of the frame (:func:`polarbssrdf.io.identity.file_digest`: the bytes,
    not the size and modification time, which ``cp -p`` or a re-export of an
    uncompressed EXR keep), the texture size, frame, excluded cameras,
    thresholds, block size and the store format version. Any change gives
    another fingerprint, hence a rebuild; the store records the inputs.
    """

    capture = _as_capture(capture)
    manifest_bytes = (capture.directory / MANIFEST_NAME).read_bytes()
    frame = capture.manifest.frame(frame_index)
    inputs = {
        "format_version": FORMAT_VERSION,
        "capture_json_sha256": hashlib.sha256(manifest_bytes).hexdigest(),
        "digest": DIGEST_NAME,
        "mesh": (None if capture.mesh_path is None or not capture.mesh_path.is_file()
                 else [capture.manifest.mesh, file_digest(capture.mesh_path)]),
        "images": [[record.path, file_digest(capture.directory / record.path)]
                   for record in frame.images],
        "texture_size": int(texture_size),
        "frame": int(frame_index),
        "exclude_cameras": sorted(exclude_cameras),
        "min_cosine": float(min_cosine),
        "block_size": int(block_size),
        "shadow_epsilon_relative": SHADOW_EPSILON_RELATIVE,
        "image_margin_px": IMAGE_MARGIN_PX,
        "mixed_pixels": {"depth_slack": MIXED_DEPTH_SLACK, "corner_offset_px": CORNER_OFFSET_PX,
                         "raw_reach": "sensor period - 1", "shadow_edges": True},
        "demosaicking": "residual",
    }
    text = json.dumps(inputs, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest(), inputs


# --------------------------------------------------------------------------- per-view evaluation
class _Surface:
    """The atlas' valid texels (object space) and a Mitsuba scene of the mesh for visibility."""

    def __init__(self, mesh, texture_size: int):

        ensure_jit_variant()  # ray casting and the atlas need a JIT variant
        mitsuba_mesh = to_mitsuba(mesh)
        atlas = texel_atlas(mitsuba_mesh, texture_size)
        self.texture_size = texture_size
        valid = atlas.valid.ravel()
        self.texel = np.flatnonzero(valid).astype(np.int64)
        self.position = atlas.position.reshape(-1, 3)[valid].astype(np.float64)
        self.normal = _unit(atlas.normal.reshape(-1, 3)[valid].astype(np.float64))
        del atlas
        extent = np.ptp(np.asarray(mesh.vertices, dtype=np.float64), axis=0)
        self.epsilon_mm = SHADOW_EPSILON_RELATIVE * float(np.linalg.norm(extent))
        self.scene = mi.load_dict({"type": "scene", "mesh": mitsuba_mesh})

    def occluded(self, origins, targets) -> np.ndarray:
        """(M,) bool: the segment from each origin to its target (mm) hits the mesh."""

        offset = targets - origins
        distance = np.linalg.norm(offset, axis=1)
        direction = offset / np.maximum(distance, 1e-30)[:, None]
        rays = mi.Ray3f(mi.Point3f(origins.T.astype(np.float32)),
                        mi.Vector3f(direction.T.astype(np.float32)),
                        to_jit(mi.Float, np.maximum(distance - 2 * self.epsilon_mm, 0), np.float32))
        return np.array(self.scene.ray_test(rays), dtype=bool)

    def chunks(self, block_size: int):
        """Index ranges into the valid texels, each ending on a block-row boundary.

        Valid texels are in row-major order, so chunks that hold whole block
        rows come out in block order once sorted inside.
        """
        T = self.texture_size
        texel_row = self.texel // T
        strip = texel_row // block_size
        n_strips = -(-T // block_size)
        strip_starts = np.searchsorted(strip, np.arange(n_strips + 1))
        start = 0
        for s in range(1, n_strips + 1):
            if strip_starts[s] - start >= TEXELS_PER_CHUNK or s == n_strips:
                if strip_starts[s] > start:
                    yield start, int(strip_starts[s])
                start = int(strip_starts[s])


def _new_statistics() -> dict[str, int]:
    return {"valid_texels": 0, "facing": 0, "outside_image": 0, "mixed": 0, "occluded": 0,
            "nonfinite": 0, "kept": 0}


def _observe_chunk(surface, rows, rig, camera, light, pose, images, mixed, min_cosine,
                   view_index, statistics) -> TexelViews | None:
    """Texel-views of the valid texels ``rows`` (a slice) in one view; updates ``statistics``."""
    p, n = surface.position[rows], surface.normal[rows]
    texel = surface.texel[rows]
    statistics["valid_texels"] += len(p)
    to_camera = rig["camera_centre"][None, :] - p
    to_light = rig["light_position"][None, :] - p
    camera_dir, light_dir = _unit(to_camera), _unit(to_light)
    facing = ((np.sum(n * camera_dir, axis=1) > min_cosine)
              & (np.sum(n * light_dir, axis=1) > min_cosine))
    statistics["facing"] += int(facing.sum())
    keep = np.flatnonzero(facing)
    if len(keep) == 0:
        return None
    world = p[keep] @ pose[:3, :3].T + pose[:3, 3]
    uv, in_front = project_to_image(camera, world)
    u, v = uv[:, 0], uv[:, 1]
    margin = IMAGE_MARGIN_PX
    inside = (in_front & np.isfinite(u) & np.isfinite(v) & (u >= margin) & (v >= margin)
              & (u <= camera.width - 1 - margin) & (v <= camera.height - 1 - margin))
    statistics["outside_image"] += int((~inside).sum())
    keep, u, v = keep[inside], u[inside], v[inside]
    if len(keep) == 0:
        return None
    pure = bilinear_samples([mixed], u, v)[:, 0] == 0
    statistics["mixed"] += int((~pure).sum())
    keep, u, v = keep[pure], u[pure], v[pure]
    if len(keep) == 0:
        return None
    origin = p[keep] + n[keep] * surface.epsilon_mm
    targets = np.concatenate([np.broadcast_to(rig["camera_centre"], origin.shape),
                              np.broadcast_to(rig["light_position"], origin.shape)])
    blocked = surface.occluded(np.concatenate([origin, origin]), targets)
    visible = ~(blocked[:len(keep)] | blocked[len(keep):])
    statistics["occluded"] += int((~visible).sum())
    keep, u, v = keep[visible], u[visible], v[visible]
    if len(keep) == 0:
        return None
    samples = bilinear_samples(images, u, v).reshape(len(keep), -1, 4)
    finite = np.isfinite(samples).all(axis=(1, 2))
    statistics["nonfinite"] += int((~finite).sum())
    keep, samples = keep[finite], samples[finite]
    statistics["kept"] += len(keep)
    if len(keep) == 0:
        return None
    camera_dir, light_dir = camera_dir[keep], light_dir[keep]
    field = polarization_field(-light_dir, rig["polarization_axis"], rig["polarizer_normal"])
    basis = camera_stokes_x_axis(-camera_dir, -rig["camera_down"])
    count = len(keep)
    return TexelViews(
        texel=texel[keep].astype(np.int32),
        view=np.full(count, view_index, dtype=np.int16),
        to_camera=camera_dir.astype(np.float32),
        to_light=light_dir.astype(np.float32),
        light_distance_mm=np.linalg.norm(to_light[keep], axis=1).astype(np.float32),
        light_intensity=np.full(count, light.intensity, dtype=np.float32),
        light_field=field.astype(np.float32),
        camera_basis=basis.astype(np.float32),
        analyser=samples.astype(np.float32))


def _sorted_by_block(views: TexelViews, texture_size: int, block_size: int):
    """``views`` sorted by (block, texel, view) and the block index of each row."""
    block = block_of_texel(views.texel, texture_size, block_size)
    order = np.lexsort((views.view, views.texel, block))
    return views.take(order), block[order]


def _observe_view(surface, capture, record, pose, min_cosine, block_size, view_index):
    """All texel-views of one image, sorted by block; ``(views, block counts, statistics)``."""
    manifest = capture.manifest
    camera, light = manifest.camera(record.camera), manifest.light(record.light)
    rig = rig_in_object_space(pose, camera, light)
    images = analyser_images(capture, record)
    mixed = mixed_pixels(surface, camera, pose, min_cosine, rig["light_position"])
    if record.kind == "raw" and camera.layout is not None:
        # a demosaicked pixel interpolates its missing analyser angles from the samples less
        # than one sensor period away: a pure pixel that close to a mixed one holds its light.
        # (The guided filter's residual correction reaches further, but weakly.)
        reach = max(camera.layout.period) - 1
        mixed = binary_dilation(mixed, structure=np.ones((2 * reach + 1, 2 * reach + 1), bool))
    mixed = mixed.astype(np.float32)
    statistics = _new_statistics()
    parts = []
    for start, stop in surface.chunks(block_size):
        part = _observe_chunk(surface, slice(start, stop), rig, camera, light, pose, images,
                              mixed, min_cosine, view_index, statistics)
        if part is not None:
            parts.append(part)
    del images
    views = TexelViews.concatenate(parts, len(manifest.bands))
    views, block = _sorted_by_block(views, surface.texture_size, block_size)
    n_blocks = (-(-surface.texture_size // block_size)) ** 2
    return views, np.bincount(block, minlength=n_blocks), statistics


# --------------------------------------------------------------------------- build
def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()


_PACKED_FIELDS = tuple(name for name in FIELDS if name != "view")
"""Fields of a pass-1 partial array; the view is the partial's own index."""


def _pack_rows(views: TexelViews) -> np.ndarray:
    """One view's texel-views as a single (N, width) float32 array (the texel's int32 bits kept).

    One array instead of nine makes pass 2 read each view's strip in one call.
    """
    columns = [views.texel.astype(np.int32).view(np.float32)[:, None]]
    columns += [getattr(views, name).reshape(len(views), -1).astype(np.float32)
                for name in _PACKED_FIELDS[1:]]
    return np.ascontiguousarray(np.concatenate(columns, axis=1))


def _unpack_rows(packed: np.ndarray, view_index: int, n_bands: int) -> TexelViews:
    """Inverse of :func:`_pack_rows`."""
    fields, column = {}, 1
    fields["texel"] = np.ascontiguousarray(packed[:, 0]).view(np.int32)
    for name in _PACKED_FIELDS[1:]:
        shape = field_shape(name, n_bands)
        width = int(np.prod(shape)) if shape else 1
        fields[name] = packed[:, column:column + width].reshape(len(packed), *shape).copy()
        column += width
    fields["view"] = np.full(len(packed), view_index, dtype=np.int16)
    return TexelViews(**fields)


def _write_partial_view(partial_group, name: str, views: TexelViews):
    """Pass 1: one view's texel-views (block-sorted, packed) as an array of ``partial_group``."""
    packed = _pack_rows(views)
    array = partial_group.create_array(name, shape=packed.shape,
                                       chunks=(min(ROWS_PER_CHUNK, len(packed)), packed.shape[1]),
                                       dtype=np.float32, compressors=compressor())
    array[:] = packed
    return array


def _strips(view_block_offsets):
    """``(first block, stop block)`` of each merge strip: consecutive blocks, grouped.

    A strip takes consecutive blocks (row-major) until it holds
    :data:`STRIP_ROWS` texel-views (one block at least): few reads of each
    view's partial array, and memory bounded by the larger of STRIP_ROWS
    and one block's texel-views.
    """
    combined = np.sum(view_block_offsets, axis=0)
    n_blocks = len(combined) - 1
    strips, first = [], 0
    for stop in range(1, n_blocks + 1):
        if combined[stop] - combined[first] >= STRIP_ROWS or stop == n_blocks:
            strips.append((first, stop))
            first = stop
    return strips


def _merge_strips(final_arrays, partials, view_block_offsets, texture_size, block_size,
                  n_bands, progress):
    """Pass 2: per strip of blocks, gather it from every view, sort by block, append."""

    appenders = {name: ChunkedAppender(array) for name, array in final_arrays.items()}
    for first, stop in tqdm(_strips(view_block_offsets), desc="merge", unit="strip",
                            disable=not progress):
        parts = []
        for view_index, (array, offsets) in enumerate(zip(partials, view_block_offsets)):
            start, end = int(offsets[first]), int(offsets[stop])
            if end > start:
                parts.append(_unpack_rows(np.asarray(array[start:end]), view_index, n_bands))
        merged = TexelViews.concatenate(parts, n_bands)
        del parts
        strip, _ = _sorted_by_block(merged, texture_size, block_size)
        del merged
        for name, values in strip.as_dict().items():
            appenders[name].append(values)
    for appender in appenders.values():
        appender.close()


def build_observations(capture, frame_index, texture_size, path, *, exclude_cameras=(),
                       block_size=32, min_cosine=0.1, progress=True) -> ObservationStore:
    """Build the observation store of one frame at ``path`` (replacing any store there).

    Parameters
    ----------
    capture : Capture or path
        The capture (never modified).
    frame_index : int
        The frame's index (its number in the manifest).
    texture_size : int
        ``T`` of the ``T x T`` texel atlas of the capture's mesh.
    path : path
        Directory of the zarr store to write.
    exclude_cameras : iterable of str
        Cameras left out (e.g. held out for validation).
    block_size : int
        Texels per side of a storage block.
    min_cosine : float
        Texel-views need ``cos > min_cosine`` between the normal and both the
        camera and the light direction.
    progress : bool
        Show tqdm progress bars.

    Returns
    -------
    ObservationStore

    Raises
    ------
    ObservationError
        (a ``ValueError``) no such frame, no polarization images, no mesh,
        no texel-view at all (with the reason per camera).
    ValueError
        ``texture_size`` or ``block_size`` < 1.
    """
    import zarr  # deferred, see polarbssrdf.inverse.observations.store.compressor

    capture = _as_capture(capture)
    texture_size = _check_texture_size(texture_size)
    if int(block_size) != block_size or block_size < 1:
        raise ValueError(f"block_size must be a positive integer, got {block_size!r}")
    block_size, frame_index = int(block_size), int(frame_index)
    exclude_cameras = tuple(sorted(set(exclude_cameras)))
    records = _frame_records(capture, frame_index, exclude_cameras)
    if len(records) > np.iinfo(np.int16).max:
        raise ObservationError(f"{len(records)} images in frame {frame_index}: the store's int16 "
                               f"view index holds at most {np.iinfo(np.int16).max}")
    if capture.mesh_path is None:
        raise ObservationError(f"capture '{capture.directory}' has no mesh: texture-space "
                               "observations need the object's mesh with UVs")
    fingerprint, inputs = observation_fingerprint(capture, frame_index, texture_size,
                                                  exclude_cameras=exclude_cameras,
                                                  block_size=block_size, min_cosine=min_cosine)
    manifest = capture.manifest
    pose = np.asarray(manifest.frame(frame_index).pose, dtype=np.float64)
    n_bands = len(manifest.bands)
    surface = _Surface(capture.load_mesh(), texture_size)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial_path, building_path = Path(f"{path}.partial"), Path(f"{path}.building")
    for leftover in (partial_path, building_path):
        _remove(leftover)  # from an interrupted build
    try:
        partial_root = zarr.open_group(os.fspath(partial_path), mode="w")
        views, partials, view_offsets, statistics, skipped = [], [], [], [], []
        counts = np.zeros(texture_size * texture_size, dtype=np.int64)
        for record in tqdm(records, desc="observations", unit="view", disable=not progress):
            view_index = len(views)
            observed, block_counts, stats = _observe_view(surface, capture, record, pose,
                                                          min_cosine, block_size, view_index)
            stats = {"camera": record.camera, "light": record.light, **stats}
            statistics.append(stats)
            if len(observed) == 0:
                reason = _why_nothing(stats)
                # one line of ours (a UserWarning would print its source line too); tqdm.write
                # keeps an open progress bar intact
                message = (f"camera {record.camera!r} (light {record.light!r}) sees no texel "
                           f"of frame {frame_index}: {reason}; skipping it")
                logger.warning(message)
                tqdm.write(f"polarbssrdf: warning: {message}", file=sys.stderr)
                skipped.append({"camera": record.camera, "light": record.light,
                                "reason": reason})
                continue
            views.append({"camera": record.camera, "light": record.light, "image": record.path})
            partials.append(_write_partial_view(partial_root, f"view{view_index:05d}", observed))
            view_offsets.append(np.concatenate([[0], np.cumsum(block_counts)]))
            counts += np.bincount(observed.texel, minlength=counts.size)
            del observed
        if not views:
            raise ObservationError(
                f"no texel-view at all in frame {frame_index} of '{capture.directory}': "
                + "; ".join(f"{s['camera']}: {_why_nothing(s)}" for s in statistics))
        total = int(sum(offsets[-1] for offsets in view_offsets))
        root = zarr.open_group(os.fspath(building_path), mode="w")
        final_arrays = create_field_arrays(root, total, n_bands)
        _merge_strips(final_arrays, partials, view_offsets, texture_size, block_size, n_bands,
                      progress)
        block_offsets = np.sum(view_offsets, axis=0).astype(np.int64)
        root.create_array("block_offsets", data=block_offsets)
        root.create_array("texel_view_counts",
                          data=counts.reshape(texture_size, texture_size).astype(np.int32))
        root.attrs.update({
            "kind": "polarbssrdf.observations", "format_version": FORMAT_VERSION,
            "texture_size": texture_size, "block_size": block_size,
            "bands": list(manifest.band_names), "views": views, "frame": frame_index,
            "fingerprint": fingerprint, "fingerprint_inputs": inputs,
            "min_cosine": float(min_cosine), "shadow_epsilon_mm": surface.epsilon_mm,
            "image_margin_px": IMAGE_MARGIN_PX, "capture": os.fspath(capture.directory),
            "skipped_views": skipped, "statistics": statistics, "texel_views": total,
            "units": {"length": "mm", "intensity": "W/sr",
                      "analyser": "W/(sr mm^2) (radiance; raw images calibrated with "
                                  "radiance_per_dn and black_level_dn)"},
        })
        _replace(building_path, path)
    finally:
        _remove(partial_path)
        _remove(building_path)
    return ObservationStore.open(path)


def _why_nothing(stats: dict) -> str:
    """A short reason why a view kept no texel-view, from its statistics."""
    if stats["valid_texels"] == 0:
        return "the atlas has no valid texel"
    if stats["facing"] == 0:
        return "every texel faces away from the camera or its light (camera looking away?)"
    if stats["kept"] == 0 and stats["outside_image"] == stats["facing"]:
        return "every facing texel projects outside the image"
    mixed = stats.get("mixed", 0)
    if stats["nonfinite"] and stats["nonfinite"] + stats["occluded"] + stats["outside_image"] \
            + mixed == stats["facing"]:
        return "the remaining texels sample non-finite (NaN) pixels"
    if mixed and mixed + stats["outside_image"] == stats["facing"]:
        return ("every facing texel in the image samples a pixel that also sees past the mesh "
                "(its outline or an occluding contour): is the mesh far smaller than the image?")
    return (f"{stats['outside_image']} facing texels outside the image, {mixed} on pixels "
            f"that also see past the mesh, {stats['occluded']} occluded")


def _replace(built: Path, final: Path) -> None:
    """Move the finished store into place; an old store is renamed away first, then removed."""
    old = Path(f"{final}.replaced")
    _remove(old)
    if final.exists():
        os.replace(final, old)
    os.replace(built, final)
    _remove(old)


def load_or_build_observations(capture, frame_index, texture_size, path,
                               **settings) -> ObservationStore:
    """The store at ``path`` if it was built from the same inputs, else a fresh build.

    ``settings`` are those of :func:`build_observations` (``exclude_cameras``,
    ``block_size``, ``min_cosine``, ``progress``). The store is reused when its
    fingerprint (:func:`observation_fingerprint`) matches; otherwise it is
    rebuilt (the capture is never touched). Logs, and prints when ``progress``,
    whether it was reused.
    """
    capture = _as_capture(capture)
    texture_size = _check_texture_size(texture_size)
    _frame_records(capture, int(frame_index), settings.get("exclude_cameras", ()))
    fingerprint_settings = {key: settings[key] for key in ("exclude_cameras", "block_size",
                                                           "min_cosine") if key in settings}
    fingerprint, _ = observation_fingerprint(capture, int(frame_index), texture_size,
                                             **fingerprint_settings)
    path = Path(path)
    reason = "no store there"
    try:
        store = ObservationStore.open(path)
        if store.fingerprint == fingerprint:
            _report(f"observations: reusing '{path}' ({len(store)} texel-views)", settings)
            return store
        reason = "its inputs changed"
    except FileNotFoundError:
        pass
    except (ValueError, KeyError) as error:
        reason = f"unreadable ({error})"
    _report(f"observations: building '{path}' ({reason})", settings)
    return build_observations(capture, frame_index, texture_size, path, **settings)


def _report(message: str, settings) -> None:
    logger.info(message)
    if settings.get("progress", True):
        print(message)
