"""Mueller matrices and Stokes frames (eq. 1, 4) against Mitsuba's ``mitsuba.mueller``."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from helpers import mueller_to_numpy as as_numpy
from polarbssrdf._arrays import to_jit
from polarbssrdf.optics import (
    coordinate_system,
    depolarizer,
    linear_polarizer,
    rotate_mueller_basis,
    rotate_stokes_basis,
    rotator,
    stokes_basis,
)


@pytest.fixture(autouse=True)
def variant():
    mi.set_variant("llvm_ad_mono_polarized")


def random_unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    # include the poles, where coordinate systems are most fragile
    v[:4] = [[0, 0, 1], [0, 0, -1], [1e-7, 0, 1], [0, 1e-7, -1]]
    v[:4] /= np.linalg.norm(v[:4], axis=1, keepdims=True)
    return mi.Vector3f(v.T.astype(np.float32))


def test_rotator_matches_mitsuba():
    theta = to_jit(mi.Float, np.linspace(-3, 3, 101), np.float32)
    np.testing.assert_allclose(as_numpy(rotator(theta)), as_numpy(mi.mueller.rotator(theta)),
                               atol=1e-6)


def test_rotator_documented_example():
    # Mitsuba: rotating the frame of [1, 1, 0, 0] by +45 degrees gives [1, 0, -1, 0]
    M = rotator(dr.scalar.Float(np.pi / 4))
    s = M @ dr.scalar.Array4f(1, 1, 0, 0)
    np.testing.assert_allclose([s[0], s[1], s[2], s[3]], [1, 0, -1, 0], atol=1e-6)


def test_depolarizer_and_polarizer_match_mitsuba():
    value = mi.Float(0.3)
    np.testing.assert_allclose(as_numpy(depolarizer(value)),
                               as_numpy(mi.mueller.depolarizer(value)), atol=1e-7)
    np.testing.assert_allclose(as_numpy(linear_polarizer(value)),
                               as_numpy(mi.mueller.linear_polarizer(value)), atol=1e-7)


def test_stokes_basis_matches_mitsuba(rng):
    d = random_unit_vectors(rng, 1000)
    ours = np.array(stokes_basis(d))
    theirs = np.array(mi.mueller.stokes_basis(d))
    np.testing.assert_allclose(ours, theirs, atol=1e-6)
    assert np.abs(np.sum(ours * np.array(d), axis=0)).max() < 1e-6  # perpendicular


def test_coordinate_system_is_mitsubas_right_handed_frame(rng):
    """Both tangents, for normals in both hemispheres (the second tangent was wrong for z < 0)."""
    d = random_unit_vectors(rng, 1000)
    s, t = coordinate_system(d)
    s_ref, t_ref = mi.coordinate_system(d)
    np.testing.assert_allclose(np.array(s), np.array(s_ref), atol=1e-6)
    np.testing.assert_allclose(np.array(t), np.array(t_ref), atol=1e-6)
    n = np.array(d)
    assert np.abs(np.sum(np.array(t) * n, axis=0)).max() < 1e-6
    np.testing.assert_allclose(np.sum(np.cross(np.array(s).T, np.array(t).T) * n.T, axis=1), 1.0,
                               atol=1e-6)


def test_rotate_mueller_basis_matches_mitsuba(rng):
    n = 500
    fwd_in, fwd_out = random_unit_vectors(rng, n), random_unit_vectors(rng, n)

    def perpendicular(forward):
        a = random_unit_vectors(rng, n)
        return dr.normalize(dr.cross(forward, a))

    bases = [perpendicular(fwd_in), perpendicular(fwd_in),
             perpendicular(fwd_out), perpendicular(fwd_out)]
    M = mi.Matrix4f(*[to_jit(mi.Float, rng.normal(size=n), np.float32) for _ in range(16)])
    ours = rotate_mueller_basis(M, fwd_in, bases[0], bases[1], fwd_out, bases[2], bases[3])
    theirs = mi.mueller.rotate_mueller_basis(M, fwd_in, bases[0], bases[1],
                                             fwd_out, bases[2], bases[3])
    np.testing.assert_allclose(as_numpy(ours), as_numpy(theirs), atol=2e-5)
    R = rotate_stokes_basis(fwd_in, bases[0], bases[1])
    np.testing.assert_allclose(as_numpy(R),
                               as_numpy(mi.mueller.rotate_stokes_basis(fwd_in, bases[0], bases[1])),
                               atol=2e-5)


def test_rotation_preserves_degree_of_polarization(rng):
    theta = to_jit(mi.Float, rng.uniform(-np.pi, np.pi, 100), np.float32)
    s = rotator(theta) @ mi.Vector4f(1.0, 0.6, 0.3, 0.1)
    dop = np.sqrt(np.array(s[1]) ** 2 + np.array(s[2]) ** 2 + np.array(s[3]) ** 2)
    np.testing.assert_allclose(dop, np.sqrt(0.46), rtol=1e-6)


def test_rotation_sincos_equals_the_angle_and_has_finite_derivatives_where_bases_coincide(rng):
    """``(sin 2 theta, cos 2 theta)`` without the angle: the same values as the angle's,
    and derivatives that stay finite at theta = 0 (where the angle's ``asin`` has none)."""
    from polarbssrdf.optics.mueller import (
        stokes_basis_rotation_angle,
        stokes_basis_rotation_sincos,
    )

    directions = random_unit_vectors(rng, 64)
    forward = mi.Vector3f(*[to_jit(mi.Float, directions[:, k], np.float32) for k in range(3)])
    current = stokes_basis(forward)
    # targets at random angles about forward, the first 8 equal to the current basis
    angle = rng.uniform(-np.pi, np.pi, 64)
    angle[:8] = 0.0
    s, c = dr.sincos(to_jit(mi.Float, angle, np.float32))
    target = c * current + s * dr.cross(forward, current)
    reference = stokes_basis_rotation_angle(forward, current, target)
    sin_2theta, cos_2theta = stokes_basis_rotation_sincos(forward, current, target)
    np.testing.assert_allclose(np.array(sin_2theta), np.sin(2 * np.array(reference)), atol=2e-6)
    np.testing.assert_allclose(np.array(cos_2theta), np.cos(2 * np.array(reference)), atol=2e-6)
    # scaled basis vectors give the same rotation
    scaled = stokes_basis_rotation_sincos(forward, 3.0 * current, 0.5 * target)
    np.testing.assert_allclose(np.array(scaled[0]), np.array(sin_2theta), atol=2e-6)

    dr.enable_grad(target)
    old = dr.sincos(2.0 * stokes_basis_rotation_angle(forward, current, target))
    dr.backward(old[0] + old[1])
    assert not np.isfinite(np.array(dr.grad(target.x))[:8]).all()  # the defect being fixed
    dr.clear_grad(target)
    new = stokes_basis_rotation_sincos(forward, current, target)
    dr.backward(new[0] + new[1])
    assert np.isfinite(np.array(dr.grad(target.x))).all()
