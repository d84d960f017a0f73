"""Diffuse degree of polarization: Atkinson & Hancock (2006) against Fresnel transmission."""

import numpy as np
import pytest

from polarbssrdf.optics import diffuse_degree_of_polarization, fresnel_transmittance, plus_minus


@pytest.mark.parametrize("eta", [1.3, 1.4, 1.5, 1.7])
def test_atkinson_hancock_equals_fresnel_transmission_ratio(eta):
    """AH's closed form is |T-| / T+ of the exit transmission, computed from the inside."""
    theta = np.linspace(0.0, np.deg2rad(89.0), 200)
    # Light leaves skin: internal angle from Snell, relative index 1/eta.
    theta_inside = np.arcsin(np.sin(theta) / eta)
    T_plus, T_minus = plus_minus(*fresnel_transmittance(np.cos(theta_inside), 1.0 / eta))
    np.testing.assert_allclose(diffuse_degree_of_polarization(eta, theta),
                               np.abs(T_minus) / T_plus, atol=1e-12)


def test_dop_is_zero_at_normal_and_grows_with_zenith():
    theta = np.linspace(0, np.deg2rad(85), 50)
    dop = diffuse_degree_of_polarization(1.4, theta)
    assert dop[0] == pytest.approx(0.0, abs=1e-15)
    assert np.all(np.diff(dop) > 0)
    # a higher index polarizes more
    assert np.all(diffuse_degree_of_polarization(1.6, theta[1:]) > dop[1:])
