"""Normals from a displacement map (supplement eq. 25) on an anisotropic flat patch."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.geometry import SurfaceMesh, normals_from_height, texel_atlas, to_mitsuba

LX, LY = 80.0, 40.0  # mm: texels are twice as wide as tall, so a u/v mix-up shows


@pytest.fixture(scope="module")
def patch_atlas():
    mi.set_variant("llvm_ad_mono_polarized")
    vertices = np.array([[0, 0, 0], [LX, 0, 0], [LX, LY, 0], [0, LY, 0]], float)
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    mesh = SurfaceMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]), uvs, name="patch")
    return texel_atlas(to_mitsuba(mesh), 128)


def height_field(atlas):
    x, y = atlas.position[..., 0], atlas.position[..., 1]
    kx, ky = 2 * np.pi / 20.0, 2 * np.pi / 25.0
    H = 0.3 * np.sin(kx * x) + 0.2 * np.cos(ky * y)
    slope = np.stack([0.3 * kx * np.cos(kx * x), -0.2 * ky * np.sin(ky * y)], -1)  # dH/dx, dH/dy
    expected = np.concatenate([-slope, np.ones_like(H)[..., None]], -1)
    return H, expected / np.linalg.norm(expected, axis=-1, keepdims=True)


def test_numpy_normals_match_the_analytic_surface(patch_atlas):
    H, expected = height_field(patch_atlas)
    n = normals_from_height(H.astype(np.float32), patch_atlas)
    inner = (slice(1, -1), slice(1, -1))
    angle = np.degrees(np.arccos(np.clip(np.sum(n * expected, -1), -1, 1)))
    assert angle[inner].max() < 0.5  # central differences at 0.625 x 0.3125 mm texels
    zero = normals_from_height(np.zeros_like(H, dtype=np.float32), patch_atlas)
    np.testing.assert_allclose(zero[..., 2], 1.0, atol=1e-6)


def test_drjit_normals_equal_numpy_and_are_differentiable(patch_atlas):
    H, _ = height_field(patch_atlas)
    reference = normals_from_height(H.astype(np.float32), patch_atlas)
    H_t = mi.TensorXf(H.astype(np.float32))
    dr.enable_grad(H_t)
    n = normals_from_height(H_t, patch_atlas)
    for k in range(3):
        np.testing.assert_allclose(np.array(n[k]), reference[..., k], atol=2e-6)
    dr.backward(dr.sum(n[0], axis=None))
    grad = np.array(dr.grad(H_t))
    # n_x = -dH/dx / |.| depends on the left and right neighbours only
    assert np.abs(grad).max() > 0 and np.isfinite(grad).all()
