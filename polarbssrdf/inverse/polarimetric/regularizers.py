"""Spatial regularizers of the static stage (supplement eq. 32-35) on a window of maps.

A patch is optimized with a halo of :data:`HALO` texels around it, taken
from the full maps, so the 5 x 5 neighbourhoods and the Laplacian of the
patch's texels are the same as on the whole texture (no seams between
patches). Each term is a mean over the patch's valid texels (see
:mod:`polarbssrdf.inverse.polarimetric.losses` for why means).

Every regularizer is a quadratic form ``|A x|^2 / n`` of a sparse stencil
``A``, so each function returns the value and its exact gradient
``2 A^T A x / n``, computed with separable box filters and shifts on the
window (NumPy). The optimizer adds these gradients to the ones
Dr.Jit's reverse pass gives the data terms instead of differentiating the
stencils inside that pass: there each neighbour read becomes an atomic
scatter-add, 81 of them per texel (the three 5 x 5 windows, the
Laplacian), which cost a quarter of a step (bench/RESULTS.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import uniform_filter

from polarbssrdf._arrays import edge_shift, edge_shift_adjoint

HALO = 2
"""Texels around a patch needed by the 5 x 5 smoothness window (eq. 35)."""

BOX = 5
"""Edge of eq. 35's neighbourhood in texels."""


@dataclasses.dataclass(frozen=True)
class WindowStencils:
    """Masks of a window's regularizers (NumPy, built once per window).

    Attributes
    ----------
    shape : (rows, cols)
        The window with its halo.
    count : int
        Number of interior texels (the patch's valid texels, where the terms are evaluated).
    interior : (rows, cols) float32
        1 on the interior texels, else 0.
    valid : (rows, cols) float32
        1 on the window's valid texels (the neighbours eq. 35 averages), else 0.
    neighbours : (rows, cols) float32
        Number of valid texels in each texel's 5 x 5 neighbourhood, centre excluded (>= 1).
    """

    shape: tuple
    count: int
    interior: np.ndarray
    valid: np.ndarray
    neighbours: np.ndarray


def _box_sum(values):
    """Sum over each texel's 5 x 5 neighbourhood, centre excluded, zero outside the window.

    ``values``: (..., rows, cols); leading axes are separate maps.
    """
    size = (1,) * (values.ndim - 2) + (BOX, BOX)
    return uniform_filter(values, size=size, mode="constant", cval=0.0) * (BOX * BOX) - values


def window_stencils(valid, patch_rows, patch_cols):
    """Stencils of a window whose ``valid`` (rows, cols) mask covers the patch plus its halo.

    Parameters
    ----------
    valid : (rows, cols) bool
        Valid texels of the window (halo included).
    patch_rows, patch_cols : slice
        Where the patch sits inside the window.
    """
    valid = np.asarray(valid, dtype=bool)
    # float32 masks (0, 1 and counts are exact) keep float32 maps in float32
    interior = np.zeros(valid.shape, np.float32)
    interior[patch_rows, patch_cols] = 1.0
    interior *= valid
    valid_values = valid.astype(np.float32)
    # rounding: the box filter's running sums leave 1e-15 on integer counts
    neighbours = np.maximum(np.rint(_box_sum(valid_values)), 1.0).astype(np.float32)
    return WindowStencils(valid.shape, int(interior.sum()), interior, valid_values, neighbours)


def _as_window(values, stencils):
    """``values`` as (..., rows, cols) maps: flat windows are reshaped; float32 stays float32."""
    values = np.asarray(values)
    if values.dtype not in (np.float32, np.float64):
        values = values.astype(np.float64)
    if values.shape[-2:] == tuple(stencils.shape):
        return values
    return values.reshape(values.shape[:-1] + tuple(stencils.shape))


def _mean_square(residual, stencils):
    """``(sum r^2 / n, 2 / n)`` over the interior (``r`` already zero elsewhere).

    The sum is a float for one map, an array over the leading axes of a stack.
    """
    count = max(stencils.count, 1)
    total = np.sum(residual * residual, axis=(-2, -1), dtype=np.float64) / count
    return (float(total) if total.ndim == 0 else total), 2.0 / count


def displacement_magnitude(height, stencils):
    """``L_Htreg = mean(H^2)`` over the patch's valid texels (eq. 33), mm^2, and its gradient.

    Parameters
    ----------
    height : (rows, cols) or flat array
        The window's displacement, mm (float32 or float64; the gradient has its precision).
    stencils : WindowStencils

    Returns
    -------
    (value, gradient) : float, (rows, cols) array
    """
    H = _as_window(height, stencils)
    residual = stencils.interior * H
    value, scale = _mean_square(residual, stencils)
    return value, scale * residual


_LAPLACIAN_NEIGHBOURS = ((0, -1), (0, 1), (1, -1), (1, 1))


def displacement_laplacian(height, stencils):
    """``L_Hsreg = mean((lap H)^2)`` with the 5-point Laplacian in texels (eq. 34), and its gradient.

    Neighbours beyond the window's edge are clamped to it; a neighbour off the charts
    holds height 0 (the window's displacement is zero there), so the prior ties the relief
    at a chart's edge to the base mesh. That is a prior on the shape, not a measurement:
    with the edge left free instead (only the valid neighbours' ``H_k - H``) the relief's
    error with its level removed was 3-15% larger on six captures (bench/RESULTS.md,
    2026-12-07), and the level it implies is not used
    (:mod:`~polarbssrdf.inverse.polarimetric.relief_level`). Units mm^2; see
    :func:`displacement_magnitude` for parameters and returns.
    """
    H = _as_window(height, stencils)
    laplacian = sum(edge_shift(H, axis, step) for axis, step in _LAPLACIAN_NEIGHBOURS) - 4.0 * H
    residual = stencils.interior * laplacian
    value, scale = _mean_square(residual, stencils)
    adjoint = sum(edge_shift_adjoint(residual, axis, step)
                  for axis, step in _LAPLACIAN_NEIGHBOURS) - 4.0 * residual
    return value, scale * adjoint


def neighbourhood_smoothness(values, stencils):
    """``mean((p - p_bar)^2)``, ``p_bar`` the mean of the valid 5 x 5 neighbours (eq. 35).

    Returns ``(value, gradient)`` in the map's units squared; see
    :func:`displacement_magnitude` for parameters. ``values`` may also be a
    stack of maps (..., rows, cols); the values are then an array.
    """
    p = _as_window(values, stencils)
    mean = _box_sum(stencils.valid * p) / stencils.neighbours
    residual = stencils.interior * (p - mean)
    value, scale = _mean_square(residual, stencils)
    # d p_bar_i / d p_k = valid_k / neighbours_i for k in i's (symmetric) neighbourhood
    adjoint = residual - stencils.valid * _box_sum(residual / stencils.neighbours)
    return value, scale * adjoint
