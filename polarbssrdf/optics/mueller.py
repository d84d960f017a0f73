"""Mueller matrices and Stokes reference frames; supplement eq. 1 and 4.

Conventions follow Mitsuba 3 (``mitsuba.mueller``): a Stokes vector is
observed looking back along the propagation direction; a frame is given by
its basis vector (the "x" axis, perpendicular to the direction of travel);
``rotator(theta)`` is the coordinate conversion ``C(theta)`` of eq. 4.

Each function takes an optional ``Matrix`` type (default: the ``Matrix4f``
of the inputs' Dr.Jit backend). Inside a polarized Mitsuba variant pass
``mi.Spectrum`` to get Mueller matrices whose entries are spectra.
"""

from __future__ import annotations

import drjit as dr

from polarbssrdf.optics._types import array3_type_for, matrix_type_for


def fresnel_mueller(F_perp, F_par, cos_delta=1.0, Matrix=None):
    """Fresnel Mueller matrix ``F^{T,R}`` of eq. 1 for a real retardance.

    Parameters
    ----------
    F_perp, F_par : float or array
        Power reflectances (or transmittances) for s and p polarization.
    cos_delta : float or array
        ``cos(delta)``: -1 below Brewster's angle for reflection, +1 above it
        and for transmission. ``sin(delta) = 0`` for a dielectric, so the
        circular-linear coupling terms of eq. 1 vanish.
    Matrix : type, optional
        Matrix type of the result.
    """
    Matrix = Matrix or matrix_type_for(F_perp, F_par)
    a = 0.5 * (F_perp + F_par)
    b = 0.5 * (F_perp - F_par)
    c = dr.sqrt(F_perp * F_par) * cos_delta
    return Matrix(a, b, 0, 0,
                  b, a, 0, 0,
                  0, 0, c, 0,
                  0, 0, 0, c)


def rotator(theta, Matrix=None):
    """Coordinate conversion ``C(theta)`` of eq. 4 (a counter-clockwise frame rotation).

    Same as ``mitsuba.mueller.rotator``: rotating the frame of horizontally
    polarized light ``[1, 1, 0, 0]`` by +45 degrees gives ``[1, 0, -1, 0]``.

    Parameters
    ----------
    theta : float or array
        Rotation angle in radians.
    """
    Matrix = Matrix or matrix_type_for(theta)
    s, c = dr.sincos(2.0 * theta)
    return Matrix(1, 0, 0, 0,
                  0, c, s, 0,
                  0, -s, c, 0,
                  0, 0, 0, 1)


def depolarizer(value=1.0, Matrix=None):
    """Ideal depolarizer: only the (0, 0) entry is non-zero and equals ``value``."""
    Matrix = Matrix or matrix_type_for(value)
    return Matrix(value, 0, 0, 0,
                  0, 0, 0, 0,
                  0, 0, 0, 0,
                  0, 0, 0, 0)


def linear_polarizer(value=1.0, Matrix=None):
    """Ideal linear polarizer transmitting along the frame's x axis, scaled by ``value``."""
    Matrix = Matrix or matrix_type_for(value)
    a = 0.5 * value
    return Matrix(a, a, 0, 0,
                  a, a, 0, 0,
                  0, 0, 0, 0,
                  0, 0, 0, 0)


def coordinate_system(n):
    """Orthonormal tangents ``(s, t)`` of unit vector ``n`` (Duff et al. 2017).

    The same construction as Mitsuba's ``coordinate_system``, so that
    :func:`stokes_basis` agrees with ``mitsuba.mueller.stokes_basis``.
    """
    Array3f = type(n) if dr.is_array_v(type(n)) else array3_type_for(n[0])
    sign = dr.select(n.z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    s = Array3f(dr.mulsign(dr.square(n.x) * a, n.z) + 1.0,
                dr.mulsign(b, n.z),
                -dr.mulsign(n.x, n.z))
    t = Array3f(b, sign + dr.square(n.y) * a, -n.y)
    return s, t


def stokes_basis(forward):
    """Implicit Stokes reference basis vector of light travelling along ``forward``."""
    return coordinate_system(forward)[0]


def unit_angle(a, b):
    """Angle in radians between unit vectors ``a`` and ``b``, accurate near 0 and pi."""
    dot_uv = dr.dot(a, b)
    temp = 2.0 * dr.asin(0.5 * dr.norm(b - dr.mulsign(a, dot_uv)))
    return dr.select(dot_uv >= 0, temp, dr.pi - temp)


def stokes_basis_rotation_angle(forward, basis_current, basis_target):
    """Signed angle that turns ``basis_current`` into ``basis_target`` about ``forward``."""
    theta = unit_angle(dr.normalize(basis_current), dr.normalize(basis_target))
    flip = dr.dot(forward, dr.cross(basis_current, basis_target)) < 0
    return dr.select(flip, -theta, theta)


def stokes_basis_rotation_sincos(forward, basis_current, basis_target):
    """``(sin 2 theta, cos 2 theta)`` of :func:`stokes_basis_rotation_angle`, without the angle.

    A Stokes rotation needs only these (eq. 4). With ``|c| |t| cos theta =
    c . t`` and ``|c| |t| sin theta = forward . (c x t)`` they are rational in
    the basis vectors, so their derivatives are finite everywhere; the
    angle's ``asin`` has an infinite derivative where the two bases coincide
    (a texel-view there turned a whole patch's gradient into NaN). A
    vanishing basis vector (a direction along the normal has no plane of
    incidence) gives ``(0, 0)``.

    Parameters
    ----------
    forward : Array3f
        Unit direction of travel.
    basis_current, basis_target : Array3f
        Basis vectors perpendicular to ``forward`` (any length).
    """
    cos_theta = dr.dot(basis_current, basis_target)
    sin_theta = dr.dot(forward, dr.cross(basis_current, basis_target))
    scale = 1.0 / dr.maximum(dr.squared_norm(basis_current) * dr.squared_norm(basis_target), 1e-30)
    return (2.0 * sin_theta * cos_theta * scale,
            (dr.square(cos_theta) - dr.square(sin_theta)) * scale)


def rotator_sincos(sin_2theta, cos_2theta, Matrix=None):
    """:func:`rotator` from ``sin 2 theta`` and ``cos 2 theta`` (see :func:`stokes_basis_rotation_sincos`)."""
    Matrix = Matrix or matrix_type_for(cos_2theta)
    return Matrix(1, 0, 0, 0,
                  0, cos_2theta, sin_2theta, 0,
                  0, -sin_2theta, cos_2theta, 0,
                  0, 0, 0, 1)


def rotate_stokes_basis(forward, basis_current, basis_target, Matrix=None):
    """Mueller matrix re-expressing a Stokes vector from one basis in another.

    Parameters
    ----------
    forward : Array3f
        Unit direction of travel.
    basis_current, basis_target : Array3f
        Unit basis vectors, both perpendicular to ``forward``.
    """
    return rotator_sincos(*stokes_basis_rotation_sincos(forward, basis_current, basis_target),
                          Matrix)


def rotate_mueller_basis(M, in_forward, in_basis_current, in_basis_target,
                         out_forward, out_basis_current, out_basis_target):
    """Re-express ``M`` (current in/out bases) as a matrix between the target bases.

    ``R_out * M * R_in^T``; same contract as ``mitsuba.mueller.rotate_mueller_basis``.
    """
    Matrix = type(M)
    sin_in, cos_in = stokes_basis_rotation_sincos(in_forward, in_basis_current, in_basis_target)
    sin_out, cos_out = stokes_basis_rotation_sincos(out_forward, out_basis_current,
                                                    out_basis_target)
    # C(theta)^T = C(-theta)
    return rotator_sincos(sin_out, cos_out, Matrix) * M * rotator_sincos(-sin_in, cos_in, Matrix)
