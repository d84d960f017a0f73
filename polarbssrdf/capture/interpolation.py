"""Bilinear interpolation of one channel's samples on its sensor lattice.

The samples of one analyser/colour channel lie on a lattice: a rectangular one
(one pixel per period, e.g. every channel of the IMX250MZR, and R and B of the
IMX250MYR) or a quincunx one (two pixels per period half a period apart, G of
the IMX250MYR). Bilinear interpolation on a lattice is a convolution of the
sparse samples with the tent ("hat") function of that lattice. Near the
borders part of the tent falls outside the image; dividing by the convolved
sample mask (normalized convolution, Knutsson & Westin 1993) renormalizes
the weights there, so constant fields are reproduced exactly everywhere and
the interior is plain bilinear interpolation.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from polarbssrdf.capture.layout import SensorLayout

__all__ = ["lattice_kernel", "normalized_convolution"]


def _tent(distance: np.ndarray) -> np.ndarray:
    return np.maximum(0.0, 1.0 - np.abs(distance))


def lattice_kernel(layout: SensorLayout, angle_deg: int, colour: str = "") -> np.ndarray:
    """The bilinear interpolation kernel of one channel's sample lattice.

    Parameters
    ----------
    layout, angle_deg, colour:
        The channel (see :meth:`SensorLayout.offsets`).

    Returns
    -------
    numpy.ndarray
        A (2 Ph - 1) x (2 Pw - 1) float64 kernel for a period Ph x Pw. One
        sample per period: the separable tent of half-width (Ph, Pw). Two
        samples half a period apart in both directions (quincunx): the tent
        of the 45-degree rotated lattice. Any other arrangement falls back to
        the separable tent, which stays exact on constant fields.
    """
    rows, cols = layout.period
    dy = np.arange(-(rows - 1), rows)[:, None] / rows
    dx = np.arange(-(cols - 1), cols)[None, :] / cols
    offsets = layout.offsets(angle_deg, colour)
    if len(offsets) == 2:
        (r0, c0), (r1, c1) = offsets
        if 2 * abs(r1 - r0) == rows and 2 * abs(c1 - c0) == cols:
            return _tent(dy + dx) * _tent(dy - dx)
    return _tent(dy) * _tent(dx)


def _correlate(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    # Rank-1 kernels are applied as two 1-D passes: same result, far fewer operations.
    u, s, vt = np.linalg.svd(kernel)
    if s.size > 1 and s[1] <= 1e-12 * s[0]:
        column, row = u[:, 0] * np.sqrt(s[0]), vt[0] * np.sqrt(s[0])
        out = ndimage.correlate1d(values, column, axis=0, mode="constant")
        return ndimage.correlate1d(out, row, axis=1, mode="constant")
    return ndimage.correlate(values, kernel, mode="constant")


def normalized_convolution(values: np.ndarray, mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Interpolate the samples ``values[mask]`` to every pixel with ``kernel``.

    Pixels with no sample within the kernel's reach (corners of quincunx
    lattices) take the value of their nearest sample.

    Parameters
    ----------
    values:
        H x W float array; only the entries where ``mask`` is true are used.
    mask:
        H x W boolean array of the sample positions.
    kernel:
        Interpolation weights (e.g. :func:`lattice_kernel`); odd sizes,
        centred.

    Returns
    -------
    numpy.ndarray
        H x W float64 ``(K * (m v)) / (K * m)``; equals ``values`` at the
        samples when ``kernel`` is a lattice tent.
    """
    if values.shape != mask.shape:
        raise ValueError(f"values {values.shape} and mask {mask.shape} differ in shape")
    if not mask.any():
        raise ValueError("no samples to interpolate")
    weights = mask.astype(np.float64)
    numerator = _correlate(np.where(mask, values, 0.0).astype(np.float64), kernel)
    denominator = _correlate(weights, kernel)
    # Rounding in the 1-D passes can leave ~1e-17 where the true weight is 0.
    uncovered = denominator <= 1e-9
    out = numerator / np.where(uncovered, 1.0, denominator)
    if uncovered.any():
        _, (rows, cols) = ndimage.distance_transform_edt(~mask, return_indices=True)
        out[uncovered] = values[rows[uncovered], cols[uncovered]]
    out[mask] = values[mask]
    return out
