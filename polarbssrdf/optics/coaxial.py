"""Coaxial image formation and the separations of the supplement (eq. 19-24).

A light polarized along image x shines from (next to) the camera. Per pixel,
with ``phi`` the azimuth of the surface normal projected into the image plane
(radians, counter-clockwise from image right), ``S = cos(theta_i) / Gamma^2``
the shading, and the Fresnel terms at the (common) zenith angle ``theta``:

    S0 = S [ kappa R+ + (rho_sss / pi) (T+ T+ - T- T+ xi) ]
    S1 = S [ kappa R+ - (rho_sss / pi) (T- T+ xi - T- T- xi^2) ]
    S2 = S [         - (rho_sss / pi) (T- T+ zeta - T- T- xi zeta) ]

with ``kappa = kappa_s + kappa_ss``, ``xi = cos 2 phi``, ``zeta = sin 2 phi``
(eq. 19; the supplement drops the second-order ``T- T-`` terms, which the
exact functions here keep and the ``first_order=True`` option drops).
The subsurface sum over entry points of eq. 19 becomes the local albedo
``rho_sss`` (the supplement's ``rho_bar_sss``, sec. 5.1); the texture-space
diffusion of a later stage replaces it by the diffused exitance.

Exactly coaxial light and view make ``theta_d = 0``, so ``R- = 0`` and the
specular lobes stay polarized along the light's axis: ``I90`` holds no
specular light at all.
"""

from __future__ import annotations

from polarbssrdf.optics import _math as xp

from polarbssrdf.optics.fresnel import fresnel_reflectance, fresnel_transmittance, plus_minus
from polarbssrdf.optics.microfacet import microfacet_reflection_term


def coaxial_fresnel_terms(cos_theta, eta):
    """``(R+, T+, T-)`` for coaxial light and view at zenith cosine ``cos_theta``.

    ``R+`` is taken at ``theta_d = 0`` (the half vector is the view direction).
    """
    R_plus, _ = plus_minus(*fresnel_reflectance(1.0, eta))
    T_plus, T_minus = plus_minus(*fresnel_transmittance(cos_theta, eta))
    return R_plus, T_plus, T_minus


def coaxial_kappa(cos_theta, albedo, alpha):
    """``kappa`` (1/sr) of a microfacet lobe for coaxial light and view (eq. 19).

    With ``wi = wo`` the half vector is the view direction: ``theta_h = theta``
    and ``theta_d = 0``.
    """
    return microfacet_reflection_term(albedo, cos_theta, cos_theta, cos_theta, 1.0, alpha)


def coaxial_stokes(cos_theta, phi, eta, rho_s, alpha_s, rho_ss, alpha_ss, rho_sss,
                   shading=1.0, first_order=False):
    """Stokes vector ``(S0, S1, S2, S3)`` in the image frame for coaxial light; eq. 19.

    Parameters
    ----------
    cos_theta : float or array
        Cosine of the zenith angle of the (common) light and view direction.
    phi : float or array
        Azimuth of the normal's projection in the image plane, radians,
        counter-clockwise from image right.
    eta, rho_s, alpha_s, rho_ss, alpha_ss, rho_sss : float or array
        pBRDF parameters (see :mod:`polarbssrdf.optics.pbrdf`).
    shading : float or array
        ``S = cos(theta_i) I_light / Gamma^2`` (radiance scale).
    first_order : bool
        Drop the ``T- T-`` terms as the supplement's eq. 19 does.
    """
    R_plus, T_plus, T_minus = coaxial_fresnel_terms(cos_theta, eta)
    kappa = coaxial_kappa(cos_theta, rho_s, alpha_s) + coaxial_kappa(cos_theta, rho_ss, alpha_ss)
    xi, zeta = xp.cos(2.0 * phi), xp.sin(2.0 * phi)
    diffuse = rho_sss * xp.inv_pi
    second = 0.0 if first_order else T_minus * T_minus
    S0 = kappa * R_plus + diffuse * (T_plus * T_plus - T_minus * T_plus * xi)
    S1 = kappa * R_plus - diffuse * (T_minus * T_plus * xi - second * xi * xi)
    S2 = -diffuse * (T_minus * T_plus * zeta - second * xi * zeta)
    return shading * S0, shading * S1, shading * S2, 0.0 * S0


def subsurface_observation(I90):
    """``I_sss = 2 I90``: the unpolarized subsurface image (eq. 22)."""
    return 2.0 * I90


def subsurface_polarization_observation(I45, I135):
    """``I_zeta = I135 - I45``: the subsurface polarization image (eq. 23)."""
    return I135 - I45


def specular_polarization_observation(I0, I90):
    """``I_s = I0 - I90``: the specular-dominant polarization image (eq. 24)."""
    return I0 - I90


def separate_observations(I0, I45, I90, I135):
    """``(I_sss, I_zeta, I_s)`` from the four analyser images (eq. 22-24)."""
    return (subsurface_observation(I90),
            subsurface_polarization_observation(I45, I135),
            specular_polarization_observation(I0, I90))
