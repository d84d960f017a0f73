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
the texels), on the backend of a Dr.Jit input or on the LLVM backend for
NumPy input. With an AD-enabled Dr.Jit input the blur is one custom AD
operation (:class:`_SumOfGaussiansBlur`): the blur is linear in the map, so
its reverse derivative is the adjoint blur (:func:`_blur_axis_adjoint`, also
fused kernels), not an AD graph of every tap (which is about 100x slower).
Gaussians narrower than the texels on both axes are merged into one identity
term.
"""

from __future__ import annotations

import numpy as np

MAX_TAPS_PER_SIDE = 64
SIGMAS_COVERED = 4.0  # +-4 sigma keeps 99.99% of the mass and 99.9% of the variance
IDENTITY_SIGMAS = 5.3  # a texel wider than this many sigma: neighbours weigh < 1e-6, the pass is skipped


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


def _weighted_taps(values, texel_mm, valid, variance, half_width, axis, shape, module):
    """``(sum_o w_o v x, W = sum_o w_o v)`` over the valid taps of one 1-D Gaussian pass.

    ``values`` may be None: then only the normalization ``W`` is formed.
    """
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
        if values is not None:
            total += weight * dr.gather(Float, values, neighbour)
        weight_sum += weight
    return total, weight_sum


def _blur_axis(values, texel_mm, valid, variance, half_width, axis, shape, module):
    """One normalized 1-D Gaussian pass over flat arrays (a single fused kernel)."""
    import drjit as dr

    total, weight_sum = _weighted_taps(values, texel_mm, valid, variance, half_width, axis,
                                       shape, module)
    return dr.select(weight_sum > 0, total / weight_sum, 0.0) * valid


def _weight_sum(texel_mm, valid, variance, half_width, axis, shape, module):
    """The normalization ``W_i`` of :func:`_blur_axis` (sum of the weights of valid taps)."""
    return _weighted_taps(None, texel_mm, valid, variance, half_width, axis, shape, module)[1]


def _blur_axis_adjoint(grad, texel_mm, valid, variance, half_width, axis, shape, module):
    """The transpose of :func:`_blur_axis` applied to ``grad`` (flat arrays, one fused kernel).

    Forward: ``y_i = v_i sum_o w_o(t_i) v_(i+o) x_(i+o) / W_i``; so
    ``xbar_j = v_j sum_o w_o(t_(j-o)) s_(j-o)`` with ``s_i = v_i ybar_i / W_i``."""
    import drjit as dr

    Float, UInt32, Int32 = module.Float, module.UInt32, module.Int32
    rows, cols = shape
    weight_sum = _weight_sum(texel_mm, valid, variance, half_width, axis, shape, module)
    scaled = dr.select(weight_sum > 0, grad * valid / weight_sum, 0.0)
    dr.eval(scaled)
    index = dr.arange(UInt32, rows * cols)
    row, col = index // cols, index % cols
    position = Int32(col if axis == 1 else row)
    length = cols if axis == 1 else rows
    inv_two_variance = dr.opaque(Float, 0.5 / variance)
    total = dr.zeros(Float, rows * cols)
    for offset in range(-half_width, half_width + 1):
        source = position - offset
        inside = (source >= 0) & (source < length)
        clamped = UInt32(dr.clip(source, 0, length - 1))
        other = row * cols + clamped if axis == 1 else clamped * cols + col
        distance = offset * dr.gather(Float, texel_mm, other)
        weight = dr.exp(-distance * distance * inv_two_variance)
        total += dr.select(inside, weight * dr.gather(Float, scaled, other), 0.0)
    return total * valid


def _axis_plan(variance_mm2, texel_size_mm, valid_mask):
    """[(axis, texel sizes along it, half width)] of the non-trivial 1-D passes (u, then v)."""
    plan = []
    for axis in (1, 0):  # along u (columns), then v (rows)
        texel_mm = texel_size_mm[..., 0] if axis == 1 else texel_size_mm[..., 1]
        half_width = half_width_texels(variance_mm2, texel_mm, valid_mask)
        smallest = texel_mm[valid_mask].min() if np.any(valid_mask) else 1.0
        # the nearest tap weighs < 1e-6 of the centre at every texel: the identity
        if half_width > 0 and smallest ** 2 < IDENTITY_SIGMAS ** 2 * variance_mm2:
            plan.append((axis, texel_mm, half_width))
    return plan


def blur_separable(texture, variance_mm2, texel_size_mm, valid_mask):
    """Blur a (T, T) map with one Gaussian of variance ``variance_mm2`` (mm^2), separably."""
    import drjit as dr

    module, Tensor, from_numpy = _backend_types(texture)
    shape = valid_mask.shape
    values = module.Float(np.ravel(texture).astype(np.float32)) if from_numpy else texture.array
    valid = module.Float(valid_mask.astype(np.float32).ravel())
    for axis, texel_mm, half_width in _axis_plan(variance_mm2, texel_size_mm, valid_mask):
        values = _blur_axis(values, module.Float(texel_mm.astype(np.float32).ravel()), valid,
                            float(variance_mm2), half_width, axis, shape, module)
        dr.eval(values)
    values = values * valid
    if from_numpy:
        return np.array(values, dtype=np.float32).reshape(shape)
    return Tensor(values, shape)


def blur_separable_adjoint(grad, variance_mm2, texel_size_mm, valid_mask, module):
    """The transpose of :func:`blur_separable` applied to a flat Dr.Jit array ``grad``."""
    import drjit as dr

    shape = valid_mask.shape
    valid = module.Float(valid_mask.astype(np.float32).ravel())
    values = grad * valid
    for axis, texel_mm, half_width in reversed(_axis_plan(variance_mm2, texel_size_mm, valid_mask)):
        values = _blur_axis_adjoint(values, module.Float(texel_mm.astype(np.float32).ravel()), valid,
                                    float(variance_mm2), half_width, axis, shape, module)
        dr.eval(values)
    return values


def _is_identity(variance_mm2, texel_size_mm, valid_mask):
    return not _axis_plan(variance_mm2, texel_size_mm, valid_mask)


class _SumOfGaussiansBlur:
    """Placeholder replaced by the Dr.Jit custom op class (defined lazily: drjit import)."""


def _custom_blur_class():
    import drjit as dr

    global _SumOfGaussiansBlur
    if isinstance(_SumOfGaussiansBlur, type) and issubclass(_SumOfGaussiansBlur, dr.CustomOp):
        return _SumOfGaussiansBlur

    class SumOfGaussiansBlur(dr.CustomOp):
        """``sum_j w_j G(v_j) * x`` as one AD node: forward blur, reverse = adjoint blur."""

        def eval(self, values, terms, texel_size_mm, valid_mask, shape, tensor_type):
            self.terms, self.texel_size_mm, self.valid_mask = terms, texel_size_mm, valid_mask
            self.shape, self.tensor_type = shape, tensor_type
            self.module = sys_module(values)
            texture = tensor_type(values, shape)
            valid = self.module.Float(valid_mask.astype(np.float32).ravel())
            result = None
            for weight, variance in terms:
                if variance is None:  # merged identity term
                    term = values * valid * float(weight)
                else:
                    term = blur_separable(texture, variance, texel_size_mm, valid_mask).array * float(weight)
                result = term if result is None else result + term
            return result

        def _adjoint(self, grad):
            valid = self.module.Float(self.valid_mask.astype(np.float32).ravel())
            result = None
            for weight, variance in self.terms:
                if variance is None:
                    term = grad * valid * float(weight)
                else:
                    term = blur_separable_adjoint(grad, variance, self.texel_size_mm, self.valid_mask,
                                                  self.module) * float(weight)
                result = term if result is None else result + term
            return result

        def backward(self):
            self.set_grad_in("values", self._adjoint(self.grad_out()))

        def forward(self):
            raise NotImplementedError("the sum-of-Gaussians blur supports reverse-mode AD only")

        def name(self):
            return "SumOfGaussiansBlur"

    _SumOfGaussiansBlur = SumOfGaussiansBlur
    return SumOfGaussiansBlur


def sys_module(array):
    import sys

    return sys.modules[type(array).__module__]


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
    # Gaussians that are the identity on both axes: one term
    terms, identity = [], 0.0
    for weight, variance in zip(weights, variances):
        if weight == 0:
            continue
        if _is_identity(variance, texel_size_mm, valid_mask):
            identity += float(weight)
        else:
            terms.append((float(weight), float(variance)))
    if identity != 0.0:
        terms.insert(0, (identity, None))
    if not terms:
        return texture * 0.0
    if not isinstance(texture, np.ndarray):
        import drjit as dr

        if dr.grad_enabled(texture):
            values = dr.custom(_custom_blur_class(), texture.array, terms, texel_size_mm,
                               valid_mask, tuple(valid_mask.shape), type(texture))
            return type(texture)(values, tuple(valid_mask.shape))
    result = None
    for weight, variance in terms:
        if variance is None:
            term = texture * (valid_mask.astype(np.float32) * weight if isinstance(texture, np.ndarray)
                              else type(texture)(valid_mask.astype(np.float32) * weight))
        else:
            term = blur_separable(texture, variance, texel_size_mm, valid_mask) * float(weight)
        result = term if result is None else result + term
    return result
