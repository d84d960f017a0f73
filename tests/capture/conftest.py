"""Synthetic Stokes scenes for the polarization camera tests."""

from types import SimpleNamespace

import numpy as np
import pytest

from polarbssrdf.capture import channel_name
from polarbssrdf.optics.stokes import (
    ANALYSER_ANGLES_DEG,
    angle_of_linear_polarization,
    degree_of_linear_polarization,
    polarization_images,
    stokes_from_polarization_images,
)

COLOUR_GAINS = {"": 1.0, "R": 1.0, "G": 0.7, "B": 0.45}
"""Per-colour scale of S0..S2, so that colour channels differ."""


def linear_stokes(s0, dolp, aolp_deg):
    """``(S0, S1, S2)`` of light with this intensity, DoLP and AoLP (degrees)."""
    angle = np.deg2rad(aolp_deg)
    return s0, s0 * dolp * np.cos(2 * angle), s0 * dolp * np.sin(2 * angle)


def disk_scene(size=128, supersampling=4):
    """An anti-aliased disk: S0 1.0, DoLP 0.6, AoLP 30 deg inside; 0.3, 0.3, -50 deg outside."""
    n = size * supersampling
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / supersampling
    inside = ((x - size / 2 - 3.3) ** 2 + (y - size / 2 + 1.7) ** 2 < (0.3 * size) ** 2)
    cover = inside.astype(float).reshape(size, supersampling, size, supersampling).mean(axis=(1, 3))
    fill, background = linear_stokes(1.0, 0.6, 30.0), linear_stokes(0.3, 0.3, -50.0)
    return tuple(cover * f + (1 - cover) * b for f, b in zip(fill, background))


def sphere_scene(size=128):
    """A rendered-like sphere: shading with the normal's z, DoLP rising toward the limb,
    AoLP along the normal's image-plane azimuth (as for specular polarization)."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    u, v = (x - size / 2) / (0.42 * size), -(y - size / 2) / (0.42 * size)
    radius2 = u * u + v * v
    on_sphere = radius2 < 1
    nz = np.sqrt(np.clip(1 - radius2, 0, 1))
    s0 = np.where(on_sphere, 0.2 + 0.8 * nz, 0.05)
    dolp = np.where(on_sphere, 0.7 * (1 - nz) ** 1.5, 0.0)
    return linear_stokes(s0, dolp, np.rad2deg(np.arctan2(v, u)))


def smooth_scene(size=64):
    """A low-frequency Stokes field (periods of 60-90 px, DoLP below 0.4)."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    s0 = 1.0 + 0.3 * np.sin(2 * np.pi * x / 64) * np.cos(2 * np.pi * y / 80)
    dolp = 0.25 + 0.1 * np.cos(2 * np.pi * (x + y) / 90)
    aolp = 40 * np.sin(2 * np.pi * x / 70) + 20 * np.cos(2 * np.pi * y / 60)
    return linear_stokes(s0, dolp, aolp)


def analyser_images_of(stokes, layout):
    """Channel name -> analyser image for every colour of ``layout`` (eq. 21)."""
    images = {}
    for colour in layout.colour_names:
        scaled = tuple(COLOUR_GAINS[colour] * s for s in stokes) + (0.0,)
        for angle, image in zip(ANALYSER_ANGLES_DEG, polarization_images(scaled)):
            images[channel_name(angle, colour)] = np.asarray(image, dtype=np.float64)
    return images


def stokes_errors(truth, estimate, layout, border):
    """Per colour: PSNR of S0 (dB, peak = max true S0) and mean |AoLP error| (degrees)
    over pixels with true DoLP > 0.1, both inside a ``border``-pixel margin."""
    crop = (slice(border, -border), slice(border, -border))
    errors = {}
    for colour in layout.colour_names:
        def stokes(images):
            return stokes_from_polarization_images(
                *(images[channel_name(a, colour)][crop] for a in ANALYSER_ANGLES_DEG))
        true_s, est_s = stokes(truth), stokes(estimate)
        psnr = 10 * np.log10(true_s[0].max() ** 2 / np.mean((est_s[0] - true_s[0]) ** 2))
        difference = (angle_of_linear_polarization(est_s[1], est_s[2])
                      - angle_of_linear_polarization(true_s[1], true_s[2]))
        wrapped = np.abs((difference + np.pi / 2) % np.pi - np.pi / 2)
        polarized = degree_of_linear_polarization(*true_s) > 0.1
        errors[colour] = (psnr, float(np.rad2deg(wrapped[polarized].mean())))
    return errors


@pytest.fixture
def kit():
    """The scene builders and metrics above, for the tests of this directory."""
    return SimpleNamespace(disk=disk_scene, sphere=sphere_scene, smooth=smooth_scene,
                           analyser_images=analyser_images_of, errors=stokes_errors,
                           linear_stokes=linear_stokes)
