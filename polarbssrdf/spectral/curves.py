"""Sampled spectral curves (wavelengths in nm) on top of colour-science.

A "curve" accepted by these functions is any of: a
``colour.SpectralDistribution``, a ``(wavelengths_nm, values)`` pair, or a
callable ``f(wavelengths_nm) -> values``.

colour-science is imported by the functions that need it, not by this
module: importing it costs about a second and changes NumPy's print options
for the whole process.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from colour import SpectralDistribution


def spectral_distribution(wavelengths_nm, values, name: str = "curve") -> SpectralDistribution:
    """A colour-science ``SpectralDistribution`` from samples (nm, any unit)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    v = np.asarray(values, dtype=float)
    if wl.ndim != 1 or v.shape != wl.shape or wl.size < 2:
        raise ValueError("a spectral curve needs matching 1-D wavelength and value arrays of length >= 2")
    if np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths must increase strictly")
    from colour import SpectralDistribution

    return SpectralDistribution(dict(zip(wl.tolist(), v.tolist())), name=name)


def wavelength_grid(start_nm: float = 400.0, end_nm: float = 700.0, step_nm: float = 5.0) -> np.ndarray:
    """Inclusive regular grid, via ``colour.SpectralShape``."""
    if step_nm <= 0 or end_nm < start_nm:
        raise ValueError(f"bad wavelength grid {start_nm}:{end_nm}:{step_nm}")
    from colour import SpectralShape

    return np.asarray(SpectralShape(start_nm, end_nm, step_nm).wavelengths, dtype=float)


def _is_spectral_distribution(curve) -> bool:
    """Whether ``curve`` is a colour-science ``SpectralDistribution``, without importing colour."""
    # Such an object can only exist once colour-science has been imported.
    colour = sys.modules.get("colour")
    return colour is not None and isinstance(curve, colour.SpectralDistribution)


def sample_curve(curve, wavelengths_nm) -> np.ndarray:
    """Values of ``curve`` at ``wavelengths_nm``: linear interpolation, zero
    outside the curve's own wavelength range (a filter or a light has no
    output where it was not measured)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    if _is_spectral_distribution(curve):
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


def read_spectra_csv(path, required=(), exact=None, check_row=None, min_rows=1):
    """Read a table of spectra: header ``wavelength_nm,<name>,...``, one row per wavelength.

    ``#`` lines are comments (provenance). Every error names the file and,
    where it applies, the line: header (unique, non-empty names; exactly
    ``exact`` if given; containing ``required``), field count, numbers,
    finite values, strictly increasing wavelengths, ``check_row(values)``
    (an error message or None, for the values after the wavelength), and at
    least ``min_rows`` data rows.

    Returns
    -------
    (wavelength_nm, {name: values})
    """
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    names, rows = None, []
    with open(path, encoding="utf-8") as handle:
        for number, raw in enumerate(handle, start=1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            fields = [f.strip() for f in line.split(",")]
            if names is None:
                names = _spectra_header(path, number, line, fields, required, exact)
                continue
            if len(fields) != len(names) + 1:
                raise ValueError(f"{path}: line {number}: expected {len(names) + 1} fields, "
                                 f"got {len(fields)}")
            try:
                values = [float(f) for f in fields]
            except ValueError:
                raise ValueError(f"{path}: line {number}: not a number in {line!r}") from None
            if not np.all(np.isfinite(values)):
                raise ValueError(f"{path}: line {number}: values must be finite")
            if rows and values[0] <= rows[-1][0]:
                raise ValueError(f"{path}: line {number}: wavelengths must increase strictly")
            problem = check_row(values[1:]) if check_row is not None else None
            if problem:
                raise ValueError(f"{path}: line {number}: {problem}")
            rows.append(values)
    if names is None:
        raise ValueError(f"{path}: empty file, expected a header 'wavelength_nm,<name>,...'")
    if not rows:
        raise ValueError(f"{path}: no data lines")
    if len(rows) < min_rows:
        raise ValueError(f"{path}: needs at least {min_rows} data rows, got {len(rows)}")
    table = np.asarray(rows, dtype=float)
    return table[:, 0], {name: table[:, i + 1] for i, name in enumerate(names)}


def _spectra_header(path, number, line, fields, required, exact):
    expected = None if exact is None else ["wavelength_nm", *exact]
    if expected is not None and [f.lower() for f in fields] != expected:
        raise ValueError(f"{path}: line {number}: expected header {','.join(expected)!r}, "
                         f"got {line!r}")
    if fields[0].lower() != "wavelength_nm" or len(fields) < 2:
        raise ValueError(f"{path}: line {number}: header must be 'wavelength_nm,<name>,...', "
                         f"got {line!r}")
    names = fields[1:] if expected is None else list(exact)
    if len(set(names)) != len(names) or any(not name for name in names):
        raise ValueError(f"{path}: line {number}: column names must be unique and non-empty")
    missing = [name for name in required if name not in names]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (header: {line})")
    return names


def read_curve_csv(path, columns, check_row=None):
    """Tabulated curves with exactly the header ``wavelength_nm,<columns...>`` (see :func:`read_spectra_csv`).

    Returns
    -------
    (wavelength_nm, values)
        1-D array (nm) and an array (rows, len(columns)).
    """
    wavelengths, table = read_spectra_csv(path, exact=tuple(columns), check_row=check_row)
    return wavelengths, np.stack([table[name] for name in columns], axis=1)
