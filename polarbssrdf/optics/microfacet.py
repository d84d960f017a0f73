"""GGX microfacet distribution and Smith masking-shadowing.

Supplement eq. 5-6 use the GGX distribution (Walter et al. 2007) and Smith's
geometric attenuation (Heitz 2014). We use the *separable* Smith form
``G = G1(wi) G1(wo)``, the form of Mitsuba's ``MicrofacetDistribution`` and so
of its ``pplastic``, which is our independent reference. ``alpha`` is the
GGX roughness (the width parameter itself, not its square root).
"""

from __future__ import annotations

from polarbssrdf.optics import _math as xp


def ggx_distribution(cos_theta_h, alpha):
    """GGX normal distribution ``D(theta_h; alpha)`` in 1/sr (projected-area normalized).

    ``D = alpha^2 / (pi (cos^2(theta_h) (alpha^2 - 1) + 1)^2)``, zero for
    microfacet normals below the surface.

    Parameters
    ----------
    cos_theta_h : float or array
        Cosine between the half vector and the macro normal.
    alpha : float or array
        GGX roughness in (0, 1].
    """
    alpha2 = xp.square(alpha)
    denominator = xp.square(xp.square(cos_theta_h) * (alpha2 - 1.0) + 1.0)
    value = alpha2 / (xp.pi * denominator)
    return xp.select(cos_theta_h > 0.0, value, 0.0)


def smith_g1_ggx(cos_theta_v, cos_theta_vh, alpha):
    """Smith masking of direction ``v`` for GGX: ``2 / (1 + sqrt(1 + alpha^2 tan^2 theta_v))``.

    Zero when ``v`` sees the back of the microfacet (``cos_theta_vh`` and
    ``cos_theta_v`` of different sign).

    Parameters
    ----------
    cos_theta_v : float or array
        Cosine between ``v`` and the macro normal.
    cos_theta_vh : float or array
        Cosine between ``v`` and the microfacet normal (half vector).
    alpha : float or array
        GGX roughness.
    """
    cos2 = xp.square(cos_theta_v)
    tan2 = xp.maximum(1.0 - cos2, 0.0) / xp.maximum(cos2, 1e-20)
    value = 2.0 / (1.0 + xp.sqrt(1.0 + xp.square(alpha) * tan2))
    return xp.select(cos_theta_vh * cos_theta_v > 0.0, value, 0.0)


def smith_masking_shadowing(cos_theta_i, cos_theta_o, cos_theta_ih, cos_theta_oh, alpha):
    """Separable Smith ``G(theta_i, theta_o; alpha) = G1(wi) G1(wo)`` for GGX."""
    return (smith_g1_ggx(cos_theta_i, cos_theta_ih, alpha)
            * smith_g1_ggx(cos_theta_o, cos_theta_oh, alpha))


def microfacet_reflection_term(albedo, cos_theta_i, cos_theta_o, cos_theta_h,
                               cos_theta_d, alpha):
    """``kappa = rho D G / (4 cos_i cos_o)``: kappa_s (eq. 5) or kappa_ss (eq. 6), in 1/sr.

    The Fresnel factor is kept out of ``kappa``, as in the supplement.

    Parameters
    ----------
    albedo : float or array or spectrum
        ``rho_s`` or ``rho_ss``.
    cos_theta_i, cos_theta_o : float or array
        Cosines of light and view directions with the normal (> 0).
    cos_theta_h : float or array
        Cosine of the half vector with the normal.
    cos_theta_d : float or array
        Cosine of the half vector with the light (and view) direction.
    alpha : float or array
        GGX roughness.
    """
    D = ggx_distribution(cos_theta_h, alpha)
    G = smith_masking_shadowing(cos_theta_i, cos_theta_o, cos_theta_d, cos_theta_d, alpha)
    denominator = 4.0 * cos_theta_i * cos_theta_o
    return albedo * xp.select(denominator > 0.0, D * G / xp.maximum(denominator, 1e-20), 0.0)
