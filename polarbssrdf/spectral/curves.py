"""Sampled spectral curves (wavelengths in nm) on top of colour-science.

A "curve" accepted by these functions is any of: a
``colour.SpectralDistribution``, a ``(wavelengths_nm, values)`` pair, or a
callable ``f(wavelengths_nm) -> values``.
"""

from __future__ import annotations

import numpy as np
from colour import SpectralDistribution, SpectralShape


def spectral_distribution(wavelengths_nm, values, name: str = "curve") -> SpectralDistribution:
    """A colour-science ``SpectralDistribution`` from samples (nm, any unit)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    v = np.asarray(values, dtype=float)
    if wl.ndim != 1 or v.shape != wl.shape or wl.size < 2:
        raise ValueError("a spectral curve needs matching 1-D wavelength and value arrays of length >= 2")
    if np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths must increase strictly")
    return SpectralDistribution(dict(zip(wl.tolist(), v.tolist())), name=name)


def wavelength_grid(start_nm: float = 400.0, end_nm: float = 700.0, step_nm: float = 5.0) -> np.ndarray:
    """Inclusive regular grid, via ``colour.SpectralShape``."""
    if step_nm <= 0 or end_nm < start_nm:
        raise ValueError(f"bad wavelength grid {start_nm}:{end_nm}:{step_nm}")
    return np.asarray(SpectralShape(start_nm, end_nm, step_nm).wavelengths, dtype=float)


def sample_curve(curve, wavelengths_nm) -> np.ndarray:
    """Values of ``curve`` at ``wavelengths_nm``: linear interpolation, zero
    outside the curve's own wavelength range (a filter or a light has no
    output where it was not measured)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    if isinstance(curve, SpectralDistribution):
        src_wl, src_v = np.asarray(curve.wavelengths), np.asarray(curve.values)
    elif isinstance(curve, tuple) and len(curve) == 2:
        src_wl, src_v = (np.asarray(x, dtype=float) for x in curve)
    elif callable(curve):
        return np.broadcast_to(np.asarray(curve(wl), dtype=float), wl.shape).copy()
    else:
        raise ValueError(f"not a spectral curve: {type(curve).__name__}")
    return np.interp(wl, src_wl, src_v, left=0.0, right=0.0)


def gaussian_curve(center_nm: float, fwhm_nm: float, peak: float = 1.0):
    """A Gaussian band shape as a callable curve (nm)."""
    sigma = fwhm_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    return lambda wl: peak * np.exp(-0.5 * ((np.asarray(wl, dtype=float) - center_nm) / sigma) ** 2)


def comb_curve(period_nm: float, phase_nm: float, low: float = 0.02, high: float = 0.95, sharpness: float = 4.0):
    """A smooth comb (multi-bandpass) filter transmittance, peaks at
    phase + m * period; ``sharpness`` squares the raised cosine into
    narrower teeth. Its complement is :func:`complementary_curve`."""

    def curve(wl):
        c = 0.5 + 0.5 * np.cos(2.0 * np.pi * (np.asarray(wl, dtype=float) - phase_nm) / period_nm)
        shaped = c**sharpness / (c**sharpness + (1.0 - c) ** sharpness)
        return low + (high - low) * shaped

    return curve


def complementary_curve(curve, low: float = 0.02, high: float = 0.95):
    """The comb whose teeth sit in the gaps of ``curve``: low + high - curve."""
    return lambda wl: low + high - curve(wl)
