"""Degree of polarization of diffuse reflection (Atkinson & Hancock 2006).

Light scattered below the surface leaves depolarized and is partially
polarized by Fresnel transmission out of the surface, parallel to the plane
of emission. Its DoP depends only on the relative index ``eta`` and the
emission (zenith) angle; the supplement uses it in the refractive-index loss
(eq. 29-30).
"""

from __future__ import annotations

from polarbssrdf.optics import _math as xp


def diffuse_degree_of_polarization(eta, theta):
    """DoP of diffuse reflection, Atkinson & Hancock (2006), eq. 18.

        rho = (eta - 1/eta)^2 sin^2 theta /
              (2 + 2 eta^2 - (eta + 1/eta)^2 sin^2 theta + 4 cos theta sqrt(eta^2 - sin^2 theta))

    It equals ``|T-| / T+`` of the power transmittances at the emission angle.

    Parameters
    ----------
    eta : float or array
        Relative refractive index of the surface (> 1).
    theta : float or array
        Zenith angle of the emitted (viewing) direction, radians, in [0, pi/2].
    """
    sin2 = xp.square(xp.sin(theta))
    cos_theta = xp.cos(theta)
    numerator = xp.square(eta - 1.0 / eta) * sin2
    denominator = (2.0 + 2.0 * xp.square(eta) - xp.square(eta + 1.0 / eta) * sin2
                   + 4.0 * cos_theta * xp.sqrt(xp.square(eta) - sin2))
    return numerator / denominator
