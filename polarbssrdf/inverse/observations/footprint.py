"""How much a capture blurs the maps fitted from it: its pixels' point spread in texture space.

A texel's value in one view is the image sampled bilinearly at the projection of the
texel's centre; that image's pixel integrates the surface over its footprint, and the
surface the camera sees between texel centres is the maps' bilinear reconstruction (the
renderer's texture filter). A map fitted per texel is therefore the surface's map blurred
by the three kernels in turn. A detail smaller than the footprint (a 3 mm freckle seen by
2 mm pixels) comes out flattened, and a fit that reads the map as sharp takes the flattening
for the detail's size (issue 32, item 3).

:func:`capture_blur_variance_mm2` gives the blur as one isotropic Gaussian: the variance
(mm^2) of the three kernels' sum, the footprint's the median over the texel-views of the
frame (a stated approximation: the blur is anisotropic and grows towards grazing views,
and a fit weights its views). Kernel variances per axis, in pixels^2:

* the pixel's box: 1/12;
* the bilinear sample: the tent of half-width 1, 1/6;
* a raw mosaic's demosaicking (:func:`~polarbssrdf.capture.demosaic.demosaic`) reconstructs
  each analyser angle from samples one sensor period ``P`` apart: at most the bilinear
  tent of half-width ``P``, ``P^2 / 6``, less the 1/6 the sample's own tent already counts
  (the residual interpolation restores some detail from the other angles: an upper bound);

and for the texture filter, the tent of one texel (1/6 texel^2 per axis). A pixel of
angular size ``1 / f`` at distance ``d`` spans ``d / f`` across the line of sight and
``d / (f cos theta)`` along the surface's tilt; the isotropic variance is the mean of the
two axes'.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.inverse.observations.build import project_to_image, rig_in_object_space

PIXEL_SAMPLING_VARIANCE_PX2 = 1.0 / 12.0 + 1.0 / 6.0
"""Per axis, the pixel's box and the bilinear sample's tent (pixels^2)."""

TEXTURE_FILTER_VARIANCE_TEXELS2 = 1.0 / 6.0
"""Per axis, the bilinear texture filter's tent (texels^2)."""


def demosaicking_variance_px2(period):
    """Per axis, the demosaicker's reach for a mosaic of ``period`` sensor pixels (pixels^2):
    the bilinear tent of half-width ``period`` less the sample's own tent (module docstring)."""
    return max(float(period) ** 2 / 6.0 - 1.0 / 6.0, 0.0)


def pixel_footprint_variance_mm2(distance_mm, cosine, focal_px, sampling_variance_px2):
    """Isotropic variance (mm^2) of a pixel's sampling kernel on the surface.

    ``distance_mm`` from the camera, ``cosine`` between the surface normal and the line of
    sight, ``focal_px`` the focal length (pixels), ``sampling_variance_px2`` the kernel's
    variance per image axis (pixels^2). The mean of the two surface axes' variances: the
    pixel's ``d / f`` across the tilt and ``d / (f cos)`` along it."""
    pixel = np.asarray(distance_mm, np.float64) / float(focal_px)
    cosine = np.maximum(np.asarray(cosine, np.float64), 1e-3)
    return 0.5 * pixel ** 2 * (1.0 + 1.0 / cosine ** 2) * float(sampling_variance_px2)


def capture_blur_variance_mm2(capture, atlas, frame_index=0, exclude_cameras=(), min_cosine=0.1):
    """``(variance_mm2, figures)``: the capture's blur of fitted maps as one Gaussian (mm^2).

    Over every texel of ``atlas`` that faces a camera of ``frame_index``'s polarization
    images (and that camera's light) by more than ``min_cosine`` and projects into its
    image: the median of :func:`pixel_footprint_variance_mm2` with that image's sampling
    kernel, plus the texture filter's variance at the median texel size (module
    docstring). Occlusion is not tested (a median over the face). ``figures``: the
    footprint's median, the texture filter's share, the texel-views counted."""
    manifest = capture.manifest
    frame = manifest.frame(frame_index)
    pose = np.asarray(frame.pose, np.float64)
    valid = np.asarray(atlas.valid, bool)
    position, normal = atlas.position[valid], atlas.normal[valid]
    variances = []
    for record in frame.images:
        if record.kind not in ("analyser", "raw") or record.camera in set(exclude_cameras):
            continue
        camera, light = manifest.camera(record.camera), manifest.light(record.light)
        rig = rig_in_object_space(pose, camera, light)
        to_camera = rig["camera_centre"][None] - position
        distance = np.linalg.norm(to_camera, axis=1)
        cosine = np.sum(normal * to_camera, axis=1) / np.maximum(distance, 1e-9)
        to_light = rig["light_position"][None] - position
        lit = np.sum(normal * to_light, axis=1) > min_cosine * np.linalg.norm(to_light, axis=1)
        world = position @ pose[:3, :3].T + pose[:3, 3]
        uv, in_front = project_to_image(camera, world)
        inside = (in_front & np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0)
                  & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] <= camera.height - 1))
        seen = (cosine > min_cosine) & lit & inside
        sampling = PIXEL_SAMPLING_VARIANCE_PX2
        if record.kind == "raw" and camera.layout is not None:
            sampling += demosaicking_variance_px2(max(camera.layout.period))
        focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
        variances.append(pixel_footprint_variance_mm2(distance[seen], cosine[seen], focal, sampling))
    counted = np.concatenate(variances) if variances else np.zeros(0)
    if counted.size == 0:
        raise ValueError(f"frame {frame_index}: no texel faces a camera of a polarization image, "
                         "so the capture's blur cannot be estimated")
    texel = np.median(np.asarray(atlas.texel_size_mm, np.float64)[valid], axis=0)
    texture = TEXTURE_FILTER_VARIANCE_TEXELS2 * float(np.mean(texel ** 2))
    footprint = float(np.median(counted))
    return footprint + texture, {"footprint_mm2": footprint, "texture_filter_mm2": texture,
                                 "texel_views": int(counted.size)}
