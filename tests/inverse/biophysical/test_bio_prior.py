"""The biophysical prior and posterior spread against dense linear algebra (NumPy only, about 10 s)."""

import numpy as np
import pytest

from polarbssrdf.inverse.biophysical.prior import (
    FourierPreconditioner,
    SpatialPrior,
    held_map_error_covariance,
    lattice_spectrum,
    mean_mode_covariance,
    noise_spectrum,
    population_prior,
    posterior_covariance,
    within_face_spread,
)
from polarbssrdf.skin.parameters import TABLE2, TABLE2_STD

T, H, L = 40, 0.5, 2.0  # texels, texel size (mm), correlation length (mm)


def grid_prior(order, texels=T):
    surface = np.ones((texels, texels), bool)
    return SpatialPrior(surface, np.full((texels, texels, 2), H), L, order)


@pytest.mark.parametrize("order", [1, 2])
def test_the_prior_alone_has_the_marginal_spread_asked_for(order):
    """diag(Q^-1) at the grid's centre = std^2 (the lattice spectrum's scale, not a fitted one)."""
    prior = grid_prior(order)
    std = 0.01
    covariance = np.linalg.inv(prior.unit.toarray() / prior.tau2(std))
    centre = (T // 2) * T + T // 2
    assert np.sqrt(covariance[centre, centre]) == pytest.approx(std, rel=0.01)
    # farther from the centre the field is as uncertain; at a corner (2 neighbours) more so
    assert covariance[0, 0] > covariance[centre, centre]


def two_map_data_covariance(sigma, correlation):
    """(2, 2) covariance of two maps' per-texel data errors of std ``sigma`` and ``correlation``."""
    off = correlation * sigma[0] * sigma[1]
    return np.array([[sigma[0] ** 2, off], [off, sigma[1] ** 2]])


@pytest.mark.parametrize("order", [1, 2])
def test_posterior_covariance_matches_the_dense_inverse_for_two_correlated_maps(order):
    """Two maps whose data are 80% correlated per texel: the quadrature's (k x k) covariance
    at the centre texel against ``(C (x) I + Q)^-1`` of the whole grid."""
    prior = grid_prior(order)
    n = T * T
    tau2 = np.array([prior.tau2(0.01), prior.tau2(0.02)])
    data_covariance = two_map_data_covariance([0.004, 0.01], 0.8)
    C = np.linalg.inv(data_covariance)
    Q = prior.unit.toarray()
    H_dense = np.kron(np.eye(n), C) + np.kron(Q, np.diag(1.0 / tau2))
    centre = (T // 2) * T + T // 2
    rows = [2 * centre, 2 * centre + 1]
    unit = np.zeros((2 * n, 2))
    unit[rows, [0, 1]] = 1.0
    dense = np.linalg.solve(H_dense, unit)[rows]
    quadrature = posterior_covariance(C[None], np.array([H * H]), tau2, L, order)[0]
    np.testing.assert_allclose(np.sqrt(np.diag(quadrature)), np.sqrt(np.diag(dense)), rtol=0.02)
    assert quadrature[0, 1] / np.sqrt(quadrature[0, 0] * quadrature[1, 1]) == pytest.approx(
        dense[0, 1] / np.sqrt(dense[0, 0] * dense[1, 1]), abs=0.02)
    # the prior narrows what the data alone allow; the data narrow the prior
    assert np.all(np.diag(quadrature) < np.diag(data_covariance))
    assert np.all(np.diag(quadrature) < [0.01 ** 2, 0.02 ** 2])


def test_the_face_mean_adds_its_uncertainty_through_the_constant_mode():
    """A free face mean with a hyperprior: the texel's total variance against the dense joint
    inverse over (field, mean)."""
    prior = grid_prior(2, texels=24)
    n = prior.unit.shape[0]
    std, mean_std, data_std = 0.01, 0.02, 0.03
    tau2 = prior.tau2(std)
    Q = prior.unit.toarray() / tau2
    c = 1.0 / data_std ** 2
    ones = np.ones(n)
    joint = np.zeros((n + 1, n + 1))
    joint[:n, :n] = Q + c * np.eye(n)
    joint[:n, n] = joint[n, :n] = -Q @ ones
    joint[n, n] = ones @ Q @ ones + 1.0 / mean_std ** 2
    dense = np.linalg.inv(joint)
    centre = (24 // 2) * 24 + 24 // 2
    C = np.full((n, 1, 1), c)
    field = posterior_covariance(C, prior.area, [tau2], L, 2)
    extra, mean_covariance = mean_mode_covariance(C, prior.area, [tau2], [mean_std ** 2])
    assert np.sqrt(mean_covariance[0, 0]) == pytest.approx(np.sqrt(dense[n, n]), rel=0.05)
    total = field[centre, 0, 0] + extra[centre, 0, 0]
    assert np.sqrt(total) == pytest.approx(np.sqrt(dense[centre, centre]), rel=0.05)
    # a fixed mean adds nothing
    none, _ = mean_mode_covariance(C, prior.area, [tau2], [0.0])
    assert np.all(none == 0)


def test_the_fourier_preconditioner_inverts_the_system_for_constant_data():
    """On a periodic texture the preconditioner is the exact inverse; on the bounded grid it is
    close in the interior, which is what makes conjugate gradients converge in tens of steps."""
    prior = grid_prior(2)
    tau2 = np.array([prior.tau2(0.01)])
    C = np.array([[1e4]])
    P = FourierPreconditioner((T, T), prior.index, H * H, tau2, C, L, 2)
    rng = np.random.default_rng(3)
    field = rng.standard_normal((T, T))
    # a smooth field well inside the grid
    yy, xx = np.mgrid[:T, :T]
    x = (np.exp(-((yy - T / 2) ** 2 + (xx - T / 2) ** 2) / 30.0) * (1 + 0.1 * field)).reshape(-1, 1)
    Hx = C[0, 0] * x + (prior.unit @ x) / tau2[0]
    recovered = P(Hx)
    inside = (np.abs(yy - T / 2) < T / 4) & (np.abs(xx - T / 2) < T / 4)
    error = np.abs(recovered - x).ravel()[inside.ravel()]
    assert np.max(error) < 0.05 * np.max(np.abs(x))


def test_the_noise_spectrum_is_the_lattice_transform_of_the_correlation():
    """Nearest-neighbour correlation rho gives ``S = 1 + 4 rho - rho lambda`` (exact: linear in
    lambda, so also per bin); any correlation averages to 1 over the zone (the variance is
    kept), white noise is 1 everywhere."""
    lam, weight = lattice_spectrum()
    rho = 0.2
    spectrum = noise_spectrum({(0, 1): rho, (0, -1): rho, (1, 0): rho, (-1, 0): rho})
    np.testing.assert_allclose(spectrum, 1.0 + 4.0 * rho - rho * lam, rtol=1e-6, atol=1e-6)
    assert np.sum(weight * noise_spectrum({(0, 1): 0.1, (1, 1): 0.05, (2, -1): -0.02})) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(noise_spectrum({(0, 1): 0.0}), 1.0)


def test_the_sandwich_covariance_matches_the_dense_one_under_correlated_noise():
    """Data noise correlated between horizontal and vertical neighbours (rho 0.2): the
    quadrature's variance at the centre texel against ``H^-1 (C^1/2 R C^1/2 + Q) H^-1``
    of the whole grid (``R`` the noise correlation, ``H = C + Q`` what the fit weighs
    with); correlated noise leaves the estimate more uncertain than white noise says."""
    prior = grid_prior(2)
    n = T * T
    tau2 = prior.tau2(0.01)
    c = 1.0 / 0.004 ** 2
    Q = prior.unit.toarray() / tau2
    rho = 0.2
    yy, xx = np.divmod(np.arange(n), T)
    neighbours = (np.abs(yy[:, None] - yy[None]) + np.abs(xx[:, None] - xx[None])) == 1
    R = np.eye(n) + rho * neighbours
    H_inverse = np.linalg.inv(c * np.eye(n) + Q)
    dense = H_inverse @ (c * R + Q) @ H_inverse
    centre = (T // 2) * T + T // 2
    spectrum = noise_spectrum({(0, 1): rho, (0, -1): rho, (1, 0): rho, (-1, 0): rho})
    quadrature = posterior_covariance(np.full((1, 1, 1), c), np.array([H * H]), [tau2], L, 2, spectrum=spectrum)
    assert quadrature[0, 0, 0] == pytest.approx(dense[centre, centre], rel=0.03)
    white = posterior_covariance(np.full((1, 1, 1), c), np.array([H * H]), [tau2], L, 2)
    assert white[0, 0, 0] == pytest.approx(H_inverse[centre, centre], rel=0.03)
    assert quadrature[0, 0, 0] > 1.2 * white[0, 0, 0]


def test_a_held_map_adds_the_error_it_makes_and_more_than_marginalizing_it_does():
    """One fitted map and one held at its prior mean (the fit renders at the face's oxygenation
    while the truth's varies within the face), their data 70% correlated per texel. The
    fitted map's error covariance at the centre texel against the dense
    ``H_cc^-1 (C_cc + Q_c) H_cc^-1 + H_cc^-1 C_ch Q_h^-1 C_hc H_cc^-1`` over the whole grid;
    marginalizing the held map (the joint posterior's Schur complement) is smaller: that is
    the spread of an estimate that fits the held map, not of one that holds it."""
    prior = grid_prior(2)
    n = T * T
    tau2 = np.array([prior.tau2(0.01), prior.tau2(0.02)])
    C = np.linalg.inv(two_map_data_covariance([0.004, 0.006], 0.7))
    unit = prior.unit.toarray()
    H_cc = C[0, 0] * np.eye(n) + unit / tau2[0]
    H_cc_inverse = np.linalg.inv(H_cc)
    held_covariance = np.linalg.inv(unit / tau2[1])
    # white noise: the sandwich H_cc^-1 (C_cc + Q_c) H_cc^-1 is H_cc^-1
    dense = H_cc_inverse + C[0, 1] ** 2 * H_cc_inverse @ held_covariance @ H_cc_inverse
    centre = (T // 2) * T + T // 2
    quadrature = held_map_error_covariance(C[None], 1, np.array([H * H]), tau2, L, 2)[0]
    assert quadrature.shape == (1, 1)
    assert quadrature[0, 0] == pytest.approx(dense[centre, centre], rel=0.03)
    joint = posterior_covariance(C[None], np.array([H * H]), tau2, L, 2)[0]
    assert quadrature[0, 0] > 1.2 * joint[0, 0]
    # nothing held: the posterior covariance itself
    alone = held_map_error_covariance(C[None, :1, :1], 0, np.array([H * H]), tau2[:1], L, 2)
    np.testing.assert_allclose(alone, posterior_covariance(C[None, :1, :1], np.array([H * H]), tau2[:1], L, 2))


def test_population_prior_and_within_face_spread_come_from_table2():
    hyper = population_prior()
    spread = within_face_spread()
    for name in ("C_m", "beta_m", "C_h_out", "C_h_in"):
        means = [getattr(p, name) for p in TABLE2.values()]
        assert hyper[name][0] == pytest.approx(np.mean(means))
        assert hyper[name][1] == pytest.approx(np.std(means))
        assert spread[name] == pytest.approx(np.mean([row[name] for row in TABLE2_STD.values()]))
        # the population spread of the face mean is wider than one face's own
        assert hyper[name][1] > spread[name]


def _two_map_system(texels, mean_std, seed):
    """A Gauss-Newton system of C_m and C_h_out on a square grid: the prior, its
    ``PriorTerms`` (face means of hyperprior std ``mean_std``; 0 holds a mean), data blocks
    from six bands that vary over the grid, and the generator for right-hand sides."""
    from polarbssrdf.inverse.biophysical.gauss_newton import PriorTerms

    prior = grid_prior(2, texels)
    n = texels * texels
    terms = PriorTerms(["C_m", "C_h_out"], prior, std=[0.004, 0.01], mean0=[0.05, 0.07],
                       mean_variance=np.square(mean_std), start=[0.05, 0.07], adapt=[True, True])
    rng = np.random.default_rng(seed)
    J = rng.standard_normal((n, 6, 2)) * np.array([300.0, 100.0]) * rng.uniform(0.5, 2.0, (n, 1, 1))
    return prior, terms, np.einsum("nbi,nbj->nij", J, J), rng


def test_the_gauss_newton_step_solves_the_joint_system_of_maps_and_face_means():
    """solve_step (CG, Fourier preconditioned) against the dense solve of the system over two
    maps and their free face means, with data blocks that vary over the grid."""
    from polarbssrdf.inverse.biophysical.gauss_newton import solve_step

    texels = 20
    n = texels * texels
    prior, terms, blocks, rng = _two_map_system(texels, mean_std=(0.02, 0.03), seed=11)
    rhs_x, rhs_mu = rng.standard_normal((n, 2)), rng.standard_normal(2)
    step, step_mu, _ = solve_step(blocks, terms, rhs_x, rhs_mu, damping=0.0, rtol=1e-8, max_iterations=2000)
    Q = prior.unit.toarray()
    inverse_tau2 = 1.0 / terms.tau2
    dense = np.zeros((2 * n + 2, 2 * n + 2))
    dense[:2 * n, :2 * n] = _block_diagonal(blocks) + np.kron(Q, np.diag(inverse_tau2))
    for m in range(2):
        coupling = -(Q @ np.ones(n)) * inverse_tau2[m]
        dense[np.arange(n) * 2 + m, 2 * n + m] = coupling
        dense[2 * n + m, np.arange(n) * 2 + m] = coupling
        dense[2 * n + m, 2 * n + m] = np.ones(n) @ Q @ np.ones(n) * inverse_tau2[m] + 1.0 / terms.mean_variance[m]
    solution = np.linalg.solve(dense, np.concatenate([rhs_x.ravel(), rhs_mu]))
    np.testing.assert_allclose(step.ravel(), solution[:2 * n], rtol=1e-4, atol=1e-6 * np.abs(solution).max())
    np.testing.assert_allclose(step_mu, solution[2 * n:], rtol=1e-4, atol=1e-6 * np.abs(solution).max())


def test_the_step_holds_the_active_set_and_predicts_the_quadratic_models_decrease():
    """With some values fixed (at a bound), solve_step against the dense solve of the system
    with those rows and columns removed; its predicted decrease against ``r.d - d.H d / 2``
    of the undamped dense system, also with damping on."""
    from polarbssrdf.inverse.biophysical.gauss_newton import solve_step

    texels = 16
    n = texels * texels
    prior, terms, blocks, rng = _two_map_system(texels, mean_std=(0.0, 0.0), seed=12)
    rhs_x = rng.standard_normal((n, 2))
    fixed = rng.uniform(size=(n, 2)) < 0.1
    H = _block_diagonal(blocks) + np.kron(prior.unit.toarray(), np.diag(1.0 / terms.tau2))
    free = ~fixed.ravel()
    for damping in (0.0, 0.3):
        step, step_mu, predicted = solve_step(blocks, terms, rhs_x, np.zeros(2), damping=damping, rtol=1e-10,
                                               max_iterations=3000, fixed=fixed)
        assert np.all(step[fixed] == 0.0) and np.all(step_mu == 0.0)
        damped = H + damping * np.diag(np.diag(H))
        expected = np.zeros(2 * n)
        expected[free] = np.linalg.solve(damped[np.ix_(free, free)], rhs_x.ravel()[free])
        np.testing.assert_allclose(step.ravel(), expected, rtol=1e-5, atol=1e-7 * np.abs(expected).max())
        d = expected
        assert predicted == pytest.approx(rhs_x.ravel() @ d - 0.5 * d @ H @ d, rel=1e-6)


def _block_diagonal(blocks):
    n, k, _ = blocks.shape
    out = np.zeros((n * k, n * k))
    for i in range(n):
        out[i * k:(i + 1) * k, i * k:(i + 1) * k] = blocks[i]
    return out


def test_expected_prior_energy_is_the_trace_of_the_em_update():
    """Per texel ``[U Sigma]_ii`` of the dense posterior (interior texels) against the quadrature,
    and the EM update keeps a spread the data cannot tell (C = 0) where it is."""
    from polarbssrdf.inverse.biophysical.prior import expected_prior_energy, updated_spread

    prior = grid_prior(2)
    tau2 = prior.tau2(0.01)
    U = prior.unit.toarray()
    c = 1.0 / 0.02 ** 2
    Sigma = np.linalg.inv(U / tau2 + c * np.eye(T * T))
    yy, xx = np.divmod(np.arange(T * T), T)
    inside = (np.abs(yy - T / 2) < T / 4) & (np.abs(xx - T / 2) < T / 4)
    dense = np.mean(np.einsum("ij,ji->i", U, Sigma)[inside])
    quadrature = expected_prior_energy(np.full((1, 1, 1), c), np.array([H * H]), [tau2], L, 2)[0, 0]
    assert quadrature == pytest.approx(dense, rel=0.03)
    # no data: the posterior is the prior, E[d^T U d] / n = tau2, the spread stays
    energy = expected_prior_energy(np.zeros((T * T, 1, 1)), prior.area, [tau2], L, 2)[:, 0]
    new_tau2, new_std = updated_spread(np.zeros(T * T), prior.unit, energy, tau2, 0.01)
    assert new_std == pytest.approx(0.01, rel=0.02)


def test_the_blurred_posterior_matches_the_dense_one():
    """Data seen through a Gaussian blur of 0.7 texels (the cheek's capture): the quadrature with
    the blur's gain (:func:`capture_gain`) against ``(K^T C K + Q)^-1`` of the whole grid,
    ``K`` the blur as a dense matrix; a blurred capture leaves each texel less certain."""
    from polarbssrdf.inverse.biophysical.prior import capture_gain

    prior = grid_prior(2)
    n = T * T
    tau2 = prior.tau2(0.01)
    c = 1.0 / 0.004 ** 2
    sigma_texels = 0.7
    yy, xx = np.divmod(np.arange(n), T)
    distance2 = (yy[:, None] - yy[None]) ** 2 + (xx[:, None] - xx[None]) ** 2
    K = np.exp(-0.5 * distance2 / sigma_texels ** 2)
    K /= K.sum(axis=1, keepdims=True)
    dense = np.linalg.inv(c * K.T @ K + prior.unit.toarray() / tau2)
    centre = (T // 2) * T + T // 2
    area = np.array([H * H])
    gain = capture_gain(area, (sigma_texels * H) ** 2)
    blurred = posterior_covariance(np.full((1, 1, 1), c), area, [tau2], L, 2, gain=gain)[0, 0, 0]
    assert blurred == pytest.approx(dense[centre, centre], rel=0.05)
    sharp = posterior_covariance(np.full((1, 1, 1), c), area, [tau2], L, 2)[0, 0, 0]
    assert blurred > 1.2 * sharp
    assert capture_gain(area, 0.0) is None


def test_the_per_texel_solve_is_the_eigenbasis_one_for_one_symbol():
    """A correlation length given per texel and map (the freed prior's path) that is the same
    everywhere gives what the shared eigenbasis gives: covariance, held maps' error, and the
    EM update's prior energy, with a blur and correlated noise."""
    from polarbssrdf.inverse.biophysical.prior import capture_gain, expected_prior_energy

    rng = np.random.default_rng(4)
    n, k = 5, 3
    root = rng.standard_normal((n, k, k)) * 30.0
    C = np.einsum("nij,nkj->nik", root, root) + 10.0 * np.eye(k)
    area = rng.uniform(0.2, 0.4, n)
    tau2 = np.array([1e-4, 4e-4, 2e-4])
    gain = capture_gain(area, 0.1)
    spectrum = noise_spectrum({(0, 1): 0.3, (0, -1): 0.3, (1, 0): 0.2, (-1, 0): 0.2})
    every = np.full((n, k), L)
    np.testing.assert_allclose(posterior_covariance(C, area, tau2, every, 2, spectrum, gain),
                               posterior_covariance(C, area, tau2, L, 2, spectrum, gain), rtol=1e-6)
    np.testing.assert_allclose(held_map_error_covariance(C, 1, area, tau2, every, 2, spectrum, gain),
                               held_map_error_covariance(C, 1, area, tau2, L, 2, spectrum, gain), rtol=1e-6)
    np.testing.assert_allclose(expected_prior_energy(C, area, tau2, every, 2, gain),
                               expected_prior_energy(C, area, tau2, L, 2, gain), rtol=1e-6)
    # a texel whose spread is freed (tau^2 / w, w = 0.01) is less certain there, not elsewhere
    freed = np.tile(tau2, (n, 1))
    freed[2] /= 0.01
    wide = posterior_covariance(C, area, freed, every, 2, None, gain)
    base = posterior_covariance(C, area, tau2, every, 2, None, gain)
    assert np.all(np.diagonal(wide[2]) > np.diagonal(base[2]))
    np.testing.assert_allclose(np.delete(wide, 2, axis=0), np.delete(base, 2, axis=0))
