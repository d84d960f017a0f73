"""Texture-space blurring with sums of Gaussians (supplement eq. 43-46, d'Eon et al. 2007).

A radially symmetric diffusion profile written as a normalized sum of
Gaussians ``G(r) = sum_j w_j G(v_j, r)`` (``sum_j w_j = 1``, variances in mm^2,
``G(v, r) = exp(-r^2 / 2v) / (2 pi v)``) is applied to a map in texture space
as separable 1-D convolutions along ``u`` and ``v``. Texels are not square
nor equal in size across a face, so each output texel uses its own extent in
mm (a "stretch map", from :class:`polarbssrdf.geometry.TexelAtlas`), and
each 1-D kernel is renormalized over the valid texels it covers: the blur
conserves energy per texel and does not leak into or out of the empty parts
of the atlas. Gaussians narrower than half a texel are the identity at this
resolution.

Works on NumPy (T, T) arrays and on Dr.Jit ``TensorXf`` maps (differentiable
with respect to the map).
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import constant_like, is_numpy, neighbour_index, take

MAX_TAPS_PER_SIDE = 64


def gaussian_taps(variance_mm2, texel_mm, valid_mask, axis, max_taps=MAX_TAPS_PER_SIDE):
    """Per-texel normalized 1-D Gaussian weights along ``axis``; list of (offset, (T, T) weights).

    Parameters
    ----------
    variance_mm2 : float
        Variance ``v`` of the Gaussian, mm^2.
    texel_mm : (T, T) array
        Texel extent along ``axis`` at each output texel, mm.
    valid_mask : (T, T) bool
        Texels that lie on the surface.
    axis : int
        0 blurs along rows (``v``), 1 along columns (``u``).
    """
    sigma = np.sqrt(variance_mm2)
    smallest = texel_mm[valid_mask].min() if np.any(valid_mask) else 1.0
    # +-4 sigma keeps 99.99% of the mass and 99.9% of the variance (3 sigma: 97.3%)
    half_width = int(min(np.ceil(4.0 * sigma / max(smallest, 1e-9)), max_taps))
    offsets = range(-half_width, half_width + 1)
    weights = []
    for offset in offsets:
        neighbour_valid = valid_mask.ravel()[neighbour_index(valid_mask.shape, axis, offset)]
        inside = np.ones(valid_mask.shape, bool)
        index = np.arange(valid_mask.shape[axis])
        shifted = index + offset
        inside_1d = (shifted >= 0) & (shifted < valid_mask.shape[axis])
        inside &= inside_1d[:, None] if axis == 0 else inside_1d[None, :]
        distance = offset * texel_mm
        weight = np.exp(-0.5 * distance**2 / variance_mm2)
        weights.append(np.where(inside & neighbour_valid.reshape(valid_mask.shape), weight, 0.0))
    total = np.sum(weights, axis=0)
    total = np.where(total > 0, total, 1.0)
    return [(offset, (w / total).astype(np.float32)) for offset, w in zip(offsets, weights)]


def blur_separable(texture, variance_mm2, texel_size_mm, valid_mask):
    """Blur a (T, T) map with one Gaussian of variance ``variance_mm2``, separably."""
    result = texture
    for axis in (1, 0):  # along u (columns), then v (rows)
        texel_mm = texel_size_mm[..., 0] if axis == 1 else texel_size_mm[..., 1]
        taps = gaussian_taps(variance_mm2, texel_mm, valid_mask, axis)
        if len(taps) == 1:
            continue
        blurred = None
        for offset, weight in taps:
            term = take(result, neighbour_index(valid_mask.shape, axis, offset)) \
                * constant_like(texture, weight)
            blurred = term if blurred is None else blurred + term
        result = blurred
    return result * constant_like(texture, valid_mask.astype(np.float32))


def blur_sum_of_gaussians(texture, weights, variances_mm2, texel_size_mm, valid_mask):
    """``sum_j w_j (G(v_j) * texture)`` in texture space; eq. 44-45.

    Parameters
    ----------
    texture : (T, T) array or TensorXf
        The map to blur (e.g. transmitted irradiance times albedo).
    weights : sequence of float
        Normalized SoG weights ``w_j`` (they should sum to 1 to conserve energy).
    variances_mm2 : sequence of float
        Gaussian variances ``v_j``, mm^2.
    texel_size_mm : (T, T, 2) array
        Texel extent along ``u`` and ``v``, mm (``TexelAtlas.texel_size_mm``).
    valid_mask : (T, T) bool
        Texels on the surface.
    """
    weights = np.asarray(weights, dtype=np.float64)
    variances = np.asarray(variances_mm2, dtype=np.float64)
    if weights.shape != variances.shape:
        raise ValueError(f"{len(weights)} SoG weights for {len(variances)} variances")
    if np.any(variances <= 0) or not np.all(np.isfinite(variances)):
        raise ValueError("SoG variances must be positive and finite")
    if texture.shape[:2] != valid_mask.shape or texel_size_mm.shape[:2] != valid_mask.shape:
        raise ValueError(f"map {texture.shape}, texel sizes {texel_size_mm.shape} and mask "
                         f"{valid_mask.shape} must share their first two dimensions")
    result = None
    for weight, variance in zip(weights, variances):
        if weight == 0:
            continue
        term = blur_separable(texture, variance, texel_size_mm, valid_mask) * float(weight)
        result = term if result is None else result + term
    if result is None:
        return texture * 0.0
    return result
