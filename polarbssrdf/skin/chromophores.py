"""Spectral absorption and scattering of the skin chromophores.

Units: wavelengths in nm, coefficients in 1/mm. Every function broadcasts
over NumPy arrays of wavelengths and never mutates its input.

Sources (supplement section 2.5 and 5.3, Donner et al. 2008 skin model):

* oxy-/deoxy-hemoglobin: molar extinction tabulated by S. Prahl (OMLC),
  vendored as ``data/hemoglobin_molar_extinction_prahl.csv`` (400-700 nm at
  5 nm), converted with 150 g/L and 64,500 g/mol;
* eumelanin 6.6e10 lambda^-3.33, pheomelanin 2.9e14 lambda^-4.75 (1/mm);
* baseline skin 0.0244 + 8.53 exp(-(lambda - 154)/66.2) (1/mm);
* reduced scattering: Donner & Jensen 2006 ("A spectral BSSRDF for shading
  human skin", EGSR), see :func:`epidermis_reduced_scattering`.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path

import numpy as np

from polarbssrdf.spectral.curves import read_curve_csv

HEMOGLOBIN_CONCENTRATION_G_PER_L = 150.0
HEMOGLOBIN_MOLAR_MASS_G_PER_MOL = 64500.0
DEFAULT_REFRACTIVE_INDEX = 1.4
HEMOGLOBIN_CSV = "hemoglobin_molar_extinction_prahl.csv"


def read_extinction_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a ``wavelength_nm,oxyhemoglobin,deoxyhemoglobin`` CSV.

    Lines starting with ``#`` are provenance comments. Returns
    ``(wavelength_nm, eps_oxy, eps_deoxy)`` with the extinction in
    cm^-1 / (mol/L) (decadic). Raises ``ValueError`` naming the offending
    line for a missing header, a wrong field count, a non-number, a negative
    value or wavelengths that are not strictly increasing.
    """
    wavelengths, table = read_curve_csv(
        path, ("oxyhemoglobin", "deoxyhemoglobin"),
        check_row=lambda values: "values must be finite and >= 0" if min(values) < 0 else None)
    if len(wavelengths) < 2:
        raise ValueError(f"{path}: need a header and at least two data lines")
    return wavelengths, table[:, 0], table[:, 1]


@functools.lru_cache(maxsize=1)
def hemoglobin_extinction_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vendored Prahl table: (wavelength nm, eps_oxy, eps_deoxy) in cm^-1/M."""
    with resources.as_file(resources.files("polarbssrdf.skin") / "data" / HEMOGLOBIN_CSV) as path:
        return read_extinction_csv(path)


def hemoglobin_wavelength_range() -> tuple[float, float]:
    """(min, max) wavelength in nm covered by the hemoglobin table."""
    wl = hemoglobin_extinction_table()[0]
    return float(wl[0]), float(wl[-1])


def check_wavelengths(wavelength_nm) -> np.ndarray:
    """Return wavelengths as a float array; ``ValueError`` outside the data range."""
    wl = np.asarray(wavelength_nm, dtype=float)
    lo, hi = hemoglobin_wavelength_range()
    if wl.size and (not np.all(np.isfinite(wl)) or wl.min() < lo or wl.max() > hi):
        raise ValueError(
            f"wavelengths must lie in the hemoglobin data range {lo:g}-{hi:g} nm, "
            f"got {wl.min():g}-{wl.max():g} nm"
        )
    return wl


def molar_extinction_to_absorption(epsilon_cm_per_molar) -> np.ndarray:
    """Whole-blood absorption coefficient (1/mm) from decadic molar extinction.

    mu_a = ln(10) * eps [cm^-1/M] * 150 g/L / 64,500 g/mol  (1/cm), / 10 -> 1/mm.
    """
    eps = np.asarray(epsilon_cm_per_molar, dtype=float)
    return np.log(10.0) * eps * HEMOGLOBIN_CONCENTRATION_G_PER_L / HEMOGLOBIN_MOLAR_MASS_G_PER_MOL / 10.0


def oxyhemoglobin_absorption(wavelength_nm) -> np.ndarray:
    """Absorption of fully oxygenated whole blood (1/mm), linear in the table."""
    wl = check_wavelengths(wavelength_nm)
    table_wl, eps_oxy, _ = hemoglobin_extinction_table()
    return molar_extinction_to_absorption(np.interp(wl, table_wl, eps_oxy))


def deoxyhemoglobin_absorption(wavelength_nm) -> np.ndarray:
    """Absorption of fully deoxygenated whole blood (1/mm), linear in the table."""
    wl = check_wavelengths(wavelength_nm)
    table_wl, _, eps_deoxy = hemoglobin_extinction_table()
    return molar_extinction_to_absorption(np.interp(wl, table_wl, eps_deoxy))


def blood_absorption(wavelength_nm, gamma=0.75) -> np.ndarray:
    """gamma sigma_oxy + (1 - gamma) sigma_deoxy (1/mm); gamma = oxygen fraction."""
    return gamma * oxyhemoglobin_absorption(wavelength_nm) + (1.0 - gamma) * deoxyhemoglobin_absorption(wavelength_nm)


def eumelanin_absorption(wavelength_nm) -> np.ndarray:
    """Eumelanin absorption 6.6e10 lambda^-3.33 (1/mm, lambda in nm)."""
    return 6.6e10 * np.asarray(wavelength_nm, dtype=float) ** -3.33


def pheomelanin_absorption(wavelength_nm) -> np.ndarray:
    """Pheomelanin absorption 2.9e14 lambda^-4.75 (1/mm, lambda in nm)."""
    return 2.9e14 * np.asarray(wavelength_nm, dtype=float) ** -4.75


def baseline_absorption(wavelength_nm) -> np.ndarray:
    """Chromophore-free skin absorption 0.0244 + 8.53 exp(-(lambda-154)/66.2) (1/mm)."""
    wl = np.asarray(wavelength_nm, dtype=float)
    return 0.0244 + 8.53 * np.exp(-(wl - 154.0) / 66.2)


def epidermis_reduced_scattering(wavelength_nm) -> np.ndarray:
    """Reduced scattering of the epidermis (1/mm).

    Donner & Jensen 2006 (EGSR, "A spectral BSSRDF for shading human skin"),
    the scattering used by the Donner et al. 2008 layered model the paper
    follows: a Mie-like plus a Rayleigh term,
    sigma_s'(lambda) = 14.74 lambda^-0.22 + 2.2e11 lambda^-4  (1/mm, lambda in nm),
    i.e. about 7.3 /mm at 500 nm, so a 0.25 mm epidermis is ~1.8 mean free paths.
    """
    wl = np.asarray(wavelength_nm, dtype=float)
    return 14.74 * wl**-0.22 + 2.2e11 * wl**-4.0


def dermis_reduced_scattering(wavelength_nm) -> np.ndarray:
    """Reduced scattering of the dermis (1/mm): half of the epidermis value.

    Donner & Jensen 2006 take the dermis scattering as 0.5 x the epidermis
    scattering of :func:`epidermis_reduced_scattering` (about 3.6 /mm at 500 nm,
    in the range of Jacques 2013's dermis power laws).
    """
    return 0.5 * epidermis_reduced_scattering(wavelength_nm)
