"""Eq. 47 from a chromophore basis: the two-layer skin's total diffuse reflectance at the basis's
samples (wavelengths, band averages or quadrature nodes), and the parameter checks.

Below both :mod:`.model` (per wavelength and per band) and :mod:`.quadrature` (whose nodes are
chosen by this reflectance), so that neither imports the other.
"""

from __future__ import annotations

import numpy as np

from .chromophores import DEFAULT_REFRACTIVE_INDEX
from .layers import absorption_from_basis
from .twolayer import boundary_terms, two_layer_total_kernel

DEFAULT_GAMMA = 0.75
#: Values per array in the chunked kernels (float64: 96 KiB, under the mmap threshold).
CHUNK_VALUES = 12288
DEFAULT_THICKNESS_MM = 0.25


def check_parameter_arrays(C_m, beta_m, C_h_out, C_h_in, thickness_mm=DEFAULT_THICKNESS_MM,
                           eta=DEFAULT_REFRACTIVE_INDEX) -> None:
    """The array form of :class:`SkinParameters` validation: ``ValueError``
    naming the field if a fraction is outside [0, 1] (or not finite),
    C_m + C_h_out > 1, or thickness / eta <= 0."""
    for name, value in (("C_m", C_m), ("beta_m", beta_m), ("C_h_out", C_h_out), ("C_h_in", C_h_in)):
        value = np.asarray(value, dtype=float)
        if not np.all((value >= 0.0) & (value <= 1.0)):
            raise ValueError(f"{name} must be a fraction in [0, 1] (found {np.nanmin(value):g} .. {np.nanmax(value):g}"
                             f"{', NaN' if np.isnan(value).any() else ''})")
    if np.any(np.asarray(C_m) + np.asarray(C_h_out) > 1.0):
        raise ValueError("C_m + C_h_out must be <= 1 (epidermis volume fractions)")
    if not np.all(np.asarray(thickness_mm, dtype=float) > 0):
        raise ValueError("thickness_mm must be > 0")
    if not np.all(np.asarray(eta, dtype=float) > 0):
        raise ValueError("eta must be > 0")


def reflectance_from_basis(basis, C_m, beta_m, C_h_out, C_h_in, thickness_mm=DEFAULT_THICKNESS_MM,
                           eta=DEFAULT_REFRACTIVE_INDEX, dtype=np.float64, chunk_texels=None, workers=2,
                           gamma=None):
    """Total diffuse reflectance (eq. 47, unitless) for chromophore spectra
    (or band averages, or quadrature nodes) ``basis`` of :func:`~.layers.chromophore_basis`.
    Output shape: broadcast(parameters, thickness, eta, gamma) + (n_samples,).
    ``gamma``: the blood's oxygen fraction per texel (None: the basis's own blood).

    Texels are processed in cache-sized chunks on ``workers`` threads (by
    default about 12,000 values per array, below glibc's 128 KiB mmap
    threshold: larger temporaries are page-faulted afresh on every NumPy
    operation and make the kernel 2-3x slower); each
    chunk is :func:`~.layers.absorption_from_basis` followed by
    :func:`~.twolayer.two_layer_total_kernel` (pure array functions)."""
    from concurrent.futures import ThreadPoolExecutor

    gamma_given = gamma is not None
    params = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (
        C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta, DEFAULT_GAMMA if gamma is None else gamma)))
    check_parameter_arrays(*params[:6])
    if gamma_given and not np.all((params[6] >= 0.0) & (params[6] <= 1.0)):
        raise ValueError("gamma must be an oxygen fraction in [0, 1]")
    shape = params[0].shape
    flat = [np.ravel(x) for x in params]
    n = flat[0].size
    n_samples = np.asarray(basis["eumelanin"]).shape[-1]
    if chunk_texels is None:
        chunk_texels = max(64, CHUNK_VALUES // n_samples)
    out = np.empty((n, n_samples), dtype=dtype)
    sc_out = np.asarray(basis["scattering_epidermis"], dtype=dtype)
    sc_in = np.asarray(basis["scattering_dermis"], dtype=dtype)
    small = {k: np.asarray(v, dtype=dtype) for k, v in basis.items()}

    uniform_eta = bool(np.all(flat[5] == flat[5][0]))
    if uniform_eta:  # the usual case: boundary constants once, as scalars
        uniform_terms = {k: dtype(v) for k, v in boundary_terms(float(flat[5][0])).items()}

    def run(start):
        stop = min(start + chunk_texels, n)
        cm, bm, cho, chi, d, e, g = (x[start:stop].astype(dtype) for x in flat)
        sa_out, sa_in = absorption_from_basis(small, cm, bm, cho, chi, g if gamma_given else None)
        if uniform_eta:
            terms = uniform_terms
        else:  # eta_in = eta_out
            terms = {k: np.asarray(v, dtype=dtype) for k, v in boundary_terms(e[:, None]).items()}
        out[start:stop] = two_layer_total_kernel(sa_out, sc_out, sa_in, sc_in, d[:, None], terms)

    starts = range(0, n, chunk_texels)
    if workers > 1 and n > chunk_texels:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(run, starts))
    else:
        for start in starts:
            run(start)
    return out.reshape(shape + (n_samples,))
