"""Reading and writing ``wavelength_nm,reflectance`` CSV files."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from polarbssrdf.spectral.curves import read_curve_csv


def read_reflectance_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read ``wavelength_nm,reflectance`` rows (a header line with those names
    is required; ``#`` lines are comments). Returns (wavelengths nm,
    reflectance). Raises ``ValueError`` naming the line on malformed input."""
    def in_unit_range(values):
        value = values[0]
        return None if 0.0 <= value <= 1.0 else f"reflectance must be in [0, 1], got {value:g}"

    wavelengths, table = read_curve_csv(path, ("reflectance",), check_row=in_unit_range)
    return wavelengths, table[:, 0]


def format_reflectance_csv(wavelengths_nm, reflectance) -> str:
    """CSV text with header ``wavelength_nm,reflectance``."""
    out = io.StringIO()
    out.write("wavelength_nm,reflectance\n")
    for wl, value in zip(np.asarray(wavelengths_nm, dtype=float), np.asarray(reflectance, dtype=float)):
        out.write(f"{wl:g},{value:.6f}\n")
    return out.getvalue()


def parse_wavelength_range(text: str) -> np.ndarray:
    """'start:stop:step' (nm, inclusive stop) or a comma list -> array."""
    text = text.strip()
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) != 3:
                raise ValueError
            start, stop, step = parts
            if step <= 0 or stop < start:
                raise ValueError
            count = int(np.floor((stop - start) / step + 1e-9)) + 1
            return start + step * np.arange(count)
        values = np.asarray([float(x) for x in text.split(",")])
    except ValueError:
        raise ValueError(f"bad wavelengths {text!r}: use start:stop:step (e.g. 400:700:5) or a comma list") from None
    if values.size == 0 or np.any(np.diff(values) <= 0):
        raise ValueError(f"bad wavelengths {text!r}: must increase strictly")
    return values
