"""Analyser images and Stokes parameters (supplement sec. 2.1, eq. 21-24)."""

import numpy as np
import pytest

from polarbssrdf.optics import (
    analyser_intensity,
    angle_of_linear_polarization,
    degree_of_linear_polarization,
    polarization_images,
    separate_observations,
    stokes_from_polarization_images,
)


def test_malus_law(rng):
    """A fully polarized beam at angle psi behind an analyser at theta gives cos^2(theta - psi)."""
    psi = rng.uniform(-np.pi, np.pi, 1000)
    stokes = (np.ones_like(psi), np.cos(2 * psi), np.sin(2 * psi), np.zeros_like(psi))
    for theta in np.deg2rad([0, 30, 45, 90, 135]):
        np.testing.assert_allclose(analyser_intensity(stokes, theta), np.cos(theta - psi) ** 2,
                                   atol=1e-12)


def test_round_trip_and_dolp_aolp(rng):
    S0 = rng.uniform(0.1, 2.0, 500)
    dolp = rng.uniform(0.0, 1.0, 500)
    aolp = rng.uniform(-np.pi / 2, np.pi / 2, 500)
    S1, S2 = S0 * dolp * np.cos(2 * aolp), S0 * dolp * np.sin(2 * aolp)
    images = polarization_images((S0, S1, S2, 0 * S0))
    np.testing.assert_allclose(images[0] + images[2], S0)  # I0 + I90
    np.testing.assert_allclose(images[1] + images[3], S0)  # I45 + I135
    back = stokes_from_polarization_images(*images)
    np.testing.assert_allclose(back, (S0, S1, S2), atol=1e-12)
    np.testing.assert_allclose(degree_of_linear_polarization(*back), dolp, atol=1e-12)
    np.testing.assert_allclose(angle_of_linear_polarization(back[1], back[2]), aolp, atol=1e-9)


def test_separations_follow_the_design_conventions():
    """I_s = I0 - I90 = S1, I_zeta = I135 - I45 = -S2, I_sss = 2 I90 (DESIGN conventions)."""
    S0, S1, S2 = 1.0, 0.3, -0.2
    I0, I45, I90, I135 = polarization_images((S0, S1, S2, 0.0))
    I_sss, I_zeta, I_s = separate_observations(I0, I45, I90, I135)
    assert I_s == pytest.approx(S1)
    assert I_zeta == pytest.approx(-S2)
    assert I_sss == pytest.approx(S0 - S1)


def test_unpolarized_light_has_zero_dolp():
    assert degree_of_linear_polarization(np.array([1.0]), np.array([0.0]), np.array([0.0]))[0] == 0
    assert degree_of_linear_polarization(np.array([0.0]), np.array([0.0]), np.array([0.0]))[0] == 0
