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

Each 1-D pass is one fused Dr.Jit kernel (all taps gathered in one loop over
the texels), on the backend of a Dr.Jit input (with autodiff) or on the LLVM
backend for NumPy input.
"""

from __future__ import annotations

import numpy as np

MAX_TAPS_PER_SIDE = 64
SIGMAS_COVERED = 4.0  # +-4 sigma keeps 99.99% of the mass and 99.9% of the variance


def _backend_types(texture):
    """(module, TensorXf) to compute in, and whether the input was NumPy."""
    import drjit as dr

    if isinstance(texture, np.ndarray):
        return dr.llvm, dr.llvm.TensorXf, True
    import sys

    return sys.modules[type(texture).__module__], type(texture), False


def half_width_texels(variance_mm2, texel_mm, valid_mask, max_taps=MAX_TAPS_PER_SIDE):
    """Taps on each side needed to cover +-4 sigma at the smallest valid texel."""
    smallest = texel_mm[valid_mask].min() if np.any(valid_mask) else 1.0
    return int(min(np.ceil(SIGMAS_COVERED * np.sqrt(variance_mm2) / max(smallest, 1e-9)), max_taps))


def _blur_axis(values, texel_mm, valid, variance, half_width, axis, shape, module):
    """One normalized 1-D Gaussian pass over flat arrays (a single fused kernel)."""
    import drjit as dr

    Float, UInt32, Int32 = module.Float, module.UInt32, module.Int32
    rows, cols = shape
    index = dr.arange(UInt32, rows * cols)
    row, col = index // cols, index % cols
    position = Int32(col if axis == 1 else row)
    length = cols if axis == 1 else rows
    inv_two_variance = dr.opaque(Float, 0.5 / variance)
    total = dr.zeros(Float, rows * cols)
    weight_sum = dr.zeros(Float, rows * cols)
    for offset in range(-half_width, half_width + 1):
        target = position + offset
        inside = (target >= 0) & (target < length)
        clamped = UInt32(dr.clip(target, 0, length - 1))
        neighbour = row * cols + clamped if axis == 1 else clamped * cols + col
        distance = offset * texel_mm
        weight = dr.exp(-distance * distance * inv_two_variance)
        weight = dr.select(inside, weight * dr.gather(Float, valid, neighbour), 0.0)
        total += weight * dr.gather(Float, values, neighbour)
        weight_sum += weight
    return dr.select(weight_sum > 0, total / weight_sum, 0.0) * valid


def blur_separable(texture, variance_mm2, texel_size_mm, valid_mask):
    """Blur a (T, T) map with one Gaussian of variance ``variance_mm2`` (mm^2), separably."""
    import drjit as dr

    module, Tensor, from_numpy = _backend_types(texture)
    shape = valid_mask.shape
    values = module.Float(np.ravel(texture).astype(np.float32)) if from_numpy else texture.array
    valid = module.Float(valid_mask.astype(np.float32).ravel())
    for axis in (1, 0):  # along u (columns), then v (rows)
        texel_mm = texel_size_mm[..., 0] if axis == 1 else texel_size_mm[..., 1]
        half_width = half_width_texels(variance_mm2, texel_mm, valid_mask)
        if half_width == 0:
            continue
        values = _blur_axis(values, module.Float(texel_mm.astype(np.float32).ravel()), valid,
                            float(variance_mm2), half_width, axis, shape, module)
        dr.eval(values)
    values = values * valid
    if from_numpy:
        return np.array(values, dtype=np.float32).reshape(shape)
    return Tensor(values, shape)


def blur_sum_of_gaussians(texture, weights, variances_mm2, texel_size_mm, valid_mask,
                          negligible_weight=1e-4):
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
    negligible_weight : float
        Gaussians whose share of the total weight is below this are dropped
        and the others rescaled to the same total (a fitted ladder carries
        many weights of 1e-6 whose wide kernels would dominate the cost).
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
    total = weights.sum()
    kept = np.abs(weights) >= negligible_weight * np.abs(weights).sum()
    if np.any(kept) and weights[kept].sum() != 0:
        weights = np.where(kept, weights * total / weights[kept].sum(), 0.0)
    result = None
    for weight, variance in zip(weights, variances):
        if weight == 0:
            continue
        term = blur_separable(texture, variance, texel_size_mm, valid_mask) * float(weight)
        result = term if result is None else result + term
    if result is None:
        return texture * 0.0
    return result
