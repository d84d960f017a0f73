"""Loss terms, regularizers and the closed-form albedo of the static stage.

Gradients are checked against central finite differences of the same
float32 loss on a few texels; regularizers against closed forms on maps
whose neighbourhood means are known; the albedo solve against its
defining least-squares property.
"""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from synthetic_texel_views import InMemoryStore, sphere_views

from polarbssrdf.inverse.config import static_config
from polarbssrdf.inverse.polarimetric.config import OPTIMIZED
from polarbssrdf.inverse.polarimetric.optimize import (
    REGULARIZER_TERMS,
    MapParameters,
    active_weights,
    patch_gradients,
    patch_losses,
)
from polarbssrdf.inverse.polarimetric.losses import DATA_TERMS
from polarbssrdf.inverse.polarimetric.patches import prepare_patch, texture_patches

T = 16
BANDS = ("b0", "b1")


@pytest.fixture(scope="module")
def problem():
    """A sphere seen by 12 views, maps a little off the truth so every gradient is non-zero."""
    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import texel_atlas, to_mitsuba, uv_sphere

    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=24, segments=48)), T)
    rng = np.random.default_rng(5)
    truth = {"eta": 1.48, "rho_s": 0.8, "alpha_s": 0.4, "rho_ss": 0.3, "alpha_ss": 0.95}
    truth = {k: np.full((T, T), v, np.float32) for k, v in truth.items()}
    truth["normal"] = atlas.normal
    rho_sss = np.stack([np.full((T, T), 0.5, np.float32), np.full((T, T), 0.7, np.float32)])
    views = sphere_views(atlas, truth, rho_sss, n_cameras=12)
    store = InMemoryStore(views, T, BANDS, block_size=8)
    start = {k: (truth[k] + rng.normal(0, 0.02, (T, T))).astype(np.float32)
             for k in ("eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss")}
    start["alpha_ss"] = np.clip(start["alpha_ss"], 0.7, 1.0)
    start["displacement"] = rng.normal(0, 0.05, (T, T)).astype(np.float32)
    # the loss's own gradient: the Sobolev preconditioner's step is checked separately below
    config = static_config(patch_size=16, min_cosine=0.2,
                           sobolev_lengths={name: 0.0 for name in OPTIMIZED})
    prepared = prepare_patch(store, atlas, texture_patches(T, 16, 8)[0])
    return atlas, store, start, rho_sss * 0.97, config, prepared


def _params(maps, rho_sss, config):
    return MapParameters(maps, rho_sss, config.learning_rates)


def _term(maps, rho_sss, config, prepared, name):
    params = _params(maps, rho_sss, config)
    terms = patch_losses(params, prepared, config, active_weights(config),
                         solve_albedo=False).terms
    value = terms[name]
    return (value if isinstance(value, float) else float(value[0])), params


def _gradient(maps, rho_sss, config, prepared, term):
    """The gradient the optimizer steps with, of ``term`` alone (weight 1, every other 0)."""
    params = _params(maps, rho_sss, config)
    weights = {name: 0.0 for name in DATA_TERMS + REGULARIZER_TERMS}
    weights[term] = 1.0
    patch_gradients(params, prepared, config, weights, solve_albedo=False)
    return params


STEPS = {"eta": 2e-3, "rho_s": 2e-3, "alpha_s": 2e-3, "rho_ss": 2e-3, "alpha_ss": 2e-3,
         "displacement": 5e-3}

DEPENDS = {  # the maps each term depends on
    "sss": OPTIMIZED, "s": OPTIMIZED, "psi": OPTIMIZED, "phi": OPTIMIZED,
    "H_magnitude": ("displacement",), "H_laplacian": ("displacement",),
    "alpha_s_smoothness": ("alpha_s",), "alpha_ss_smoothness": ("alpha_ss",),
    "eta_smoothness": ("eta",),
}


@pytest.mark.parametrize("term", DATA_TERMS + REGULARIZER_TERMS)
def test_gradients_match_central_differences(problem, term):
    """Data terms through Dr.Jit's reverse pass, regularizers through their own adjoints."""
    atlas, store, start, rho_sss, config, prepared = problem
    params = _gradient(start, rho_sss, config, prepared, term)
    gradients = {name: np.array(dr.grad(params.optimizer[name]), dtype=np.float64).ravel()
                 for name in DEPENDS[term]}
    # 1% of the term's largest sensitivity: a map that barely matters to a term (alpha_s in the
    # cross-polarized I_sss) moves its float32 value below rounding
    scale = max(np.max(np.abs(g) * STEPS[name]) for name, g in gradients.items())
    for name, analytic in gradients.items():
        assert np.max(np.abs(analytic)) > 0, (term, name)
        # the texels where the term is most sensitive: float32 differences resolve there
        texels = np.argsort(-np.abs(analytic))[:3]
        for texel in texels:
            step = STEPS[name]
            shifted = []
            for sign in (1, -1):
                maps = {k: v.copy() for k, v in start.items()}
                maps[name].ravel()[texel] += sign * step
                shifted.append(_term(maps, rho_sss, config, prepared, term)[0])
            numeric = (shifted[0] - shifted[1]) / (2 * step)
            assert analytic[texel] == pytest.approx(numeric, rel=0.01, abs=0.01 * scale / step), \
                (term, name, texel)


def test_the_stepped_gradient_is_the_loss_gradient_preconditioned(problem):
    """With a smoothing length the optimizer steps ``(I + l^2 L)^-1`` of the loss's gradient on
    the window (zero off the mesh); a map without one steps the plain gradient."""
    import dataclasses

    from polarbssrdf.inverse.polarimetric.preconditioning import sobolev_gradient

    atlas, store, start, rho_sss, config, prepared = problem
    plain = _gradient(start, rho_sss, config, prepared, "sss")
    lengths = dict(config.sobolev_lengths, displacement=3.0)
    smoothed = _gradient(start, rho_sss, dataclasses.replace(config, sobolev_lengths=lengths),
                         prepared, "sss")

    def grad(params, name):
        return np.array(dr.grad(params.optimizer[name]), dtype=np.float64)

    expected = sobolev_gradient(grad(plain, "displacement")[prepared.window_rows,
                                                             prepared.window_cols],
                                3.0, prepared.window_valid)
    window = grad(smoothed, "displacement")[prepared.window_rows, prepared.window_cols]
    assert window == pytest.approx(expected, rel=1e-5, abs=1e-6 * np.max(np.abs(expected)))
    assert not np.allclose(window, grad(plain, "displacement")[prepared.window_rows,
                                                                prepared.window_cols])
    assert np.array_equal(grad(smoothed, "eta"), grad(plain, "eta"))


def test_closed_form_albedo_is_the_least_squares_solution(problem):
    atlas, store, start, rho_sss, config, prepared = problem
    params = _params(start, rho_sss, config)
    weights = active_weights(config)
    patch_losses(params, prepared, config, weights)  # solves rho_sss in place
    solved = params.rho_sss.copy()
    base = _term(start, solved, config, prepared, "sss")[0]
    for factor in (0.99, 1.01):
        worse = _term(start, solved * factor, config, prepared, "sss")[0]
        assert worse > base


def test_closed_form_albedo_is_exact_at_the_truth(problem):
    """With the glossy maps and normals of the truth, the solve returns the true albedo."""
    atlas, store, _, rho_sss_start, config, prepared = problem
    truth = {"eta": 1.48, "rho_s": 0.8, "alpha_s": 0.4, "rho_ss": 0.3, "alpha_ss": 0.95,
             "displacement": 0.0}
    maps = {k: np.full((T, T), v, np.float32) for k, v in truth.items()}
    params = _params(maps, rho_sss_start, config)
    patch_losses(params, prepared, config, active_weights(config))
    seen = np.bincount(prepared.window_index[prepared.texel_numpy], minlength=T * T) > 0
    for band, value in enumerate((0.5, 0.7)):
        recovered = params.rho_sss[band].ravel()[seen]
        np.testing.assert_allclose(recovered, value, rtol=2e-4)


def test_regularizers_vanish_on_maps_they_should_not_penalize():
    from polarbssrdf.inverse.polarimetric.regularizers import (
        displacement_laplacian,
        displacement_magnitude,
        neighbourhood_smoothness,
        window_stencils,
    )

    size = 12
    valid = np.ones((size, size), bool)
    stencils = window_stencils(valid, slice(2, 10), slice(2, 10))
    i, j = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    ramp = 0.3 * i + 0.2 * j
    # the mean of a symmetric neighbourhood of a linear map is the centre value
    for function in (neighbourhood_smoothness, displacement_laplacian):
        value, gradient = function(ramp, stencils)
        assert value == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(gradient, 0.0, atol=1e-12)
    # H = a i^2: the 5-point Laplacian is 2a everywhere
    a = 0.01
    quadratic = a * i ** 2
    assert displacement_laplacian(quadratic, stencils)[0] == pytest.approx((2 * a) ** 2, rel=1e-9)
    assert displacement_magnitude(quadratic, stencils)[0] == pytest.approx(
        np.mean((a * i[2:10, 2:10] ** 2) ** 2), rel=1e-12)
    # a +-1 checkerboard: 12 of the 24 neighbours agree with the centre, 12 oppose it
    checker = np.where((i + j) % 2, 1.0, -1.0)
    assert neighbourhood_smoothness(checker, stencils)[0] == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("name", ["displacement_magnitude", "displacement_laplacian",
                                  "neighbourhood_smoothness"])
def test_regularizer_gradients_match_central_differences_at_every_texel(name):
    """On a window with holes, halo and clamped edges: every texel's derivative (float64)."""
    from polarbssrdf.inverse.polarimetric import regularizers

    function = getattr(regularizers, name)
    rng = np.random.default_rng(3)
    valid = rng.random((11, 13)) > 0.25
    stencils = regularizers.window_stencils(valid, slice(0, 9), slice(2, 13))
    values = rng.normal(size=valid.shape)
    _, gradient = function(values, stencils)
    step = 1e-6
    numeric = np.zeros_like(values)
    for texel in range(values.size):
        shift = np.zeros(values.size)
        shift[texel] = step
        shift = shift.reshape(values.shape)
        numeric.flat[texel] = (function(values + shift, stencils)[0]
                               - function(values - shift, stencils)[0]) / (2 * step)
    assert np.count_nonzero(gradient) > values.size // 3  # the halo moves too
    np.testing.assert_allclose(gradient, numeric, atol=1e-7 * np.abs(numeric).max())


def test_a_texel_view_with_a_non_finite_gradient_is_dropped_not_the_step(problem):
    """One singular texel-view must not turn its patch's gradient into NaN."""
    from polarbssrdf.inverse.polarimetric.optimize import _leaf_gradients

    atlas, store, start, rho_sss, config, prepared = problem
    params = _params(start, rho_sss, config)
    loss = patch_losses(params, prepared, config, active_weights(config), solve_albedo=False,
                        differentiable=True)
    dr.backward(loss.total)
    clean, dropped = _leaf_gradients(loss.leaves, prepared)
    assert dropped == 0
    leaf = loss.leaves["eta"]
    poisoned = np.array(dr.grad(leaf))
    poisoned[5] = np.nan
    dr.set_grad(leaf, type(leaf)(poisoned))
    gradients, dropped = _leaf_gradients(loss.leaves, prepared)
    assert dropped == 1
    texel = prepared.texel_numpy[5]
    for name, window in gradients.items():
        assert np.isfinite(window).all(), name
    others = np.arange(len(prepared.window_index)) != texel
    np.testing.assert_array_equal(gradients["eta"][others], clean["eta"][others])
