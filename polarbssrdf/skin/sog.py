"""Sums of Gaussians for radial profiles (supplement eq. 16, 17, 43-46).

G(v, r) = exp(-r^2 / (2 v)) / (2 pi v) (1/mm^2, v in mm^2, integrates to 1
over the plane). Fixed variance ladder v_j = 2^j v0, v0 = (0.01 mm)^2.
Eq. 18 as printed is wrong: G(va) * G(vb) = G(va + vb), so convolving a
Gaussian with itself doubles its variance, and repeated self-convolution,
the construction eq. 18 describes, produces the ratio-2 ladder used by
default. The printed ratio-4 ladder is available (``ratio=4``; there
G(4^n v0) * G(3 * 4^n v0) = G(4^(n+1) v0), see :func:`ladder_step_variance`)
but fits the thin-epidermis transmittance profiles only to a few percent.
"""

from __future__ import annotations

import numpy as np

V0_MM2 = 0.01**2


def variance_ladder(count: int | None = None, v0_mm2: float = V0_MM2, ratio: float = 2.0) -> np.ndarray:
    """v_j = ratio^j v0 (mm^2), j = 0..count-1; by default ratio 2 with 23
    steps (std 0.01 mm to 20 mm), the ladder of repeated self-convolution
    G(v) * G(v) = G(2 v). ratio = 4 is the ladder printed in the supplement
    (12 steps); it fits the thin-epidermis transmittance profiles up to ~40x
    worse (see docs/skin.md)."""
    if ratio <= 1:
        raise ValueError("ladder ratio must be > 1")
    if count is None:
        count = int(np.ceil(np.log(4.0**11) / np.log(ratio))) + 1
    return v0_mm2 * ratio ** np.arange(count)


def ladder_step_variance(v_mm2, ratio: float = 2.0):
    """The variance to convolve G(v) with to reach G(ratio v): (ratio - 1) v
    (mm^2): v on the default ladder, 3 v on the printed ratio-4 ladder (not v,
    as eq. 18 suggests)."""
    return (ratio - 1.0) * np.asarray(v_mm2, dtype=float)


def gaussian(v_mm2, r_mm):
    """G(v, r) = exp(-r^2 / 2v) / (2 pi v) in 1/mm^2."""
    v = np.asarray(v_mm2, dtype=float)
    r = np.asarray(r_mm, dtype=float)
    return np.exp(-(r**2) / (2.0 * v)) / (2.0 * np.pi * v)


def sog_profile(r_mm, weights, variances_mm2):
    """sum_j w_j G(v_j, r) (eq. 17), 1/mm^2; weights on the last axis."""
    r = np.asarray(r_mm, dtype=float)
    return gaussian(np.asarray(variances_mm2)[None, :], r.reshape(-1, 1)).reshape(r.shape + (-1,)) @ np.asarray(weights)


def _radial_weights(r):
    """Trapezoid weights times r for int r f(r) dr on an increasing grid."""
    r = np.asarray(r, dtype=float)
    w = np.empty_like(r)
    w[1:-1] = 0.5 * (r[2:] - r[:-2])
    w[0] = 0.5 * (r[1] - r[0])
    w[-1] = 0.5 * (r[-1] - r[-2])
    return w * r


def fit_sog(r_mm, profile, variances_mm2=None) -> np.ndarray:
    """Non-negative weights w_j minimising int r (R(r) - sum w_j G(v_j, r))^2 dr
    (eq. 16) on the given radial grid (scipy.optimize.nnls). The weights are
    unitless and sum approximately to the total 2 pi int R r dr."""
    variances = variance_ladder() if variances_mm2 is None else np.asarray(variances_mm2, dtype=float)
    r = np.asarray(r_mm, dtype=float)
    sqrt_w = np.sqrt(_radial_weights(r))
    basis = gaussian(variances[None, :], r[:, None]) * sqrt_w[:, None]
    from scipy.optimize import nnls  # imported here: scipy.optimize is slow to import

    weights, _ = nnls(basis, np.asarray(profile, dtype=float) * sqrt_w, maxiter=50 * len(variances))
    return weights


def sog_relative_error(r_mm, profile, weights, variances_mm2=None) -> float:
    """Relative L2 error with the r weighting of eq. 16:
    sqrt(int r (R - fit)^2 dr / int r R^2 dr)."""
    variances = variance_ladder() if variances_mm2 is None else np.asarray(variances_mm2, dtype=float)
    w = _radial_weights(r_mm)
    fit = sog_profile(r_mm, weights, variances)
    profile = np.asarray(profile, dtype=float)
    return float(np.sqrt(np.sum(w * (profile - fit) ** 2) / np.sum(w * profile**2)))


def normalized_weights(weights):
    """w_bar = w / sum(w) (eq. 43): the blur kernel shape, total factored out."""
    weights = np.asarray(weights, dtype=float)
    total = weights.sum(axis=-1, keepdims=True)
    if np.any(total <= 0):
        raise ValueError("SoG weights must have a positive sum")
    return weights / total


def discrete_kernel(weights, variances_mm2, texel_mm: float, radius_texels: int) -> np.ndarray:
    """A (2 radius + 1)^2 texture-space blur kernel of the SoG, normalized to
    sum 1 (energy conservation, supplement section 5.3)."""
    if texel_mm <= 0 or radius_texels < 0:
        raise ValueError("texel_mm must be > 0 and radius_texels >= 0")
    offsets = np.arange(-radius_texels, radius_texels + 1) * texel_mm
    r = np.hypot(offsets[:, None], offsets[None, :])
    kernel = sog_profile(r, normalized_weights(weights), variances_mm2)
    return kernel / kernel.sum()


def separable_kernels(variances_mm2, texel_mm: float, radius_texels: int) -> np.ndarray:
    """1-D normalized Gaussian kernels, one row per variance, so that each
    G(v_j) blur is two 1-D convolutions (eq. 17 text)."""
    offsets = np.arange(-radius_texels, radius_texels + 1) * texel_mm
    k = np.exp(-(offsets[None, :] ** 2) / (2.0 * np.asarray(variances_mm2, dtype=float)[:, None]))
    return k / k.sum(axis=1, keepdims=True)
