"""Forward skin model: biophysical parameters -> total diffuse reflectance
(eq. 47) per wavelength or per band. Parameter arrays broadcast over any
leading shape (e.g. texels); the wavelength/band axis is appended last.
"""

from __future__ import annotations

import numpy as np

from ..spectral.bands import Band, band_weights_matrix
from .chromophores import DEFAULT_REFRACTIVE_INDEX, check_wavelengths
from .layers import absorption_from_basis, chromophore_basis
from .parameters import SkinParameters
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
                           eta=DEFAULT_REFRACTIVE_INDEX, dtype=np.float64, chunk_texels=None, workers=2):
    """Total diffuse reflectance (eq. 47, unitless) for chromophore spectra
    (or band averages) ``basis`` of :func:`~.layers.chromophore_basis`.
    Output shape: broadcast(parameters, thickness, eta) + (n_samples,).

    Texels are processed in cache-sized chunks on ``workers`` threads (by
    default about 12,000 values per array, below glibc's 128 KiB mmap
    threshold: larger temporaries are page-faulted afresh on every NumPy
    operation and make the kernel 2-3x slower); each
    chunk is :func:`~.layers.absorption_from_basis` followed by
    :func:`~.twolayer.two_layer_total_kernel` (pure array functions)."""
    from concurrent.futures import ThreadPoolExecutor

    params = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta)))
    check_parameter_arrays(*params)
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
        cm, bm, cho, chi, d, e = (x[start:stop].astype(dtype) for x in flat)
        sa_out, sa_in = absorption_from_basis(small, cm, bm, cho, chi)
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


def reflectance_spectra(C_m, beta_m, C_h_out, C_h_in, wavelengths_nm, gamma=DEFAULT_GAMMA,
                        thickness_mm=DEFAULT_THICKNESS_MM, eta=DEFAULT_REFRACTIVE_INDEX):
    """Total diffuse reflectance spectra (unitless), shape params + (n_wl,).
    Wavelengths in nm within the hemoglobin table (400-700 nm)."""
    basis = chromophore_basis(check_wavelengths(np.atleast_1d(wavelengths_nm)), gamma)
    return reflectance_from_basis(basis, C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta)


def skin_reflectance_spectrum(params: SkinParameters, wavelengths_nm) -> np.ndarray:
    """Total diffuse reflectance (eq. 47) of one skin over wavelengths (nm)."""
    return reflectance_spectra(params.C_m, params.beta_m, params.C_h_out, params.C_h_in, wavelengths_nm,
                               params.gamma, params.thickness_mm, params.eta)


def band_chromophore_basis(bands: list[Band], gamma=DEFAULT_GAMMA) -> dict[str, np.ndarray]:
    """Band averages of the chromophore absorption and scattering spectra
    (1/mm), one value per band: the 'band-effective' optical coefficients
    (absorption is linear in the parameters, so these are exact band
    averages of sigma_a; the reflectance computed from them is an
    approximation of the band-averaged reflectance)."""
    key = (tuple((b.name, b.wavelengths_nm.tobytes(), b.weights.tobytes()) for b in bands), float(gamma))
    if key not in _BAND_BASIS_CACHE:
        if len(_BAND_BASIS_CACHE) > 32:
            _BAND_BASIS_CACHE.clear()
        _BAND_BASIS_CACHE[key] = _band_basis(list(bands), float(gamma))
    return _BAND_BASIS_CACHE[key]


_BAND_BASIS_CACHE: dict = {}


def _band_basis(bands: list, gamma: float):
    grid = np.unique(np.concatenate([b.wavelengths_nm for b in bands]))
    spectra = chromophore_basis(check_wavelengths(grid), gamma)
    matrix = band_weights_matrix(bands, grid)
    return {name: matrix @ values for name, values in spectra.items()}


def band_reflectance(C_m, beta_m, C_h_out, C_h_in, bands: list[Band], method: str = "effective",
                     gamma=DEFAULT_GAMMA, thickness_mm=DEFAULT_THICKNESS_MM, eta=DEFAULT_REFRACTIVE_INDEX):
    """Per-band total diffuse reflectance, shape params + (n_bands,).

    method="effective": eq. 47 evaluated once per band with band-averaged
    coefficients (fast; what a per-band renderer does).
    method="exact": the band average int R(l) B(l) dl / int B(l) dl of the
    spectral reflectance (slower by the number of wavelengths).
    """
    if method == "effective":
        basis = band_chromophore_basis(bands, gamma)
        return reflectance_from_basis(basis, C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta)
    if method == "exact":
        grid = np.unique(np.concatenate([b.wavelengths_nm for b in bands]))
        spectra = reflectance_spectra(C_m, beta_m, C_h_out, C_h_in, grid, gamma, thickness_mm, eta)
        return spectra @ band_weights_matrix(bands, grid).T
    raise ValueError(f"method must be 'effective' or 'exact', got {method!r}")
