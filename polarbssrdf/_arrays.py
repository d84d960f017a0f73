"""Index operations on 2-D maps that work on NumPy arrays and on Dr.Jit tensors (with autodiff)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter


def is_numpy(array):
    return isinstance(array, np.ndarray)


def neighbour_index(shape, axis, offset):
    """Flat indices of each texel's neighbour ``offset`` texels along ``axis``, clamped to the map."""
    rows, cols = shape
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    if axis == 0:
        i = np.clip(i + offset, 0, rows - 1)
    else:
        j = np.clip(j + offset, 0, cols - 1)
    return (i * cols + j).ravel()


def take(map2d, flat_index):
    """``map2d.ravel()[flat_index]`` reshaped to the map's shape; differentiable for Dr.Jit."""
    shape = (map2d.shape[0], map2d.shape[1])
    if is_numpy(map2d):
        return map2d.reshape(-1)[flat_index].reshape(shape)
    import drjit as dr

    Array = type(map2d.array)
    values = dr.gather(Array, map2d.array, to_jit(dr.uint32_array_t(Array), flat_index, np.uint32))
    return type(map2d)(values, shape)


def aligned_copy(values, dtype=None):
    """A C-contiguous copy of ``values`` whose buffer starts on a 64-byte boundary.

    Dr.Jit maps NumPy buffers without copying and records their alignment in
    the kernels that read them; arrays at varying alignments make otherwise
    identical kernels hash differently and compile again at every call.
    """
    values = np.asarray(values, dtype=dtype)
    buffer = np.empty(values.nbytes + 64, np.uint8)
    offset = (-buffer.ctypes.data) % 64
    out = buffer[offset:offset + values.nbytes].view(values.dtype).reshape(values.shape)
    out[...] = values
    return out


def to_jit(array_type, values, dtype=None):
    """``array_type`` (a Dr.Jit array or tensor type) holding a 64-byte aligned copy of ``values``."""
    return array_type(aligned_copy(values, dtype))


def constant_like(map2d, values):
    """A NumPy (T, T) float32 array as the same kind of map as ``map2d``."""
    if is_numpy(map2d):
        return np.ascontiguousarray(values, dtype=np.float32)
    return to_jit(type(map2d), values, np.float32)


def edge_shift(values, axis, step):
    """NumPy ``values`` at each element's neighbour ``step`` along ``axis``, clamped to the array."""
    index = np.clip(np.arange(values.shape[axis]) + step, 0, values.shape[axis] - 1)
    return np.take(values, index, axis=axis)


def edge_shift_adjoint(values, axis, step):
    """Adjoint of :func:`edge_shift` for ``step`` +-1: each value added to its clamped neighbour."""
    source = np.moveaxis(values, axis, 0)
    out = np.zeros_like(source)
    if step == 1:
        out[1:] += source[:-1]
        out[-1] += source[-1]
    else:
        out[:-1] += source[1:]
        out[0] += source[0]
    return np.moveaxis(out, 0, axis)


def masked_low_pass(values, mask, sigma_texels):
    """Gaussian low-pass of ``values`` over the ``mask`` texels only (normalized convolution;
    ``sigma_texels`` 0: the values themselves)."""
    if sigma_texels <= 0:
        return np.asarray(values, np.float64)
    weight = np.asarray(mask, np.float64)
    smooth = gaussian_filter(np.asarray(values, np.float64) * weight, sigma_texels)
    return smooth / np.maximum(gaussian_filter(weight, sigma_texels), 1e-9)
