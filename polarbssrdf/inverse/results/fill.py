"""Filling texels without data from their neighbours (shared by the stages)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter


def fill_from_neighbours(values, known, sigma=1.0):
    """``values`` with the texels that are not ``known`` replaced by the normalized
    Gaussian average of known texels, the radius doubling until every texel is reached.

    Returns a float64 copy; unchanged where ``known`` (or when nothing is known).
    """

    out = np.array(values, dtype=np.float64)
    known = np.asarray(known, bool) & np.isfinite(out)
    if known.all() or not known.any():
        return out
    base = np.where(known, out, 0.0)
    weight_known = known.astype(np.float64)
    missing = ~known
    while missing.any():
        weight = gaussian_filter(weight_known, sigma, mode="nearest")
        total = gaussian_filter(base, sigma, mode="nearest")
        reached = missing & (weight > 1e-6)
        out[reached] = total[reached] / weight[reached]
        missing &= ~reached
        sigma *= 2.0
        if sigma > 4 * max(out.shape):
            out[missing] = base[known].mean()
            break
    return out
