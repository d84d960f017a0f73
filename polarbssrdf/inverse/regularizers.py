"""Spatial regularizers of the static stage (supplement eq. 32-35) on a window of maps.

A patch is optimized with a halo of :data:`HALO` texels around it, taken
from the full maps, so the 5 x 5 neighbourhoods and the Laplacian of the
patch's texels are the same as on the whole texture (no seams between
patches). Each term is a mean over the patch's valid texels (see
:mod:`polarbssrdf.inverse.losses` for why means).
"""

from __future__ import annotations

import dataclasses

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit

HALO = 2
"""Texels around a patch needed by the 5 x 5 smoothness window (eq. 35)."""


@dataclasses.dataclass(frozen=True)
class WindowStencils:
    """Gather indices and weights of a window's neighbourhoods (NumPy, built once per window).

    Attributes
    ----------
    shape : (rows, cols)
        The window with its halo.
    count : int
        Number of interior texels.
    interior : UInt32
        Flat window indices of the patch's valid texels (where the terms are evaluated).
    laplacian : list of 4 UInt32
        The 4-neighbours of each interior texel (clamped at the window edge).
    box_index, box_weight : lists of 24 UInt32 and Float
        The 5 x 5 neighbours (centre excluded) and 1 / (valid neighbours) where valid, else 0.
    """

    shape: tuple
    count: int
    interior: object
    laplacian: list
    box_index: list
    box_weight: list


def window_stencils(valid, patch_rows, patch_cols):
    """Stencils of a window whose ``valid`` (rows, cols) mask covers the patch plus its halo.

    Parameters
    ----------
    valid : (rows, cols) bool
        Valid texels of the window (halo included).
    patch_rows, patch_cols : slice
        Where the patch sits inside the window.
    """
    rows, cols = valid.shape
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    inside = np.zeros_like(valid)
    inside[patch_rows, patch_cols] = True
    centre = np.flatnonzero(inside & valid)
    ci, cj = i.ravel()[centre], j.ravel()[centre]

    def flat(di, dj):
        return np.clip(ci + di, 0, rows - 1) * cols + np.clip(cj + dj, 0, cols - 1)

    laplacian = np.stack([flat(-1, 0), flat(1, 0), flat(0, -1), flat(0, 1)])
    offsets = [(di, dj) for di in range(-2, 3) for dj in range(-2, 3) if (di, dj) != (0, 0)]
    box_index = np.stack([flat(di, dj) for di, dj in offsets])
    in_range = np.stack([(ci + di >= 0) & (ci + di < rows) & (cj + dj >= 0) & (cj + dj < cols)
                         for di, dj in offsets])
    box_valid = in_range & valid.ravel()[box_index]
    counts = np.maximum(box_valid.sum(axis=0), 1)
    box_weight = (box_valid / counts).astype(np.float32)
    from polarbssrdf.inverse.model import jit_types

    Float, _, UInt32, _ = jit_types()
    return WindowStencils((rows, cols), len(centre), to_jit(UInt32, centre, np.uint32),
                          [to_jit(UInt32, index, np.uint32) for index in laplacian],
                          [to_jit(UInt32, index, np.uint32) for index in box_index],
                          [to_jit(Float, weight, np.float32) for weight in box_weight])


def _count(values, stencils):
    # opaque: a literal texel count would compile new kernels for every patch
    return dr.opaque(type(values), max(stencils.count, 1))


def _gather(values, index):
    return dr.gather(type(values), values, index)


def displacement_magnitude(height, stencils):
    """``L_Htreg = mean(H^2)`` over the patch's valid texels (eq. 33), mm^2."""
    H = _gather(height, stencils.interior)
    return dr.sum(dr.square(H)) / _count(height, stencils)


def displacement_laplacian(height, stencils):
    """``L_Hsreg = mean((lap H)^2)`` with the 5-point Laplacian in texels (eq. 34), mm^2."""
    H = _gather(height, stencils.interior)
    neighbours = sum(_gather(height, index) for index in stencils.laplacian)
    return dr.sum(dr.square(neighbours - 4.0 * H)) / _count(height, stencils)


def neighbourhood_smoothness(values, stencils):
    """``mean((p - p_bar)^2)``, ``p_bar`` the mean of the valid 5 x 5 neighbours (eq. 35)."""
    p = _gather(values, stencils.interior)
    mean = sum(weight * _gather(values, index)
               for index, weight in zip(stencils.box_index, stencils.box_weight))
    return dr.sum(dr.square(p - mean)) / _count(values, stencils)
