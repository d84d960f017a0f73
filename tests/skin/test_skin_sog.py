"""Sums of Gaussians (eq. 16-17, 43) on the multipole profiles of the
Table 2 skins in the default bands."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from polarbssrdf.skin.layers import absorption_from_basis
from polarbssrdf.skin.model import band_chromophore_basis
from polarbssrdf.skin.multipole import slab_profiles
from polarbssrdf.skin.parameters import TABLE2
from polarbssrdf.skin.sog import (
    V0_MM2,
    discrete_kernel,
    fit_sog,
    gaussian,
    ladder_step_variance,
    normalized_weights,
    separable_kernels,
    sog_relative_error,
    variance_ladder,
)
from polarbssrdf.skin.twolayer import radial_energy, two_layer_profile
from polarbssrdf.spectral import default_bands

R_GRID = np.concatenate([[0.0], np.geomspace(1e-4, 30.0, 400)])


def _layer_profiles():
    """(name, key, band, profile) for the five layer profiles of every Table 2 skin and band."""
    basis = band_chromophore_basis(default_bands())
    out = []
    for key, p in TABLE2.items():
        sa_out, sa_in = absorption_from_basis(basis, p.C_m, p.beta_m, p.C_h_out, p.C_h_in)
        for band in range(len(basis["eumelanin"])):
            ss_out, ss_in = basis["scattering_epidermis"][band], basis["scattering_dermis"][band]
            R_f, T_f = slab_profiles(R_GRID, sa_out[band], ss_out, p.thickness_mm, p.eta, 1.0)
            R_b, T_b = slab_profiles(R_GRID, sa_out[band], ss_out, p.thickness_mm, 1.0, p.eta, incidence="diffuse")
            R_in, _ = slab_profiles(R_GRID, sa_in[band], ss_in, np.inf, 1.0, 1.0)
            for name, prof in (("R_out_f", R_f), ("T_out_f", T_f), ("R_out_b", R_b), ("T_out_b", T_b), ("R_in", R_in)):
                out.append((name, key, band, prof))
    return out


PROFILES = _layer_profiles()


def test_ladder_and_the_corrected_eq18():
    v = variance_ladder()
    assert v[0] == pytest.approx(V0_MM2) and np.allclose(v[1:] / v[:-1], 2.0)
    assert np.sqrt(v[-1]) >= 10.0  # covers mm-scale profiles
    h = 0.01
    x = np.arange(-256, 257) * h
    r = np.hypot(x[:, None], x[None, :])
    va = 0.01
    # G(v) * G(v) = G(2v): the default ladder's step ...
    same = fftconvolve(gaussian(va, r), gaussian(ladder_step_variance(va), r), mode="same") * h * h
    np.testing.assert_allclose(same, gaussian(2 * va, r), atol=1e-6 * gaussian(2 * va, 0.0))
    # ... not G(4v) as eq. 18 prints; the printed ladder needs G(v) * G(3v) = G(4v)
    assert np.max(np.abs(same - gaussian(4 * va, r))) > 0.1 * gaussian(4 * va, 0.0)
    conv = fftconvolve(gaussian(va, r), gaussian(ladder_step_variance(va, ratio=4.0), r),
                       mode="same") * h * h
    np.testing.assert_allclose(conv, gaussian(4 * va, r), atol=1e-6 * gaussian(4 * va, 0.0))


def test_every_layer_profile_fits_within_2_percent():
    """All five layer profiles of every Table 2 skin in every default band (eq. 16-17)."""
    worst = {}
    for name, key, band, prof in PROFILES:
        error = sog_relative_error(R_GRID, prof, fit_sog(R_GRID, prof))
        worst[name] = max(worst.get(name, 0.0), error)
    assert max(worst.values()) < 0.02, worst


def test_the_printed_ratio_4_ladder_fits_worse():
    """The ladder printed in the supplement (4^j v0) leaves larger errors than the default."""
    paper = variance_ladder(ratio=4.0)
    for name, key, band, prof in PROFILES[::7]:
        default_error = sog_relative_error(R_GRID, prof, fit_sog(R_GRID, prof))
        paper_error = sog_relative_error(R_GRID, prof, fit_sog(R_GRID, prof, paper), paper)
        assert default_error <= paper_error + 1e-6, (name, key, band)


def test_combined_two_layer_profile_fits_within_2_percent():
    basis = band_chromophore_basis(default_bands())
    r = np.concatenate([[0.0], np.geomspace(1e-4, 30.0, 200)])
    worst = 0.0
    for key in (("forehead", "I"), ("cheek", "IV")):
        p = TABLE2[key]
        sa_out, sa_in = absorption_from_basis(basis, p.C_m, p.beta_m, p.C_h_out, p.C_h_in)
        for band in (0, 3, 5):
            prof = two_layer_profile(r, sa_out[band], basis["scattering_epidermis"][band], sa_in[band],
                                     basis["scattering_dermis"][band], p.thickness_mm, p.eta)
            w = fit_sog(r, prof)
            # the weights carry the profile's energy (eq. 42: sum w = total)
            assert w.sum() == pytest.approx(radial_energy(r, prof), rel=0.02)
            worst = max(worst, sog_relative_error(r, prof, w))
    assert worst < 0.02


def test_normalized_and_discrete_kernels():
    name, _, _, prof = PROFILES[0]
    w = fit_sog(R_GRID, prof)
    wn = normalized_weights(w)
    assert wn.sum() == pytest.approx(1.0) and np.all(wn >= 0)
    kernel = discrete_kernel(w, variance_ladder(), texel_mm=0.05, radius_texels=20)
    assert kernel.shape == (41, 41) and kernel.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(kernel, kernel.T)
    np.testing.assert_allclose(kernel, kernel[::-1, ::-1])
    assert kernel[20, 20] == kernel.max()
    rows = separable_kernels(variance_ladder()[:4], 0.01, 10)
    np.testing.assert_allclose(rows.sum(axis=1), 1.0)
    with pytest.raises(ValueError):
        normalized_weights(np.zeros(3))
