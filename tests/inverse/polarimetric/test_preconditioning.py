"""The Sobolev-preconditioned gradient: an exact solve of (I + l^2 L) on the window, checked
against an independent Laplacian, its spectrum, and what it does to an optimizer."""

import numpy as np
import pytest

from polarbssrdf.inverse.polarimetric.config import StaticConfig, merged_config
from polarbssrdf.inverse.polarimetric.preconditioning import sobolev_gradient


def graph_laplacian(x):
    """5-point graph Laplacian, each texel minus its neighbours summed over the ones that exist
    (reflecting edges): edge padding makes the missing neighbour's difference 0."""
    padded = np.pad(x, 1, mode="edge")
    return (4.0 * x - padded[:-2, 1:-1] - padded[2:, 1:-1]
            - padded[1:-1, :-2] - padded[1:-1, 2:])


@pytest.mark.parametrize("shape, length", [((17, 23), 3.0), ((64, 40), 8.0), ((5, 1), 2.0)])
def test_the_solve_inverts_identity_plus_laplacian(shape, length):
    rng = np.random.default_rng(4)
    gradient = rng.normal(size=shape)
    smoothed = sobolev_gradient(gradient, length)
    assert smoothed + length ** 2 * graph_laplacian(smoothed) == pytest.approx(gradient, abs=1e-10)


def test_each_cosine_mode_keeps_its_share_and_the_mean_passes_whole():
    rows, cols, length = 32, 48, 4.0
    i = (np.arange(rows)[:, None] + 0.5) / rows
    j = (np.arange(cols)[None, :] + 0.5) / cols
    for k, m in ((0, 0), (1, 0), (0, 3), (5, 7)):
        mode = np.cos(np.pi * k * i) * np.cos(np.pi * m * j)
        eigenvalue = (2 - 2 * np.cos(np.pi * k / rows)) + (2 - 2 * np.cos(np.pi * m / cols))
        expected = mode / (1.0 + length ** 2 * eigenvalue)
        assert sobolev_gradient(mode, length) == pytest.approx(expected, abs=1e-12)
    # a long wavelength keeps far more of its gradient than a texel-scale one
    long_wave = np.cos(np.pi * i) * np.ones_like(j)
    short_wave = np.cos(np.pi * (rows - 1) * i) * np.ones_like(j)
    assert (np.abs(sobolev_gradient(long_wave, length)).max()
            > 50 * np.abs(sobolev_gradient(short_wave, length)).max())


def test_length_zero_is_the_plain_gradient_and_the_mask_zeroes_texels_off_the_mesh():
    rng = np.random.default_rng(1)
    gradient = rng.normal(size=(12, 9))
    assert np.array_equal(sobolev_gradient(gradient, 0.0), gradient)
    valid = rng.random((12, 9)) > 0.3
    smoothed = sobolev_gradient(gradient * valid, 5.0, valid)
    assert np.all(smoothed[~valid] == 0) and np.any(smoothed[valid] != 0)


@pytest.mark.parametrize("length", [-1.0, float("nan"), float("inf")])
def test_a_bad_length_is_refused_by_name(length):
    with pytest.raises(ValueError, match="length"):
        sobolev_gradient(np.zeros((4, 4)), length)
    with pytest.raises(ValueError, match="sobolev_lengths.displacement"):
        merged_config({"sobolev_lengths": {"displacement": length}})


def test_the_config_merges_one_length_and_refuses_unknown_maps():
    config = merged_config({"sobolev_lengths": {"eta": 2.0}})
    assert config.sobolev_lengths["eta"] == 2.0
    assert config.sobolev_lengths["displacement"] == StaticConfig().sobolev_lengths["displacement"]
    with pytest.raises(ValueError, match="sobolev_lengths"):
        merged_config({"sobolev_lengths": {"rho_sss": 2.0}})


def test_rmsprop_reaches_a_smooth_relief_in_a_fraction_of_the_steps():
    """What the stage gains, on the fit's own optimizer and loss shape: a relief seen through its
    slopes (sum of squared slope residuals plus the fit's Laplacian prior), from zero, with the
    fit's RMSProp at a fixed step budget. The face-scale bowl is what plain steps leave behind."""
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import TensorXf

    n = 64
    y, x = np.mgrid[0:n, 0:n] / (n - 1.0)
    truth = 2.0 * ((x - 0.5) ** 2 + (y - 0.5) ** 2) + 0.1 * np.sin(12 * x) * np.cos(9 * y)
    truth -= truth.mean()

    def slopes(h):
        return np.diff(h, axis=0), np.diff(h, axis=1)

    target = slopes(truth)

    def gradient(h):
        dv, du = (s - t for s, t in zip(slopes(h), target))
        g = np.zeros_like(h)
        g[1:, :] += dv
        g[:-1, :] -= dv
        g[:, 1:] += du
        g[:, :-1] -= du
        return 2.0 * g + 2e-3 * graph_laplacian(graph_laplacian(h))

    def fit(length, steps=300):
        optimizer = dr.opt.RMSProp(lr=2e-3)
        optimizer["h"] = TensorXf(np.zeros((n, n), np.float32))
        for _ in range(steps):
            g = gradient(np.array(optimizer["h"], np.float64))
            if length:
                g = sobolev_gradient(g, length)
            dr.set_grad(optimizer["h"], TensorXf(g.astype(np.float32)))
            optimizer.step()
        h = np.array(optimizer["h"], np.float64)
        h -= h.mean()
        return float(np.sum(h * truth) / np.sum(truth * truth))

    plain, preconditioned = fit(0.0), fit(8.0)
    assert plain < 0.7
    assert 0.85 < preconditioned < 1.15
