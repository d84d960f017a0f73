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


def skin_profile_kernel(band=3):
    """Normalized SoG of the two-layer reflectance profile of a Table 2 skin (eq. 43)."""
    from polarbssrdf.skin import TABLE2, fit_sog, normalized_weights, two_layer_profile, variance_ladder
    from polarbssrdf.skin.layers import absorption_from_basis
    from polarbssrdf.skin.model import band_chromophore_basis
    from polarbssrdf.spectral import default_bands

    basis = band_chromophore_basis(default_bands())
    p = TABLE2[("cheek", "II")]
    sa_out, sa_in = absorption_from_basis(basis, p.C_m, p.beta_m, p.C_h_out, p.C_h_in)
    r = np.concatenate([[0.0], np.geomspace(1e-4, 30.0, 300)])
    profile = two_layer_profile(r, sa_out[band], basis["scattering_epidermis"][band], sa_in[band],
                                basis["scattering_dermis"][band], p.thickness_mm, p.eta)
    variances = variance_ladder()
    return normalized_weights(fit_sog(r, profile, variances)), variances


@pytest.mark.parametrize("band", [0, 5])
def test_a_thin_line_spreads_with_the_skin_profile_width_and_keeps_its_energy(band):
    """The line spread of a radial profile has variance sum_j w_j v_j (1-D marginals)."""
    weights, variances = skin_profile_kernel(band)
    size = 320
    texel_u, texel_v = 0.06, 0.09  # mm; anisotropic on purpose
    sizes = np.empty((size, size, 2))
    sizes[..., 0], sizes[..., 1] = texel_u, texel_v
    valid = np.ones((size, size), bool)
    line = np.zeros((size, size), np.float32)
    line[:, size // 2] = 1.0  # a line along v, one texel wide
    out = blur_sum_of_gaussians(line, weights, variances, sizes, valid, negligible_weight=0.0)
    profile = out[size // 2]
    x = (np.arange(size) - size // 2) * texel_u
    measured = np.sqrt(np.sum(profile * x**2) / np.sum(profile))
    expected = np.sqrt(np.sum(weights * variances) / np.sum(weights) + texel_u**2 / 12)
    assert measured == pytest.approx(expected, rel=0.10)
    assert 0.05 < expected < 3.0  # mm: a real, resolved skin profile
    # energy along the row (the line spans every row): conserved away from the borders
    assert profile.sum() == pytest.approx(1.0, rel=0.01)


def test_the_widest_skin_kernel_is_not_truncated_at_2k():
    """Every Table 2 profile's widest kept Gaussian fits in the tap budget at 2048^2 texel sizes,
    and a Gaussian of that width keeps its variance there."""
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.render.subsurface import layer_profile_kernels
    from polarbssrdf.render.texture_diffusion import MAX_TAPS_PER_SIDE, half_width_texels
    from polarbssrdf.skin.parameters import TABLE2

    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.spectral import default_bands

    atlas = texel_atlas(to_mitsuba(face_mesh(1)), 128)
    sizes_2k = atlas.texel_size_mm * (128 / 2048)  # texel extent scales as 1 / T
    widest = 0.0
    for skin in TABLE2.values():
        for band in layer_profile_kernels(default_bands(), skin):
            for weights, variances in band.values():
                weights, variances = np.asarray(weights), np.asarray(variances)
                kept = weights >= 1e-4 * np.abs(weights).sum()  # blur_sum_of_gaussians' cut
                widest = max(widest, float(variances[kept].max()))
    taps = max(half_width_texels(widest, sizes_2k[..., axis], atlas.valid) for axis in (0, 1))
    smallest = float(sizes_2k[..., 0][atlas.valid].min())
    assert np.ceil(4.0 * np.sqrt(widest) / smallest) <= taps < MAX_TAPS_PER_SIDE
    # that width on texels of the smallest 2K size: the variance comes out whole
    size = 4 * taps + 21  # texels the impulse reaches see their whole window
    sizes = np.full((size, size, 2), smallest)
    impulse = np.zeros((size, size), np.float32)
    impulse[size // 2, size // 2] = 1.0
    out = blur_separable(impulse, widest, sizes, np.ones((size, size), bool))
    i, j = np.mgrid[0:size, 0:size]
    total = out.sum()
    var_u = (out * ((j - size // 2) * smallest) ** 2).sum() / total
    assert total == pytest.approx(1.0, rel=1e-4)
    assert var_u == pytest.approx(widest, rel=0.01)


def test_other_weights_and_unaligned_input_reuse_the_blur_kernels():
    """The SoG weights (fitted per skin and band) are kernel inputs, and a NumPy map at any
    address makes the same kernels: nothing compiles anew (Dr.Jit's kernel history)."""
    sizes, valid = patch(0.2, 0.25)
    rng = np.random.default_rng(3)
    image = rng.uniform(size=(T, T)).astype(np.float32)
    blur_sum_of_gaussians(image, [0.3, 0.2, 0.5], [1e-6, 0.1, 0.8], sizes, valid)
    # 4 bytes past a 64-byte boundary: an address NumPy can hand out
    buffer = np.empty(T * T + 16, np.float32)
    start = (-buffer.ctypes.data % 64) // 4 + 1
    unaligned = buffer[start:start + T * T].reshape(T, T)
    unaligned[...] = rng.uniform(size=(T, T))
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        out = blur_sum_of_gaussians(unaligned, [0.1, 0.6, 0.3], [1e-6, 0.1, 0.8], sizes, valid)
        history = dr.kernel_history([dr.KernelType.JIT])
    # not in memory: compiled, or loaded from ~/.drjit (cache_disk), a kernel new to this process
    compiled = [h["hash"] for h in history if not h["cache_hit"] or h["cache_disk"]]
    assert history and not compiled, f"{len(compiled)} of {len(history)} blur kernels compiled anew"
    # the weights did take effect: the result is the weighted sum of single blurs
    expected = (0.1 * unaligned + 0.6 * blur_separable(unaligned, 0.1, sizes, valid)
                + 0.3 * blur_separable(unaligned, 0.8, sizes, valid))
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-6)


def test_other_widths_reuse_the_blur_kernels_and_the_adjoint_is_the_transpose():
    """Each Gaussian's taps are a symbolic loop whose bound, its half width, is a kernel
    input: a blur of other variances (5 and 23 taps a side where the first had 7 and 18) compiles nothing,
    forward or reverse. Unrolled, each set of widths was a kernel of its own, thousands of
    operations long. The reverse pass stays the forward blur's transpose:
    ``<w, B x> = <B^T w, x>``."""
    TensorXf = dr.llvm.ad.TensorXf
    sizes, valid = patch(0.2, 0.25)
    valid = valid.copy()
    valid[:, :9] = False  # an atlas border the taps must not cross
    rng = np.random.default_rng(4)
    image = rng.uniform(size=(T, T)).astype(np.float32)
    weights = rng.uniform(size=(T, T)).astype(np.float32)

    def blur_and_adjoint(variances):
        x = TensorXf(image)
        dr.enable_grad(x)
        y = blur_sum_of_gaussians(x, [0.4, 0.6], variances, sizes, valid)
        dr.backward(dr.sum(y * TensorXf(weights), axis=None))
        return y.numpy(), x.grad.numpy()

    blur_and_adjoint([0.1, 0.8])
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        out, adjoint = blur_and_adjoint([0.05, 1.3])
        history = dr.kernel_history([dr.KernelType.JIT])
    compiled = [h["hash"] for h in history if not h["cache_hit"] or h["cache_disk"]]
    assert history and not compiled, f"{len(compiled)} of {len(history)} blur kernels compiled anew"
    expected = 0.4 * blur_separable(image, 0.05, sizes, valid) + 0.6 * blur_separable(image, 1.3, sizes, valid)
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-6)
    forward = float(np.sum(weights.astype(np.float64) * out))
    assert float(np.sum(adjoint.astype(np.float64) * image)) == pytest.approx(forward, rel=1e-5)
    assert np.all(adjoint[~valid] == 0.0)
