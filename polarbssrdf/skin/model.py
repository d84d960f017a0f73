"""Forward skin model: biophysical parameters -> total diffuse reflectance
(eq. 47) per wavelength or per band. Parameter arrays broadcast over any
leading shape (e.g. texels); the wavelength/band axis is appended last.
"""

from __future__ import annotations

import numpy as np

from ..spectral.bands import Band, band_weights_matrix
from .chromophores import DEFAULT_REFRACTIVE_INDEX, check_wavelengths
from .layers import chromophore_basis
from .parameters import SkinParameters
from .quadrature import quadrature_reflectance, spectral_quadrature
from .reflectance import (  # re-exported: the per-wavelength and per-band models build on them
    DEFAULT_GAMMA,
    DEFAULT_THICKNESS_MM,
    check_parameter_arrays,
    reflectance_from_basis,
)



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


def band_reflectance(C_m, beta_m, C_h_out, C_h_in, bands: list[Band], method: str = "integral",
                     gamma=DEFAULT_GAMMA, thickness_mm=DEFAULT_THICKNESS_MM, eta=DEFAULT_REFRACTIVE_INDEX):
    """Per-band total diffuse reflectance, shape params + (n_bands,).

    method="integral" (default): the band integral int R(l) B(l) dl / int B(l) dl a
    camera records, by the spectral quadrature of
    :func:`~.quadrature.band_integral_quadrature` (relative error under 0.2% of the
    1 nm integral over its design box).
    method="exact": the same integral by the trapezoid rule on the bands' own sample
    grid (slower by the number of wavelengths).
    method="effective": eq. 47 evaluated once per band with band-averaged
    coefficients (:func:`~.quadrature.band_effective_quadrature`): an approximation,
    10-19% off the integral in some bands.
    ``gamma``, ``thickness_mm`` and ``eta`` broadcast with the chromophores (maps or scalars).
    """

    if method in ("integral", "effective"):
        return quadrature_reflectance(spectral_quadrature(bands, method), C_m, beta_m, C_h_out, C_h_in, gamma,
                                      thickness_mm, eta)
    if method == "exact":
        grid = np.unique(np.concatenate([b.wavelengths_nm for b in bands]))
        basis = chromophore_basis(check_wavelengths(grid))
        spectra = reflectance_from_basis(basis, C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta, gamma=gamma)
        return spectra @ band_weights_matrix(bands, grid).T
    raise ValueError(f"method must be 'integral', 'exact' or 'effective', got {method!r}")
