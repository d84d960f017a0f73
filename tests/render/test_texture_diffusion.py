"""Texture-space sum-of-Gaussians blur: moments in mm, energy, borders, autodiff."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.render.texture_diffusion import blur_separable, blur_sum_of_gaussians

T = 96


def patch(texel_u_mm, texel_v_mm, valid=None):
    sizes = np.empty((T, T, 2))
    sizes[..., 0], sizes[..., 1] = texel_u_mm, texel_v_mm
    return sizes, np.ones((T, T), bool) if valid is None else valid


def second_moments(image, texel_u_mm, texel_v_mm):
    i, j = np.mgrid[0:T, 0:T]
    total = image.sum()
    ci, cj = (image * i).sum() / total, (image * j).sum() / total
    var_u = (image * ((j - cj) * texel_u_mm) ** 2).sum() / total
    var_v = (image * ((i - ci) * texel_v_mm) ** 2).sum() / total
    return total, var_u, var_v


@pytest.mark.parametrize("texel_u,texel_v", [(0.2, 0.2), (0.3, 0.15)])
def test_an_impulse_spreads_with_the_variance_in_mm(texel_u, texel_v):
    sizes, valid = patch(texel_u, texel_v)
    impulse = np.zeros((T, T), np.float32)
    impulse[T // 2, T // 2] = 1.0
    variance = 1.0  # mm^2: sigma = 1 mm = 3.3 to 6.7 texels
    out = blur_separable(impulse, variance, sizes, valid)
    total, var_u, var_v = second_moments(out, texel_u, texel_v)
    assert total == pytest.approx(1.0, rel=1e-5)
    assert var_u == pytest.approx(variance, rel=0.02)
    assert var_v == pytest.approx(variance, rel=0.02)


def test_constant_maps_stay_constant_up_to_the_atlas_border():
    valid = np.zeros((T, T), bool)
    valid[10:80, 20:70] = True
    sizes, _ = patch(0.25, 0.25)
    constant = np.where(valid, 0.7, 0.0).astype(np.float32)
    out = blur_sum_of_gaussians(constant, [0.3, 0.7], [0.05, 1.5], sizes, valid)
    np.testing.assert_allclose(out[valid], 0.7, rtol=1e-5)
    assert np.all(out[~valid] == 0)


def test_sub_texel_gaussians_are_the_identity():
    sizes, valid = patch(0.5, 0.5)
    image = np.random.default_rng(0).uniform(size=(T, T)).astype(np.float32)
    np.testing.assert_array_equal(blur_separable(image, 0.01**2, sizes, valid), image)


def test_drjit_maps_match_numpy_and_carry_gradients():
    mi.set_variant("llvm_ad_mono_polarized")
    sizes, valid = patch(0.3, 0.2)
    image = np.random.default_rng(1).uniform(size=(T, T)).astype(np.float32)
    reference = blur_sum_of_gaussians(image, [0.5, 0.5], [0.1, 0.8], sizes, valid)
    tensor = mi.TensorXf(image)
    dr.enable_grad(tensor)
    out = blur_sum_of_gaussians(tensor, [0.5, 0.5], [0.1, 0.8], sizes, valid)
    np.testing.assert_allclose(np.array(out), reference, rtol=1e-5, atol=1e-6)
    # d(sum out)/d(input texel) = how much of that texel's value reaches the map
    dr.backward(dr.sum(out, axis=None))
    grad = np.array(dr.grad(tensor))
    assert grad[T // 2, T // 2] == pytest.approx(1.0, rel=1e-3)


def test_mismatched_inputs_are_rejected():
    sizes, valid = patch(0.3, 0.3)
    with pytest.raises(ValueError, match="weights"):
        blur_sum_of_gaussians(np.zeros((T, T)), [1.0], [0.1, 0.2], sizes, valid)
    with pytest.raises(ValueError, match="positive"):
        blur_sum_of_gaussians(np.zeros((T, T)), [1.0], [0.0], sizes, valid)
    with pytest.raises(ValueError, match="share"):
        blur_sum_of_gaussians(np.zeros((T, 4)), [1.0], [0.1], sizes, valid)
