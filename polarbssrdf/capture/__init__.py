"""The polarization camera: filter layouts, mosaic, noise, demosaicking, products.

Forward: analyser images ``I0, I45, I90, I135`` (per colour) ->
:func:`mosaic_images` -> :func:`simulate_raw` (shot and read noise, 12-bit
DN). Back: :func:`radiance_from_raw` -> :func:`demosaic` (bilinear or
intensity-guided residual interpolation) -> :func:`polarization_products`
(Stokes, DoLP, AoLP and the separations of eq. 22-24). See docs/capture.md.
"""

from polarbssrdf.capture.demosaic import (
    DEMOSAICKING_METHODS,
    demosaic,
    demosaic_bilinear,
    demosaic_residual,
    intensity_guides,
)
from polarbssrdf.capture.guided_filter import masked_guided_filter
from polarbssrdf.capture.interpolation import lattice_kernel, normalized_convolution
from polarbssrdf.capture.layout import IMX250MYR, IMX250MZR, SensorLayout, channel_name
from polarbssrdf.capture.mosaic import check_analyser_images, mosaic_images
from polarbssrdf.capture.noise import (
    SensorNoise,
    expected_raw_mean,
    expected_raw_variance,
    radiance_from_raw,
    simulate_raw,
)
from polarbssrdf.capture.products import PRODUCT_NAMES, polarization_products

__all__ = [
    "DEMOSAICKING_METHODS",
    "IMX250MYR",
    "IMX250MZR",
    "PRODUCT_NAMES",
    "SensorLayout",
    "SensorNoise",
    "channel_name",
    "check_analyser_images",
    "demosaic",
    "demosaic_bilinear",
    "demosaic_residual",
    "expected_raw_mean",
    "expected_raw_variance",
    "intensity_guides",
    "lattice_kernel",
    "masked_guided_filter",
    "mosaic_images",
    "normalized_convolution",
    "polarization_products",
    "radiance_from_raw",
    "simulate_raw",
]
