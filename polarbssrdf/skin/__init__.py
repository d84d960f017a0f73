"""Layered skin optics (supplement sections 2.5 and 5.3).

Chromophore spectra, biophysical parameters -> layer coefficients, the
multipole profiles and totals of a slab (eq. 9-12, 42), the two-layer
combination (eq. 15, 47), sums of Gaussians (eq. 16-17, 43) and the
inversion of eq. 41. Units: mm, nm, 1/mm.
"""

from .chromophores import (
    baseline_absorption,
    blood_absorption,
    deoxyhemoglobin_absorption,
    dermis_reduced_scattering,
    epidermis_reduced_scattering,
    eumelanin_absorption,
    hemoglobin_wavelength_range,
    oxyhemoglobin_absorption,
    pheomelanin_absorption,
    read_extinction_csv,
)
from .inversion import InversionResult, fit_spectrum, invert_bands, invert_spectra
from .layers import dermis_absorption, epidermis_absorption
from .model import band_reflectance, reflectance_spectra, skin_reflectance_spectrum
from .multipole import (
    classical_dipole_profile,
    diffuse_fresnel_reflectance,
    dipole_profile,
    slab_profiles,
    slab_reflectance_transmittance,
    slab_totals,
    slab_totals_poles,
)
from .parameters import TABLE2, SkinParameters, table2_ranges
from .reflectance_csv import read_reflectance_csv
from .sog import discrete_kernel, fit_sog, normalized_weights, sog_profile, sog_relative_error, variance_ladder
from .twolayer import LayerTotals, layer_totals, two_layer_profile, two_layer_total, two_layer_total_from_coefficients

__all__ = [
    "baseline_absorption", "blood_absorption", "deoxyhemoglobin_absorption", "dermis_reduced_scattering",
    "epidermis_reduced_scattering", "eumelanin_absorption", "hemoglobin_wavelength_range",
    "oxyhemoglobin_absorption", "pheomelanin_absorption", "read_extinction_csv", "InversionResult",
    "fit_spectrum", "invert_bands", "invert_spectra", "dermis_absorption", "epidermis_absorption",
    "band_reflectance", "reflectance_spectra", "skin_reflectance_spectrum", "classical_dipole_profile",
    "diffuse_fresnel_reflectance",
    "dipole_profile", "slab_profiles", "slab_reflectance_transmittance", "slab_totals", "slab_totals_poles",
    "TABLE2", "SkinParameters", "table2_ranges", "read_reflectance_csv", "discrete_kernel", "fit_sog",
    "normalized_weights", "sog_profile", "sog_relative_error", "variance_ladder", "LayerTotals", "layer_totals",
    "two_layer_profile", "two_layer_total", "two_layer_total_from_coefficients",
]
