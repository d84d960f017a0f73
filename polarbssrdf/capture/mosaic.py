"""The forward sampling of a polarization filter array: analyser images -> raw mosaic.

Each pixel of a division-of-focal-plane sensor sees the scene through one
linear analyser (and one colour filter), so the raw mosaic takes, at every
pixel, the value of the analyser image its filter selects. Values stay in the
units of the input (linear radiance); :mod:`polarbssrdf.capture.noise` turns
them into digital numbers.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from polarbssrdf.capture.layout import SensorLayout, channel_name
from polarbssrdf.optics.stokes import ANALYSER_ANGLES_DEG

__all__ = ["check_analyser_images", "mosaic_images"]


def check_analyser_images(images: Mapping[str, np.ndarray], layout: SensorLayout,
                          allow_negative: bool = False) -> tuple[int, int]:
    """Check that ``images`` holds every analyser image of ``layout``; return ``(H, W)``.

    Parameters
    ----------
    images:
        Channel name (``I0``, ``I45``, ... or ``I0.R``, ... for colour
        layouts, see :attr:`SensorLayout.channel_names`) -> H x W real array.
        Extra channels (``S0``, ...) are ignored.
    layout:
        The sensor layout the images are meant for.
    allow_negative:
        Accept negative values (demosaicked noisy data may dip below zero).

    Raises
    ------
    ValueError
        Naming the problem: a missing channel, a channel that is not 2-D,
        channels of different shapes, sizes that are not a multiple of the
        period, non-finite or (unless allowed) negative values.
    """
    missing = [name for name in layout.channel_names if name not in images]
    if missing:
        raise ValueError(f"analyser images for layout {layout.name!r} lack channels "
                         f"{missing} (got {sorted(images)})")
    shape = None
    for name in layout.channel_names:
        values = np.asarray(images[name])
        if values.ndim != 2:
            raise ValueError(f"channel {name} must be a 2-D H x W array, got shape {values.shape}")
        if shape is None:
            shape = values.shape
        elif values.shape != shape:
            raise ValueError(f"channel {name} has shape {values.shape}, but "
                             f"{layout.channel_names[0]} has shape {shape}")
        if not np.issubdtype(values.dtype, np.number) or np.iscomplexobj(values):
            raise ValueError(f"channel {name} must hold real numbers, got dtype {values.dtype}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"channel {name} has {np.count_nonzero(~np.isfinite(values))} "
                             "NaN or infinite values")
        if not allow_negative and np.any(values < 0):
            raise ValueError(f"channel {name} has negative intensities "
                             f"(minimum {values.min():g}); radiance cannot be negative")
    return layout.check_shape(shape, what="analyser images")


def mosaic_images(images: Mapping[str, np.ndarray], layout: SensorLayout) -> np.ndarray:
    """The raw mosaic that ``layout`` records from per-pixel analyser images.

    Parameters
    ----------
    images:
        Channel name -> H x W array of linear radiance (any consistent
        unit) behind each analyser; see :func:`check_analyser_images`.
    layout:
        The filter layout; H and W must be multiples of its period.

    Returns
    -------
    numpy.ndarray
        H x W float64 mosaic, in the units of the input: pixel ``(y, x)``
        holds ``images[channel_name(angle, colour)][y, x]`` for the analyser
        angle and colour of that pixel.
    """
    shape = check_analyser_images(images, layout)
    raw = np.empty(shape, dtype=np.float64)
    for angle in ANALYSER_ANGLES_DEG:
        for colour in layout.colour_names:
            mask = layout.sample_mask(shape, angle, colour)
            raw[mask] = np.asarray(images[channel_name(angle, colour)], dtype=np.float64)[mask]
    return raw
