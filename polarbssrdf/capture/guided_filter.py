"""A guided filter fitted on sparse samples (guided upsampling).

He, Sun & Tang, "Guided image filtering", TPAMI 2013, fit in every
(2r+1) x (2r+1) window a local linear model ``p ~ a I + b`` of the input
``p`` on the guide ``I`` and average the models of all windows covering a
pixel. Residual interpolation (Kiku et al., "Residual interpolation for color
image demosaicking", ICIP 2013; Morimatsu et al. 2020 for polarization) fits
the models on the sampled pixels of a mosaic channel only, which gives a
tentative full-resolution estimate of that channel shaped like the guide.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["masked_guided_filter"]


def _box_mean(values: np.ndarray, radius: int) -> np.ndarray:
    # Zero padding scales every sum near the border by the same factor, which
    # cancels in the ratios below.
    return ndimage.uniform_filter(values, size=2 * radius + 1, mode="constant")


def masked_guided_filter(guide: np.ndarray, values: np.ndarray, mask: np.ndarray,
                         radius: int, eps: float) -> np.ndarray:
    """Guided filter of ``guide`` towards the samples ``values[mask]``.

    Parameters
    ----------
    guide:
        H x W float array ``I``, known at every pixel.
    values:
        H x W float array ``p``; only the sampled entries (``mask``) are used.
    mask:
        H x W boolean array of sample positions; every (2r+1)-window must
        hold at least one sample.
    radius:
        Window radius ``r`` in pixels.
    eps:
        Regularization of the slope ``a`` in units of ``guide`` squared;
        larger values smooth more (``a -> 0``).

    Returns
    -------
    numpy.ndarray
        H x W float64 ``mean(a) I + mean(b)``, with ``a, b`` the least-squares
        fit of ``p`` on ``I`` over the samples of each window. A constant
        ``p`` gives back that constant exactly (``a = 0``).
    """
    weights = mask.astype(np.float64)
    samples = np.where(mask, values, 0.0).astype(np.float64)
    guide = np.asarray(guide, dtype=np.float64)
    count = _box_mean(weights, radius)
    if np.any(count <= 1e-12):
        raise ValueError(f"a guided-filter window of radius {radius} holds no sample; "
                         "use a larger radius")
    mean_guide = _box_mean(weights * guide, radius) / count
    mean_value = _box_mean(samples, radius) / count
    covariance = _box_mean(samples * guide, radius) / count - mean_guide * mean_value
    variance = np.maximum(_box_mean(weights * guide * guide, radius) / count - mean_guide ** 2, 0.0)
    slope = covariance / (variance + eps)
    # A constant p must give a = 0 exactly, not a rounding residue times I.
    slope[np.abs(covariance) <= 1e-12 * (np.abs(mean_guide * mean_value) + eps)] = 0.0
    intercept = mean_value - slope * mean_guide
    coverage = _box_mean(np.ones_like(guide), radius)
    return (_box_mean(slope, radius) * guide + _box_mean(intercept, radius)) / coverage
