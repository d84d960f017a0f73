"""Cross-camera intensity normalization from images of a white reference sphere.

Supplement section 3.2: a Spectralon sphere is placed where the face will be
and every camera photographs it; each camera's values are then normalized so
that all cameras (or the predicted response) agree.

The sphere's statistic is size- and position-invariant: the sphere is the
largest connected region brighter than ``threshold x`` (its 99.5th
percentile); its centre is the region's centroid and its radius
``sqrt(area / pi)``; the statistic is the per-channel mean over the central
disc of radius ``inner_fraction x radius``. For a coaxially lit Lambertian
sphere that disc covers the same range of normals in every view, so equal
cameras give equal statistics whatever the sphere's image size. The gain
of a camera is its statistic divided by the reference's (or by a predicted
value); dividing its images by the gain normalizes them.
"""

from __future__ import annotations

import numpy as np

from .board import _cv2

__all__ = ["sphere_gains", "sphere_statistic", "srgb_to_linear"]


def srgb_to_linear(encoded) -> np.ndarray:
    """Linear values from sRGB-encoded ones in [0, 1] (the IEC 61966-2-1 decoding curve)."""
    encoded = np.asarray(encoded, dtype=np.float64)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def sphere_statistic(image, *, threshold: float = 0.25, inner_fraction: float = 0.5) -> np.ndarray:
    """Per-channel mean of the central disc of the brightest blob (the sphere).

    Parameters
    ----------
    image:
        ``H x W`` or ``H x W x C`` linear (dark-subtracted) image.
    threshold:
        Fraction of the 99.5th percentile of the luminance that separates sphere and background.
    inner_fraction:
        Radius of the averaged disc relative to the sphere's radius, in (0, 1].

    Returns
    -------
    numpy.ndarray
        ``(C,)`` (``(1,)`` for a grey image).
    """
    cv2 = _cv2()
    values = np.asarray(image, dtype=np.float64)
    if values.ndim == 2:
        values = values[..., None]
    if values.ndim != 3:
        raise ValueError(f"image must be H x W or H x W x C, got shape {np.shape(image)}")
    if not 0 < inner_fraction <= 1:
        raise ValueError(f"inner_fraction must be in (0, 1], got {inner_fraction}")
    luminance = np.nan_to_num(values.mean(axis=2))
    top = float(np.percentile(luminance, 99.5))
    if top <= 0:
        raise ValueError("image has no bright pixels: no sphere found")
    mask = (luminance > threshold * top).astype(np.uint8)
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count < 2:
        raise ValueError("no sphere found (no pixel above the threshold)")
    label = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    area = float(stats[label, cv2.CC_STAT_AREA])
    if area < 50:
        raise ValueError(f"sphere too small in the image ({area:.0f} pixels; need >= 50)")
    cx, cy = centroids[label]
    radius = np.sqrt(area / np.pi)
    rows, columns = np.mgrid[0:luminance.shape[0], 0:luminance.shape[1]]
    disc = ((columns - cx) ** 2 + (rows - cy) ** 2 <= (inner_fraction * radius) ** 2) & (labels == label)
    return values[disc].mean(axis=0)


def sphere_gains(images: dict, *, reference: str | None = None, predicted=None,
                 threshold: float = 0.25, inner_fraction: float = 0.5) -> dict[str, np.ndarray]:
    """Per-camera (and per-channel) gains from images of a white sphere.

    Parameters
    ----------
    images:
        ``{camera name: image}`` (see :func:`sphere_statistic`).
    reference:
        Camera whose gain is 1 (default: first name in sorted order); ignored with ``predicted``.
    predicted:
        Predicted statistic (scalar or per channel) of an ideal camera, e.g. from the
        calibrated response and the light; gains are then absolute.
    threshold, inner_fraction:
        As in :func:`sphere_statistic`.

    Returns
    -------
    dict
        ``{camera: gain (C,)}``; divide a camera's images by its gain.
    """
    if not images:
        raise ValueError("no sphere images given")
    statistics = {}
    for name in sorted(images):
        try:
            statistics[name] = sphere_statistic(images[name], threshold=threshold,
                                                inner_fraction=inner_fraction)
        except ValueError as error:
            raise ValueError(f"camera {name}: {error}") from None
    if predicted is not None:
        base = np.asarray(predicted, dtype=np.float64)
    else:
        reference = sorted(images)[0] if reference is None else reference
        if reference not in statistics:
            raise ValueError(f"reference camera {reference!r} not among {', '.join(sorted(images))}")
        base = statistics[reference]
    if np.any(base <= 0):
        raise ValueError("reference/predicted sphere value must be > 0")
    return {name: value / base for name, value in statistics.items()}
