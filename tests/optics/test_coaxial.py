"""Coaxial image formation (eq. 19-24) against the full pBRDF Mueller matrix."""

import drjit as dr
import numpy as np
import pytest

from polarbssrdf.optics import (
    coaxial_stokes,
    diffuse_degree_of_polarization,
    pbrdf_mueller,
    polarization_images,
    rotate_stokes_basis,
    separate_observations,
    stokes_basis,
)

Float, Array3f, Vector4f = dr.llvm.ad.Float, dr.llvm.ad.Array3f, dr.llvm.ad.Array4f
PARAMS = dict(eta=1.42, rho_s=0.8, alpha_s=0.45, rho_ss=0.3, alpha_ss=0.95, rho_sss=0.6)


def coaxial_geometry(rng, n):
    """Random view directions v (local frame) and image-right axes perpendicular to them."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a = rng.normal(size=(n, 3))
    right = np.cross(v, a)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    up = np.cross(v, right)  # right x up = v (towards the camera)
    # azimuth of the normal (0, 0, 1) projected into the image plane
    phi = np.arctan2(up[:, 2], right[:, 2])
    return v, right, phi


def full_model_image_stokes(v, right, params):
    """Stokes in the image frame from pbrdf_mueller with light polarized along image right."""
    wi = Array3f(v.T)
    wo = Array3f(v.T)
    e_x = Array3f(right.T)
    # light travels along -wo, polarized along e_x: [1, 1, 0, 0] in basis e_x
    s_in = rotate_stokes_basis(-wo, e_x, stokes_basis(-wo)) @ Vector4f(1, 1, 0, 0)
    M = pbrdf_mueller(wi, wo, **params)
    s_out = M @ s_in
    # image frame: basis e_x for light travelling towards the camera (+wi)
    s_img = rotate_stokes_basis(wi, stokes_basis(wi), e_x) @ s_out
    return np.array([np.array(s_img[i]) for i in range(4)])


@pytest.mark.parametrize("params", [
    PARAMS,
    dict(PARAMS, rho_s=0.0, rho_ss=0.0),
    dict(PARAMS, rho_sss=0.0, eta=1.6, alpha_s=0.1),
])
def test_closed_form_matches_full_mueller_model(rng, params):
    v, right, phi = coaxial_geometry(rng, 2000)
    full = full_model_image_stokes(v, right, params)
    closed = np.array(coaxial_stokes(v[:, 2], phi, **params))
    scale = np.abs(full[0]).max()
    np.testing.assert_allclose(closed, full, atol=2e-5 * scale)


def test_first_order_form_is_the_supplement_eq19(rng):
    """Dropping T- T- changes the result by at most DoP^2 of the subsurface term."""
    v, _, phi = coaxial_geometry(rng, 500)
    exact = np.array(coaxial_stokes(v[:, 2], phi, **PARAMS))
    first = np.array(coaxial_stokes(v[:, 2], phi, first_order=True, **PARAMS))
    dop = diffuse_degree_of_polarization(PARAMS["eta"], np.arccos(v[:, 2]))
    np.testing.assert_allclose(exact[0], first[0])
    # (rho/pi) T+^2 <= S0_sss / (1 - DoP), and the dropped terms are (rho/pi) T-^2 |xi| <= ...
    sss = np.array(coaxial_stokes(v[:, 2], phi, **dict(PARAMS, rho_s=0.0, rho_ss=0.0)))
    bound = dop**2 * sss[0] / (1 - dop)
    assert np.all(np.abs(exact[1:3] - first[1:3]) <= bound * (1 + 1e-9) + 1e-15)


def test_specular_is_cross_polarization_free_and_subsurface_dop_is_atkinson_hancock(rng):
    v, _, phi = coaxial_geometry(rng, 1000)
    theta = np.arccos(v[:, 2])
    spec = coaxial_stokes(v[:, 2], phi, **dict(PARAMS, rho_sss=0.0))
    I0, I45, I90, I135 = polarization_images(spec)
    assert np.abs(I90).max() <= 1e-12 * np.abs(I0).max()
    sss = coaxial_stokes(v[:, 2], phi, **dict(PARAMS, rho_s=0.0, rho_ss=0.0))
    # entry scales the intensity; the exit fixes the DoP: |T-|/T+ = Atkinson-Hancock
    dolp = np.hypot(sss[1], sss[2]) / sss[0]
    np.testing.assert_allclose(dolp, diffuse_degree_of_polarization(PARAMS["eta"], theta),
                               rtol=1e-9)


def test_separations_recover_model_terms(rng):
    v, _, phi = coaxial_geometry(rng, 1000)
    images = polarization_images(coaxial_stokes(v[:, 2], phi, **PARAMS))
    I_sss, I_zeta, I_s = separate_observations(*images)
    sss_only = coaxial_stokes(v[:, 2], phi, **dict(PARAMS, rho_s=0.0, rho_ss=0.0))
    # I_sss = 2 I90 holds only the subsurface term; I_zeta = -S2 of the subsurface term
    np.testing.assert_allclose(I_sss, sss_only[0] - sss_only[1], rtol=1e-12)
    np.testing.assert_allclose(I_zeta, -sss_only[2], rtol=1e-9, atol=1e-15)
