"""Stokes images, DoLP, AoLP and the coaxial separations from analyser images.

Thin per-colour wrappers around :mod:`polarbssrdf.optics.stokes` (eq. 21)
and :func:`polarbssrdf.optics.coaxial.separate_observations` (eq. 22-24), so
that demosaicked images (``I0``, ... or ``I0.R``, ...) give named product
images with the same colour suffixes.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from polarbssrdf.capture.layout import SensorLayout, channel_name
from polarbssrdf.capture.mosaic import check_analyser_images
from polarbssrdf.optics.coaxial import separate_observations
from polarbssrdf.optics.stokes import (
    ANALYSER_ANGLES_DEG,
    angle_of_linear_polarization,
    degree_of_linear_polarization,
    stokes_from_polarization_images,
)

__all__ = ["PRODUCT_NAMES", "polarization_products"]

PRODUCT_NAMES = ("S0", "S1", "S2", "DoLP", "AoLP", "I_sss", "I_zeta", "I_s")
"""Products per colour: linear Stokes, DoLP (0-1), AoLP (radians, (-pi/2, pi/2],
counter-clockwise from image right) and the separations ``I_sss = 2 I90``,
``I_zeta = I135 - I45``, ``I_s = I0 - I90`` (light polarized along image x)."""


def polarization_products(images: Mapping[str, np.ndarray], layout: SensorLayout
                          ) -> dict[str, np.ndarray]:
    """Stokes, DoLP, AoLP and separation images of every colour of ``layout``.

    Parameters
    ----------
    images:
        Analyser images (linear radiance), e.g. from
        :func:`polarbssrdf.capture.demosaic.demosaic`; negative values from
        noise are accepted.
    layout:
        Gives the colour names; products are suffixed like the inputs
        (``S0`` or ``S0.R``, ...).

    Returns
    -------
    dict
        ``<product><suffix>`` -> H x W float64 array for each name in
        :data:`PRODUCT_NAMES`.
    """
    check_analyser_images(images, layout, allow_negative=True)
    products = {}
    for colour in layout.colour_names:
        suffix = f".{colour}" if colour else ""
        analysers = [np.asarray(images[channel_name(a, colour)], dtype=np.float64)
                     for a in ANALYSER_ANGLES_DEG]
        S0, S1, S2 = stokes_from_polarization_images(*analysers)
        I_sss, I_zeta, I_s = separate_observations(*analysers)
        values = {"S0": S0, "S1": S1, "S2": S2,
                  "DoLP": degree_of_linear_polarization(S0, S1, S2),
                  "AoLP": angle_of_linear_polarization(S1, S2),
                  "I_sss": I_sss, "I_zeta": I_zeta, "I_s": I_s}
        products.update({name + suffix: values[name] for name in PRODUCT_NAMES})
    return products
