"""Small CSV tables for the calibration commands (header row, ``#`` comment lines).

Every error names the file and line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarbssrdf.spectral.curves import read_spectra_csv

__all__ = ["read_labelled_table", "read_spectra_table"]


def _rows(path: Path):
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    with open(path, encoding="utf-8") as handle:
        for number, raw in enumerate(handle, start=1):
            line = raw.strip()
            if line and not line.startswith("#"):
                yield number, [field.strip() for field in line.split(",")]


def _numbers(path, number, fields):
    try:
        values = [float(field) for field in fields]
    except ValueError:
        raise ValueError(f"{path}: line {number}: not a number in {','.join(fields)!r}") from None
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: line {number}: values must be finite")
    return values


def read_spectra_table(path, required: tuple[str, ...] | None = None
                       ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``wavelength_nm,<name>,...`` -> (wavelengths (nm), ``{name: values}``), at least 3 rows.

    ``required``: column names that must be present (others are allowed).
    The parsing and its checks are :func:`polarbssrdf.spectral.curves.read_spectra_csv`.
    """
    return read_spectra_csv(path, required=tuple(required or ()), min_rows=3)


def read_labelled_table(path, label: str) -> tuple[list[str], list[str], np.ndarray]:
    """``<label>,<column>,...`` rows of a label and numbers -> (labels, columns, values (N, C))."""
    path = Path(path)
    header, labels, table = None, [], []
    for number, fields in _rows(path):
        if header is None:
            if fields[0].lower() != label or len(fields) < 2:
                raise ValueError(f"{path}: line {number}: header must be '{label},<column>,...', "
                                 f"got {','.join(fields)!r}")
            header = fields[1:]
            continue
        if len(fields) != len(header) + 1:
            raise ValueError(f"{path}: line {number}: expected {len(header) + 1} fields, got {len(fields)}")
        if fields[0] in labels:
            raise ValueError(f"{path}: line {number}: duplicate {label} {fields[0]!r}")
        labels.append(fields[0])
        table.append(_numbers(path, number, fields[1:]))
    if header is None:
        raise ValueError(f"{path}: empty file (expected header '{label},...')")
    if not table:
        raise ValueError(f"{path}: no data lines")
    return labels, header, np.asarray(table)
