"""Index operations on 2-D maps that work on NumPy arrays and on Dr.Jit tensors (with autodiff)."""

from __future__ import annotations

import numpy as np


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
    values = dr.gather(Array, map2d.array, dr.uint32_array_t(Array)(flat_index.astype(np.uint32)))
    return type(map2d)(values, shape)


def constant_like(map2d, values):
    """A NumPy (T, T) float32 array as the same kind of map as ``map2d``."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    return values if is_numpy(map2d) else type(map2d)(values)
