"""Sampled spectral curves and bands (camera response x filter x light),
band integration; colour-science glue. Wavelengths in nm."""

from .bands import (
    Band,
    band_average,
    band_weights_matrix,
    bandpass_bands,
    bands_from_json,
    bands_to_json,
    comb_filter_pair,
    comb_pair_bands,
    default_bands,
    default_camera_responses,
    default_filters,
    default_light,
    make_band,
    read_bands,
    shipped_default_bands,
)
from .curves import comb_curve, complementary_curve, gaussian_curve, sample_curve, spectral_distribution, wavelength_grid

__all__ = [
    "Band", "band_average", "band_weights_matrix", "bandpass_bands", "bands_from_json", "bands_to_json",
    "comb_filter_pair", "comb_pair_bands", "default_bands",
    "default_camera_responses", "default_filters", "default_light", "make_band", "read_bands",
    "shipped_default_bands", "comb_curve",
    "complementary_curve", "gaussian_curve", "sample_curve", "spectral_distribution", "wavelength_grid",
]
