"""Sobolev-preconditioned gradients of the maps: long wavelengths move as fast as short ones.

The static and dynamic stages step every texel by RMSProp, which moves a
texel by about its learning rate whatever the gradient. A map's long
wavelengths (the relief's bowl and slant over the face, a roughness level
shared by a cheek) then converge slowly: the data term's gradient of a
smooth change is small per texel and shares each texel's step with the
texel-scale misfit, whose sign changes from texel to texel. On the demo's
face the relief reached half the truth's amplitude in 150 epochs, and 400
epochs took its error from 0.68 to 0.51 of the constant map's
(bench/RESULTS.md, 2026-12-07): the relief's "flattening" was the
optimizer stopping short, not the data.

The remedy is the Sobolev gradient (Neuberger, *Sobolev Gradients and
Differential Equations*, Springer 1997, ch. 2): the gradient of the loss in
the ``H^1`` inner product ``<x, y> = x^T (I + lambda L) y`` instead of the
Euclidean one, ``g_S = (I + lambda L)^-1 g``, with ``L`` the 5-point graph
Laplacian of the texel grid and ``lambda = length^2`` in texels^2. A
wavelength ``w`` texels long keeps ``1 / (1 + lambda (2 pi / w)^2)`` of its
gradient (approximately): texel-scale detail is damped, the face-scale
shape passes whole, and RMSProp's normalization then gives every scale a
comparable step. It is the preconditioner Nicolet, Jacobson and Jakob apply
to mesh vertices in "Large Steps in Inverse Rendering of Geometry" (ACM
Trans. Graph. 40(6), 248, 2021), here on a texture grid and applied to the
gradient (one solve per step) rather than by re-parameterizing the map.

The minimum is unchanged: the preconditioner is symmetric positive definite
(and so is its restriction to the texels on the mesh, where alone ``g`` is
non-zero), so ``g_S = 0`` exactly where ``g = 0``. Only the path and its
speed change.

The solve is exact on a patch's window (a rectangle of texels) with
reflecting (Neumann) edges, by the type-II discrete cosine transform, which
diagonalizes that Laplacian (Strang, "The Discrete Cosine Transform", SIAM
Review 41(1), 1999, sec. 3): ``O(n log n)`` for ``n`` texels, bounded by the
patch as every other per-step array is. Texels off the mesh carry no
gradient; the smoothed gradient is zeroed there again.
"""

from __future__ import annotations

import numpy as np
from scipy.fft import dctn, idctn


def neumann_laplacian_eigenvalues(shape):
    """Eigenvalues ``(rows, cols)`` of the 5-point graph Laplacian with reflecting edges on a
    ``(rows, cols)`` grid, in the type-II DCT's basis: ``(2 - 2 cos(pi k / rows)) + (2 - 2
    cos(pi l / cols))``, 1 / texel^2 (0 for the constant)."""
    rows, cols = int(shape[0]), int(shape[1])
    along_rows = 2.0 - 2.0 * np.cos(np.pi * np.arange(rows) / rows)
    along_cols = 2.0 - 2.0 * np.cos(np.pi * np.arange(cols) / cols)
    return along_rows[:, None] + along_cols[None, :]


def sobolev_gradient(gradient, length, valid=None):
    """``(I + length^2 L)^-1 gradient`` on a texel grid (the module docstring).

    Parameters
    ----------
    gradient : (rows, cols) array
        The loss's Euclidean gradient on a window of texels (any unit).
    length : float
        Smoothing length in texels (>= 0); 0 returns the gradient unchanged.
    valid : (rows, cols) bool or 0/1 array, optional
        Texels that carry a map value; the result is zeroed elsewhere.

    Returns
    -------
    (rows, cols) float64 array, in the gradient's unit.
    """
    gradient = np.asarray(gradient, np.float64)
    if gradient.ndim != 2:
        raise ValueError(f"sobolev_gradient needs a (rows, cols) window, got shape {gradient.shape}")
    if not np.isfinite(length) or length < 0:
        raise ValueError(f"sobolev_gradient: length must be a finite number >= 0, got {length!r}")
    if length == 0:
        smoothed = gradient.copy()
    else:
        spectrum = dctn(gradient, type=2, norm="ortho")
        spectrum /= 1.0 + float(length) ** 2 * neumann_laplacian_eigenvalues(gradient.shape)
        smoothed = idctn(spectrum, type=2, norm="ortho")
    if valid is not None:
        smoothed *= np.asarray(valid, np.float64)
    return smoothed


__all__ = ["neumann_laplacian_eigenvalues", "sobolev_gradient"]
