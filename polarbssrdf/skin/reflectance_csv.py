"""Reading and writing ``wavelength_nm,reflectance`` CSV files."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np


def read_reflectance_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read ``wavelength_nm,reflectance`` rows (a header line with those names
    is required; ``#`` lines are comments). Returns (wavelengths nm,
    reflectance). Raises ``ValueError`` naming the line on malformed input."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    wavelengths, values = [], []
    header_seen = False
    with open(path, encoding="utf-8") as handle:
        for number, raw in enumerate(handle, start=1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            fields = [f.strip() for f in line.split(",")]
            if not header_seen:
                if [f.lower() for f in fields] != ["wavelength_nm", "reflectance"]:
                    raise ValueError(f"{path}: line {number}: expected header 'wavelength_nm,reflectance', got {line!r}")
                header_seen = True
                continue
            if len(fields) != 2:
                raise ValueError(f"{path}: line {number}: expected 2 fields, got {len(fields)}")
            try:
                wl, value = float(fields[0]), float(fields[1])
            except ValueError:
                raise ValueError(f"{path}: line {number}: not a number in {line!r}") from None
            if not (np.isfinite(wl) and np.isfinite(value)):
                raise ValueError(f"{path}: line {number}: values must be finite")
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{path}: line {number}: reflectance must be in [0, 1], got {value:g}")
            if wavelengths and wl <= wavelengths[-1]:
                raise ValueError(f"{path}: line {number}: wavelengths must increase strictly")
            wavelengths.append(wl)
            values.append(value)
    if not header_seen:
        raise ValueError(f"{path}: empty file, expected header 'wavelength_nm,reflectance'")
    if not wavelengths:
        raise ValueError(f"{path}: no data lines")
    return np.asarray(wavelengths), np.asarray(values)


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
