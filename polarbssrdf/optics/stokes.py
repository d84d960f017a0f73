"""Stokes vectors and the four-angle linear analyser of a polarization camera.

Supplement sec. 2.1 (Stokes vectors) and eq. 21 (the analyser). Image Stokes
frame (Mitsuba's ``stokes`` integrator): x = image right, y = image up, and
an analyser at angle ``theta`` (counter-clockwise from image right) measures

    I(theta) = (S0 + S1 cos 2 theta + S2 sin 2 theta) / 2.

Stokes vectors are tuples ``(S0, S1, S2, S3)`` of floats or arrays, so the
same code runs on NumPy images and on Dr.Jit texel arrays.
"""

from __future__ import annotations

import math

from polarbssrdf.optics import _math as xp

ANALYSER_ANGLES_DEG = (0, 45, 90, 135)
"""Analyser angles of a division-of-focal-plane polarization camera, in degrees."""


def linear_analyser_row(theta):
    """First row of the Mueller matrix of a linear polarizer at angle ``theta`` (radians).

    ``I = row . S`` is the intensity behind an ideal analyser (eq. 21).
    """
    return (0.5, 0.5 * math.cos(2.0 * theta), 0.5 * math.sin(2.0 * theta), 0.0)


def analyser_intensity(stokes, theta):
    """Intensity behind an ideal linear analyser at ``theta`` radians from image right."""
    row = linear_analyser_row(theta)
    return row[0] * stokes[0] + row[1] * stokes[1] + row[2] * stokes[2]


def polarization_images(stokes):
    """``(I0, I45, I90, I135)`` seen through analysers at 0/45/90/135 degrees; eq. 21."""
    S0, S1, S2 = stokes[0], stokes[1], stokes[2]
    return (0.5 * (S0 + S1), 0.5 * (S0 + S2), 0.5 * (S0 - S1), 0.5 * (S0 - S2))


def stokes_from_polarization_images(I0, I45, I90, I135):
    """Linear Stokes components ``(S0, S1, S2)`` from the four analyser images.

    ``S0`` averages both estimates ``I0 + I90`` and ``I45 + I135``. (The
    circular component is not observable with linear analysers.)
    """
    S0 = 0.5 * (I0 + I45 + I90 + I135)
    return S0, I0 - I90, I45 - I135


def degree_of_linear_polarization(S0, S1, S2, eps=1e-12):
    """DoLP ``sqrt(S1^2 + S2^2) / S0`` (0 where ``S0 <= eps``)."""
    dolp = xp.sqrt(xp.square(S1) + xp.square(S2)) / xp.maximum(S0, eps)
    return xp.select(S0 > eps, dolp, 0.0)


def degree_of_polarization(S0, S1, S2, S3, eps=1e-12):
    """DoP ``psi = sqrt(S1^2 + S2^2 + S3^2) / S0``; supplement sec. 2.1."""
    dop = xp.sqrt(xp.square(S1) + xp.square(S2) + xp.square(S3)) / xp.maximum(S0, eps)
    return xp.select(S0 > eps, dop, 0.0)


def angle_of_linear_polarization(S1, S2):
    """AoLP ``atan2(S2, S1) / 2`` in radians, in (-pi/2, pi/2], from image right."""
    return 0.5 * xp.atan2(S2, S1)
