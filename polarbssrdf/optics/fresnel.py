"""Fresnel equations for a smooth dielectric interface.

Supplement eq. 2 (reflectance), the power transmittance ``T = 1 - R`` (the
supplement's eq. 3 prints amplitude-ratio formulas without the
``eta2 cos(theta2) / (eta1 cos(theta1))`` factor; see ``DESIGN.md`` errata),
the combinations ``F+ = (F_perp + F_par) / 2`` and ``F- = (F_perp - F_par) / 2``
and the average diffuse Fresnel reflectance ``F_dr`` (eq. 12, Egan et al. 1973).

Angles are given through their cosines (dimensionless); ``eta`` is the relative
refractive index ``eta2 / eta1`` of the medium the light enters over the medium
it comes from (``eta > 1``: light enters the denser medium, e.g. air -> skin).
All functions work on floats and on Dr.Jit arrays of any backend.
"""

from __future__ import annotations

from polarbssrdf.optics import _math as xp


def refracted_cosine(cos_theta_i, eta):
    """Cosine of the refraction angle, Snell's law (0 under total internal reflection).

    Parameters
    ----------
    cos_theta_i : float or array
        Cosine of the incidence angle, in [0, 1].
    eta : float or array
        Relative refractive index ``eta2 / eta1``.
    """
    sin2_theta_t = (1.0 - xp.square(cos_theta_i)) / xp.square(eta)
    return xp.safe_sqrt(1.0 - sin2_theta_t)


def fresnel_reflectance(cos_theta_i, eta):
    """Fresnel power reflectances ``(R_perp, R_par)``; supplement eq. 2.

    ``R_perp`` is for light polarized perpendicular to the plane of incidence
    (s), ``R_par`` parallel to it (p). Under total internal reflection
    (``eta < 1`` beyond the critical angle) both are 1.

    Parameters
    ----------
    cos_theta_i : float or array
        Cosine of the incidence angle, in [0, 1].
    eta : float or array
        Relative refractive index ``eta2 / eta1`` (> 0).
    """
    cos_i = xp.clip(cos_theta_i, 0.0, 1.0)
    sin2_theta_t = (1.0 - xp.square(cos_i)) / xp.square(eta)
    total_internal = sin2_theta_t >= 1.0
    cos_t = xp.safe_sqrt(1.0 - sin2_theta_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_par = (cos_t - eta * cos_i) / (cos_t + eta * cos_i)
    R_perp = xp.select(total_internal, 1.0, xp.square(r_perp))
    R_par = xp.select(total_internal, 1.0, xp.square(r_par))
    return R_perp, R_par


def normal_incidence_reflectance(eta):
    """``F0 = ((eta - 1) / (eta + 1))^2``: eq. 2 at ``theta_i = 0`` (both polarizations), unitless.

    Parameters
    ----------
    eta : float or array
        Relative refractive index ``eta2 / eta1`` (> 0).
    """
    return xp.square((eta - 1.0) / (eta + 1.0))


def fresnel_transmittance(cos_theta_i, eta):
    """Fresnel power transmittances ``(T_perp, T_par) = (1 - R_perp, 1 - R_par)``.

    This replaces the supplement's eq. 3, which prints amplitude ratios; the
    power transmittance is what energy conservation and Mitsuba's
    ``mueller.specular_transmission`` use. It is reciprocal: the value for the
    external angle with ``eta`` equals the value for the internal angle with
    ``1 / eta``.
    """
    R_perp, R_par = fresnel_reflectance(cos_theta_i, eta)
    return 1.0 - R_perp, 1.0 - R_par


def plus_minus(F_perp, F_par):
    """``(F+, F-) = ((F_perp + F_par) / 2, (F_perp - F_par) / 2)``; supplement sec. 2.2.

    For transmission ``T- <= 0`` (p-polarized light is transmitted better).
    """
    return 0.5 * (F_perp + F_par), 0.5 * (F_perp - F_par)


def reflection_phase_cosine(cos_theta_i, eta):
    """``cos(delta)`` of the reflection retardance for external reflection (``eta > 1``).

    Supplement eq. 1: ``delta = pi`` below Brewster's angle and 0 above it, so
    ``cos(delta)`` is the sign of the p amplitude ``(cos_t - eta cos_i)``; it is
    -1 at normal incidence, which makes a mirror flip the handedness of
    circular and the sign of diagonal polarization.
    """
    cos_i = xp.clip(cos_theta_i, 0.0, 1.0)
    cos_t = refracted_cosine(cos_i, eta)
    return xp.select(cos_t - eta * cos_i < 0.0, -1.0, 1.0)


def brewster_angle(eta):
    """Brewster's angle ``arctan(eta)`` in radians, where ``R_par = 0``."""
    return xp.atan(eta)


def average_diffuse_fresnel_reflectance(eta):
    """Average (hemispherical, cosine-weighted) Fresnel reflectance ``F_dr``; eq. 12.

    Polynomial fits of Egan et al. (1973) as given by the supplement, for a
    relative index ``eta`` of the medium the diffuse light is *in* over the
    outside (for skin under air: ``eta = 1.4`` gives ``F_dr`` of light inside
    skin reflected back at its surface).
    """
    inv = 1.0 / eta
    below = -0.4399 + 0.7099 * inv - 0.3319 * xp.square(inv) + 0.0636 * inv * xp.square(inv)
    above = -1.440 * xp.square(inv) + 0.710 * inv + 0.668 + 0.0636 * eta
    return xp.select(eta < 1.0, below, above)
