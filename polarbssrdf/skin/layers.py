"""Biophysical parameters -> optical coefficients of the two layers
(Donner et al. 2008 form). Units: 1/mm. Arguments broadcast (texels x wavelengths)."""

from __future__ import annotations

import numpy as np

from . import chromophores as ch


def epidermis_absorption(wavelength_nm, C_m, beta_m, C_h_out, gamma=0.75):
    """sigma_a of the epidermis (1/mm), Donner et al. 2008:

    C_m (beta_m sigma_em + (1 - beta_m) sigma_pm)
      + C_h_out (gamma sigma_oxy + (1 - gamma) sigma_deoxy)
      + (1 - C_m - C_h_out) sigma_baseline.
    """
    wl = ch.check_wavelengths(wavelength_nm)
    C_m, beta_m, C_h_out = (np.asarray(x, dtype=float) for x in (C_m, beta_m, C_h_out))
    melanin = beta_m * ch.eumelanin_absorption(wl) + (1.0 - beta_m) * ch.pheomelanin_absorption(wl)
    return C_m * melanin + C_h_out * ch.blood_absorption(wl, gamma) + (1.0 - C_m - C_h_out) * ch.baseline_absorption(wl)


def dermis_absorption(wavelength_nm, C_h_in, gamma=0.75):
    """sigma_a of the dermis (1/mm): C_h_in sigma_blood + (1 - C_h_in) sigma_baseline."""
    wl = ch.check_wavelengths(wavelength_nm)
    C_h_in = np.asarray(C_h_in, dtype=float)
    return C_h_in * ch.blood_absorption(wl, gamma) + (1.0 - C_h_in) * ch.baseline_absorption(wl)


def chromophore_basis(wavelength_nm, gamma=0.75) -> dict[str, np.ndarray]:
    """The spectra the layer absorptions are linear in (1/mm), for fast models:
    eumelanin, pheomelanin, blood (at this gamma), oxy- and deoxyhemoglobin
    (for another gamma: :func:`blood_from_basis`), baseline, and the reduced
    scattering of both layers."""
    wl = ch.check_wavelengths(wavelength_nm)
    return {
        "eumelanin": ch.eumelanin_absorption(wl),
        "pheomelanin": ch.pheomelanin_absorption(wl),
        "blood": ch.blood_absorption(wl, gamma),
        "oxyhemoglobin": ch.oxyhemoglobin_absorption(wl),
        "deoxyhemoglobin": ch.deoxyhemoglobin_absorption(wl),
        "baseline": ch.baseline_absorption(wl),
        "scattering_epidermis": ch.epidermis_reduced_scattering(wl),
        "scattering_dermis": ch.dermis_reduced_scattering(wl),
    }


def blood_from_basis(basis, gamma=None):
    """Whole-blood absorption (1/mm) of a :func:`chromophore_basis` at oxygen fraction ``gamma``:
    ``gamma sigma_oxy + (1 - gamma) sigma_deoxy`` (Donner et al. 2008), the samples on
    the last axis; ``gamma`` None (or a basis without the two hemoglobins): the basis's
    own ``blood``. An array ``gamma`` (e.g. a map) gets the sample axis appended."""
    if gamma is None or "oxyhemoglobin" not in basis:
        return np.asarray(basis["blood"], dtype=float)
    gamma = np.asarray(gamma, dtype=float)[..., None]
    return gamma * basis["oxyhemoglobin"] + (1.0 - gamma) * basis["deoxyhemoglobin"]


def absorption_from_basis(basis, C_m, beta_m, C_h_out, C_h_in, gamma=None):
    """(sigma_a epidermis, sigma_a dermis) from a :func:`chromophore_basis`
    (or its band averages, or the nodes of a spectral quadrature); same formulas as
    the two functions above. ``gamma`` (scalar or per texel): the blood's oxygen
    fraction, else the basis's own blood (:func:`blood_from_basis`)."""
    C_m, beta_m, C_h_out, C_h_in = (np.asarray(x, dtype=float)[..., None] for x in (C_m, beta_m, C_h_out, C_h_in))
    return layer_absorption(basis["eumelanin"], basis["pheomelanin"], blood_from_basis(basis, gamma),
                            basis["baseline"], C_m, beta_m, C_h_out, C_h_in)


def layer_absorption(eumelanin, pheomelanin, blood, baseline, C_m, beta_m, C_h_out, C_h_in):
    """(sigma_a epidermis, sigma_a dermis) in 1/mm from the chromophore
    absorptions of one sample (or arrays that broadcast with the parameters):
    the formulas of :func:`epidermis_absorption` and :func:`dermis_absorption`.
    Plain arithmetic, so it also runs on Dr.Jit arrays (with autodiff)."""
    epi = C_m * (beta_m * eumelanin + (1.0 - beta_m) * pheomelanin) + C_h_out * blood + (1.0 - C_m - C_h_out) * baseline
    der = C_h_in * blood + (1.0 - C_h_in) * baseline
    return epi, der
