"""Small dense linear algebra over many matrices at once (one k x k system per texel)."""

from __future__ import annotations

import numpy as np


def batched_spd_inverse(matrices):
    """Inverse of each symmetric positive-definite ``(..., k, k)`` matrix, by Cholesky.

    ``L L^T = A``, ``W = L^-1``, ``A^-1 = W^T W``, with the loops over the k x k
    entries unrolled in Python and each entry one NumPy array over the batch:
    for the 3-6 parameters a texel has, NumPy's batched ``inv`` is a LAPACK call
    per matrix, 1.5-5x slower on 12,000 4 x 4 matrices
    (bench/bench_spd_inverse.py, bench/RESULTS.md, 2026-12-07). Cholesky needs no
    pivoting on a positive-definite matrix and is backward stable for it whatever
    its scaling. A matrix whose Cholesky meets a
    pivot that is not positive and finite (not positive definite to working
    precision) is inverted by ``numpy.linalg.inv`` instead, so the result is
    never worse than NumPy's.

    Parameters
    ----------
    matrices : (..., k, k) array_like
        Symmetric; only the lower triangle is read.

    Returns
    -------
    (..., k, k) float64.
    """
    A = np.asarray(matrices, np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"need (..., k, k) matrices, got shape {A.shape}")
    k = A.shape[-1]
    entries = np.moveaxis(A, (-2, -1), (0, 1))
    L = [[None] * k for _ in range(k)]
    inverse_pivot = [None] * k
    singular = np.zeros(entries.shape[2:], bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(k):
            pivot = entries[j, j].copy()
            for m in range(j):
                pivot -= L[j][m] * L[j][m]
            singular |= ~(pivot > 0) | ~np.isfinite(pivot)
            L[j][j] = np.sqrt(pivot)
            inverse_pivot[j] = 1.0 / L[j][j]
            for i in range(j + 1, k):
                column = entries[i, j].copy()
                for m in range(j):
                    column -= L[i][m] * L[j][m]
                L[i][j] = column * inverse_pivot[j]
        W = [[None] * k for _ in range(k)]  # L^-1, lower triangular
        for i in range(k):
            W[i][i] = inverse_pivot[i]
            for j in range(i):
                total = L[i][j] * W[j][j]
                for m in range(j + 1, i):
                    total = total + L[i][m] * W[m][j]
                W[i][j] = -total * inverse_pivot[i]
        out = np.empty((k, k) + entries.shape[2:])
        for i in range(k):
            for j in range(i + 1):
                total = W[i][i] * W[i][j]
                for m in range(i + 1, k):
                    total = total + W[m][i] * W[m][j]
                out[i, j] = total
                out[j, i] = total
    out = np.moveaxis(out, (0, 1), (-2, -1))
    if singular.any():
        out[singular] = np.linalg.inv(A[singular])
    return out
