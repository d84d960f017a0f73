"""The polarimetric BRDF of the supplement (Hwang et al. 2022 form), as Mueller matrices.

Three lobes (supplement sec. 2.4 and 3.1):

* specular (eq. 5): ``kappa_s C(-phi_o) F^R(theta_d; eta) C(phi_i)`` with GGX
  roughness ``alpha_s`` and albedo ``rho_s``; the Fresnel reflection Mueller
  matrix acts in the plane of incidence of the half vector;
* single scattering (eq. 6): the same form with ``alpha_ss`` and ``rho_ss``;
* subsurface: Fresnel transmission into the surface, an ideal depolarizer
  scaled by ``rho_sss / pi``, Fresnel transmission out (eq. 19), in the plane
  of incidence of the normal. ``rho_sss`` is the lobe's albedo (a Lambertian
  lobe of albedo ``rho_sss`` between two Fresnel transmissions); the
  supplement folds the ``1 / pi`` into ``rho_sss``.

Conventions are Mitsuba's (``BSDF::eval``): directions are unit vectors in
the local shading frame (normal = +z); light arrives along ``-wo_hat`` and
leaves along ``wi_hat`` (``wo_hat = wo, wi_hat = wi`` in radiance mode, swapped
in importance mode); the matrices map Stokes vectors in the basis
``stokes_basis(-wo_hat)`` to ``stokes_basis(wi_hat)``. The returned values
are BRDF values in 1/sr, *without* the cosine foreshortening factor.

The exactly collinear (retro-reflection) configuration ``wi == wo`` leaves the
half-vector plane of incidence undefined. Any s axis perpendicular to the half
vector, used for *both* the incident and the exitant frame, gives the right
matrix there (the Fresnel matrix at ``theta_d = 0`` is invariant under that
joint rotation); Mitsuba's ``pplastic`` instead falls back to a fixed axis
that is generally not perpendicular to the beam and leaks cross-polarized
specular light.
"""

from __future__ import annotations

import drjit as dr

from polarbssrdf.optics._types import array3_type_for, matrix_type_for
from polarbssrdf.optics.fresnel import (
    fresnel_reflectance,
    fresnel_transmittance,
    plus_minus,
    reflection_phase_cosine,
)
from polarbssrdf.optics.microfacet import microfacet_reflection_term
from polarbssrdf.optics.mueller import (
    rotate_mueller_basis,
    stokes_basis,
    stokes_basis_rotation_sincos,
)

_COLLINEAR_EPSILON = 1e-12  # squared norm of a cross product of unit vectors
_NEAR_COLLINEAR_SQUARED_SINE = 1e-6  # (1e-3 rad)^2


def _frame_axis(normal, direction, fallback):
    """Unit s axis ``cross(normal, direction)``, or ``fallback`` where they are collinear."""
    axis = dr.cross(normal, direction)
    collinear = dr.squared_norm(axis) <= _COLLINEAR_EPSILON
    return dr.select(collinear, fallback, dr.normalize(axis))


def half_vector(wi, wo):
    """Unit half vector ``h = (wi + wo) / |wi + wo|``."""
    return dr.normalize(wi + wo)


def microfacet_lobe_mueller(wi_hat, wo_hat, kappa, eta, Matrix=None):
    """Mueller matrix of a microfacet reflection lobe (eq. 5 or eq. 6).

    ``kappa * C_{h->o}(-phi_o) F^R(theta_d; eta) C_{i->h}(phi_i)``, expressed
    between Mitsuba's implicit Stokes bases.

    Parameters
    ----------
    wi_hat, wo_hat : Array3f
        Exitant and (reversed) incident directions in the local frame.
    kappa : float, array or spectrum
        ``kappa_s`` or ``kappa_ss`` (1/sr), see
        :func:`polarbssrdf.optics.microfacet.microfacet_reflection_term`.
    eta : float or array
        Relative refractive index.
    Matrix : type, optional
        Matrix type of the result (``mi.Spectrum`` in a polarized variant).
    """
    h = half_vector(wi_hat, wo_hat)
    cos_theta_d = dr.dot(wo_hat, h)
    R_perp, R_par = fresnel_reflectance(cos_theta_d, eta)
    cos_delta = reflection_phase_cosine(cos_theta_d, eta)
    Matrix = Matrix or matrix_type_for(R_perp)
    a = 0.5 * (R_perp + R_par) * kappa
    b = 0.5 * (R_perp - R_par) * kappa
    c = dr.sqrt(R_perp * R_par) * cos_delta * kappa
    F = Matrix(a, b, 0, 0,
               b, a, 0, 0,
               0, 0, c, 0,
               0, 0, 0, c)
    s_in, s_out = _half_vector_plane_axes(wi_hat, wo_hat, h)
    return rotate_mueller_basis(F, -wo_hat, s_in, stokes_basis(-wo_hat),
                                wi_hat, s_out, stokes_basis(wi_hat))


def _half_vector_plane_axes(wi_hat, wo_hat, h):
    """s axes of the half vector's plane of incidence for the incident and exitant beams.

    Both come from one shared axis ``cross(wi, wo)`` (the plane's normal), so
    rounding cannot turn them against each other when the directions are
    nearly collinear, and each is then made exactly perpendicular to its
    beam. Within 1e-3 rad of exact retro-reflection the axis is any vector
    perpendicular to ``h``: the Fresnel matrix is invariant under a joint
    rotation of both frames up to O(theta_d^2) = 1e-6.
    """
    axis = dr.cross(wi_hat, wo_hat)
    near_collinear = dr.squared_norm(axis) < _NEAR_COLLINEAR_SQUARED_SINE
    shared = dr.select(near_collinear, stokes_basis(h), dr.normalize(axis))
    s_in = dr.normalize(shared - dr.dot(shared, wo_hat) * wo_hat)
    s_out = dr.normalize(shared - dr.dot(shared, wi_hat) * wi_hat)
    return s_in, s_out


def _normal_plane_axis(direction):
    """s axis of the normal's plane of incidence for ``direction`` (local frame)."""
    Array3f = array3_type_for(direction.z)
    normal = Array3f(0.0, 0.0, 1.0)
    # Along the normal T- = 0, so any axis serves.
    return _frame_axis(normal, direction, Array3f(1.0, 0.0, 0.0))


def subsurface_entry_stokes_row(wo_hat, eta):
    """Entry factor of the subsurface lobe: ``[T+_i, T-_i, 0, 0]`` rotated to Mitsuba's basis.

    The row vector ``r`` such that ``r . s`` is the power that light with
    Stokes vector ``s`` (in ``stokes_basis(-wo_hat)``) arriving along
    ``-wo_hat`` transmits into the surface, per unit incident power. Texture-
    space diffusion blurs this transmitted power before it leaves through
    :func:`subsurface_exit_stokes_column`.

    Returns
    -------
    tuple of 4 arrays
    """
    T_plus, T_minus = plus_minus(*fresnel_transmittance(wo_hat.z, eta))
    s, c = stokes_basis_rotation_sincos(-wo_hat, _normal_plane_axis(-wo_hat),
                                        stokes_basis(-wo_hat))
    # Row of [T+, T-, 0, 0] . C(angle)^T
    return (T_plus, T_minus * c, -T_minus * s, 0.0 * T_plus)


def subsurface_exit_stokes_column(wi_hat, eta):
    """Exit factor of the subsurface lobe: ``[T+_o, T-_o, 0, 0] / pi`` in Mitsuba's basis.

    Radiance Stokes vector (in ``stokes_basis(wi_hat)``) leaving along
    ``wi_hat`` per unit of diffused, depolarized power density below the
    surface (albedo included by the caller).

    Returns
    -------
    tuple of 4 arrays
    """
    T_plus, T_minus = plus_minus(*fresnel_transmittance(wi_hat.z, eta))
    s, c = stokes_basis_rotation_sincos(wi_hat, _normal_plane_axis(wi_hat),
                                        stokes_basis(wi_hat))
    # C(angle) . [T+, T-, 0, 0]^T
    return (T_plus * dr.inv_pi, T_minus * c * dr.inv_pi, -T_minus * s * dr.inv_pi,
            0.0 * T_plus)


def subsurface_lobe_mueller(wi_hat, wo_hat, rho_sss, eta, Matrix=None):
    """Mueller matrix of the depolarized subsurface lobe (supplement eq. 19).

    ``F^T(theta_out) . (rho_sss / pi) depolarizer . F^T(theta_in)``: the
    rank-one matrix ``rho_sss * exit_column x entry_row`` of
    :func:`subsurface_exit_stokes_column` and :func:`subsurface_entry_stokes_row`,
    whose s axes are perpendicular to the normal's planes of incidence.

    Parameters
    ----------
    wi_hat, wo_hat : Array3f
        Exitant and (reversed) incident directions in the local frame.
    rho_sss : float, array or spectrum
        Subsurface albedo (dimensionless).
    eta : float or array
        Relative refractive index.
    """
    row = subsurface_entry_stokes_row(wo_hat, eta)
    column = subsurface_exit_stokes_column(wi_hat, eta)
    Matrix = Matrix or matrix_type_for(row[0])
    column = [rho_sss * value for value in column[:3]]
    return Matrix(column[0] * row[0], column[0] * row[1], column[0] * row[2], 0,
                  column[1] * row[0], column[1] * row[1], column[1] * row[2], 0,
                  column[2] * row[0], column[2] * row[1], column[2] * row[2], 0,
                  0, 0, 0, 0)


def pbrdf_mueller(wi_hat, wo_hat, eta, rho_s, alpha_s, rho_ss, alpha_ss, rho_sss,
                  Matrix=None, specular=True, single_scattering=True, subsurface=True):
    """Full pBRDF Mueller matrix (1/sr): specular + single scattering + subsurface.

    Zero unless both directions are in the upper hemisphere. Parameters are
    named after the paper; see the lobe functions for the conventions.
    """
    cos_i, cos_o = wi_hat.z, wo_hat.z
    active = (cos_i > 0.0) & (cos_o > 0.0)
    h = half_vector(wi_hat, wo_hat)
    cos_h, cos_d = h.z, dr.dot(wo_hat, h)
    result = None
    if specular:
        kappa_s = microfacet_reflection_term(rho_s, cos_i, cos_o, cos_h, cos_d, alpha_s)
        result = microfacet_lobe_mueller(wi_hat, wo_hat, kappa_s, eta, Matrix)
    if single_scattering:
        kappa_ss = microfacet_reflection_term(rho_ss, cos_i, cos_o, cos_h, cos_d, alpha_ss)
        lobe = microfacet_lobe_mueller(wi_hat, wo_hat, kappa_ss, eta, Matrix)
        result = lobe if result is None else result + lobe
    if subsurface:
        lobe = subsurface_lobe_mueller(wi_hat, wo_hat, rho_sss, eta, Matrix)
        result = lobe if result is None else result + lobe
    if result is None:
        Matrix = Matrix or matrix_type_for(cos_i)
        return dr.zeros(Matrix)
    return dr.select(active, result, 0.0)


def pbrdf_intensity(cos_theta_i, cos_theta_o, cos_theta_h, cos_theta_d, eta,
                    rho_s, alpha_s, rho_ss, alpha_ss, rho_sss):
    """Unpolarized part ``M00`` of :func:`pbrdf_mueller` (1/sr), from angle cosines alone.

    ``(kappa_s + kappa_ss) R+(theta_d) + (rho_sss / pi) T+(theta_i) T+(theta_o)``.
    This is what the plugin returns in unpolarized variants.
    """
    R_plus, _ = plus_minus(*fresnel_reflectance(cos_theta_d, eta))
    T_i_plus, _ = plus_minus(*fresnel_transmittance(cos_theta_i, eta))
    T_o_plus, _ = plus_minus(*fresnel_transmittance(cos_theta_o, eta))
    kappa = (microfacet_reflection_term(rho_s, cos_theta_i, cos_theta_o, cos_theta_h,
                                        cos_theta_d, alpha_s)
             + microfacet_reflection_term(rho_ss, cos_theta_i, cos_theta_o, cos_theta_h,
                                          cos_theta_d, alpha_ss))
    value = kappa * R_plus + rho_sss * dr.inv_pi * T_i_plus * T_o_plus
    return dr.select((cos_theta_i > 0.0) & (cos_theta_o > 0.0), value, 0.0)
