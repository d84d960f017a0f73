"""The biophysical fit's solver: one projected, damped Gauss-Newton over the maps and their face
means (supplement sec. 5.3, eq. 41 with the Matérn prior of :mod:`.prior`).

The objective is the data term of :class:`~polarbssrdf.inverse.biophysical.problem.DataTerm`
plus the prior energy of :class:`PriorTerms`: every fitted map (chromophores and nuisances) is
a Matérn field around its face mean, each face mean Gaussian around its hyperprior's mean.
:func:`gauss_newton` takes the gradient exactly (Dr.Jit reverse mode through the blur), the
Hessian as the per-texel Gauss-Newton blocks of the unblurred model plus the prior's exact
Hessian, solves each step by conjugate gradients preconditioned in the Fourier domain
(:func:`solve_step`), keeps values at a bound that the gradient pushes outward fixed for the
step (projected Newton; Bertsekas, SIAM J. Control Optim. 20, 1982) and damps by Nielsen's
rule.
"""

from __future__ import annotations

import drjit as dr
import numpy as np
from scipy.sparse.linalg import LinearOperator, cg

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.biophysical.model import jit_types
from polarbssrdf.inverse.biophysical.prior import (
    FourierPreconditioner,
    expected_prior_energy,
    updated_spread,
)

STEP_RTOL = 0.05
"""Relative residual at which the conjugate gradients of a Gauss-Newton step stop: an
inexact Newton step (Dembo, Eisenstat and Steihaug, SIAM J. Numer. Anal. 19, 1982) with a
constant forcing term. At 512^2 the residual stalls at 1-5% for a hundred iterations
after the first steps; solving to 1e-3 cost 1580 iterations in 10 steps (111 s) for the
same maps as 478 iterations (36 s; bench/RESULTS.md, 2026-12-02)."""

STEP_MAX_ITERATIONS = 40
"""A cap on a step's conjugate-gradient iterations (the damping still guards the step). Where
features free the prior (:func:`~polarbssrdf.inverse.biophysical.prior.feature_coupling`) the
Fourier preconditioner, which assumes the stationary field everywhere, leaves a relative
residual of 0.3-3.3 after 20 iterations and 0.07-2.8 after 100: on the freckled cheek of
test_freckles.py all but two steps ran into a cap of 100. A cap of 40 took its biophysical
frame from 71.8 s to 49.1 s with the same freckle figures (bench/RESULTS.md, 2026-12-08)."""

INITIAL_DAMPING = 1e-3
"""Levenberg-Marquardt damping of a fit's first step (relative to the diagonal)."""

BOUND_MARGIN = 1e-3
"""A value within this fraction of its bounds range of a bound counts as at the bound
(the Gauss-Newton step's active set)."""

ARC_FRACTIONS = (1.0, 0.5, 0.25)
"""Fractions of a Gauss-Newton step tried along the projected arc before the damping grows."""

LEVEL_STD_FRACTION = 0.1
"""A map whose face mean is estimated before the fit (``known_variance``) keeps its own
area-weighted mean within this fraction of that estimate's std (a quadratic penalty)."""


class PriorTerms:
    """The Matérn prior of the fitted maps and their face means, in NumPy.

    Parameters
    ----------
    names : list of str
        The fitted maps, in the order of the unknowns' columns.
    spatial : SpatialPrior or None
        The unit Matérn precision over the movable texels (None: no prior).
    std : (k,) float
        Each map's spread around its face mean.
    mean0, mean_variance : (k,) float
        The face means' hyperprior (variance 0: the mean is fixed at ``mean0``).
    start : (k,) float
        The face means' start (``mean0`` where fixed).
    adapt : (k,) bool
        Whose spread :meth:`update_spreads` re-estimates.
    known_variance : (k,) float, optional
        Variance of a face mean estimated before the fit (0: none). Such a mean is fixed at
        ``mean0`` and the map's own area-weighted mean held near it
        (:data:`LEVEL_STD_FRACTION`): without it, per-texel noise through the model's
        curvature moved the face means of the maps the bands tell poorly along the
        prior's nearly free constant mode (beta_m by +0.02, 2.7x the constant map's error,
        over two rounds on a forehead II face at 1% noise).
    coupling : ((n, k), (n_pairs, k)), optional
        Each texel's innovation weight and each neighbour pair's coupling, in [0, 1], for
        each map (:func:`~polarbssrdf.inverse.biophysical.prior.feature_coupling`,
        :meth:`~.prior.SpatialPrior.coupled_unit`, order 2); the posterior reads each
        texel's spread ``tau^2 / w`` and correlation length per map from them
        (:meth:`local_tau2`, :attr:`correlation`). None: the Gaussian field.
    gain : (bins, n), optional
        The capture's blur of the data over the prior's spectrum
        (:func:`~polarbssrdf.inverse.biophysical.prior.capture_gain`), for the posterior
        expectations.

    Attributes
    ----------
    units : list of (n, n) sparse
        Each map's unit precision (``Q = unit / tau^2``).
    correlation : float or (n, k)
        The correlation length (mm) the posterior formulas take at each texel for each map.
    """

    def __init__(self, names, spatial, std, mean0, mean_variance, start, adapt, known_variance=None,
                 coupling=None, gain=None):
        self.names = list(names)
        self.spatial = spatial
        self.std = np.asarray(std, np.float64).copy()
        self.mean0 = np.asarray(mean0, np.float64).copy()
        self.mean_variance = np.asarray(mean_variance, np.float64).copy()
        self.free = self.mean_variance > 0
        self.mu = np.where(self.free, np.asarray(start, np.float64), self.mean0)
        self.adapt = np.asarray(adapt, bool).copy()
        k = len(self.names)
        self.known_variance = np.zeros(k) if known_variance is None else np.asarray(known_variance, np.float64).copy()
        self.tau2 = (np.array([spatial.tau2(s) for s in self.std]) if spatial is not None
                     else np.full(k, np.inf))
        self.level_precision = np.zeros(k)
        self.coupling, self.gain, self.weights = coupling, gain, None
        if spatial is not None:
            if coupling is None:
                self.units, self.correlation = [spatial.unit] * k, spatial.correlation_mm
            else:
                self.weights, pairs = (np.asarray(c, np.float64) for c in coupling)
                self.units = [spatial.coupled_unit(pairs[:, i], self.weights[:, i]) for i in range(k)]
                self.correlation = spatial.correlation_mm * np.sqrt(spatial.texel_couplings(pairs))
            ones = np.ones(len(spatial.index))
            self.ones_response = np.stack([unit @ ones for unit in self.units], axis=-1)  # (n, k): Q 1 tau^2
            self.ones_energy = self.ones_response.sum(axis=0)  # (k,): 1^T Q 1 tau^2
            self.level_weights = spatial.area / spatial.area.sum()
            known = self.known_variance > 0
            self.level_precision[known] = 1.0 / (LEVEL_STD_FRACTION ** 2 * self.known_variance[known])

    def energy(self, X, mu):
        """``(value, gradient (n, k), gradient of mu (k,))`` at surface values ``X`` (n, k)."""
        if self.spatial is None:
            return 0.0, np.zeros_like(X), np.zeros_like(mu)
        deviation = X - mu[None, :]
        gradient = self.apply_unit(deviation) / self.tau2[None, :]
        value = 0.5 * float(np.sum(deviation * gradient))
        mean_gradient = -gradient.sum(axis=0)
        level = self.level_weights @ deviation  # (k,) the maps' mean deviation
        value += 0.5 * float(np.sum(self.level_precision * level ** 2))
        gradient = gradient + self.level_weights[:, None] * (self.level_precision * level)[None, :]
        free = self.free
        value += 0.5 * float(np.sum((mu[free] - self.mean0[free]) ** 2 / self.mean_variance[free]))
        mean_gradient[free] += (mu[free] - self.mean0[free]) / self.mean_variance[free]
        mean_gradient[~free] = 0.0
        return value, gradient, mean_gradient

    def local_tau2(self):
        """``tau^2`` (k,), or per texel ``tau^2 / w`` (n, k) where features free the prior."""
        return self.tau2 if self.weights is None else self.tau2[None, :] / self.weights

    def apply_unit(self, X):
        """(n, k) each map's unit precision times its column of ``X``."""
        if all(unit is self.units[0] for unit in self.units):  # one matrix for every map
            return self.units[0] @ X
        return np.stack([unit @ X[:, i] for i, unit in enumerate(self.units)], axis=-1)

    def unit_diagonal(self):
        """(n, k) the diagonals of the maps' unit precisions."""
        return np.stack([unit.diagonal() for unit in self.units], axis=-1)

    def shift_mean(self, name, offset):
        """Re-centre map ``name``: its face mean and hyperprior move by ``-offset`` (the caller
        moves the map's values and the model's centre by the same)."""
        i = self.names.index(name)
        self.mu[i] -= offset
        self.mean0[i] -= offset

    def update_spreads(self, maps, C, movable):
        """Re-estimate the spreads of the ``adapt`` maps from the posterior
        (:func:`~polarbssrdf.inverse.biophysical.prior.updated_spread`); returns the
        largest relative change."""
        if self.spatial is None:
            return 0.0
        spatial = self.spatial
        energy = expected_prior_energy(C, spatial.area, self.local_tau2(), self.correlation, spatial.order,
                                       self.gain)
        if self.weights is not None:  # the share of the weighted quadratic form
            energy = energy * self.weights
        change = 0.0
        for i, name in enumerate(self.names):
            if not self.adapt[i]:
                continue
            deviation = np.ravel(maps[name])[movable] - self.mu[i]
            tau2, std = updated_spread(deviation, self.units[i], energy[:, i], self.tau2[i], self.std[i])
            change = max(change, abs(np.log(std / self.std[i])))
            self.tau2[i], self.std[i] = tau2, std
        return change


def solve_step(blocks, prior, rhs_x, rhs_mu, damping, fixed=None, max_iterations=STEP_MAX_ITERATIONS,
               rtol=STEP_RTOL):
    """``(delta_x (n, k), delta_mu (k,), predicted)`` of the damped Gauss-Newton system, by CG.

    The system is ``H delta = rhs`` with ``H`` the per-texel data blocks
    (n, k, k) plus the prior's Hessian over the maps and their face means
    (:class:`PriorTerms`), plus ``damping`` times its diagonal
    (Levenberg-Marquardt); conjugate gradients preconditioned in the Fourier
    domain (:class:`~polarbssrdf.inverse.biophysical.prior.FourierPreconditioner`).
    Without a prior the blocks decouple and are solved directly. ``fixed``
    (n, k) bool marks values that do not move (their rows and columns are
    replaced by the identity, their step is 0). ``predicted`` is the decrease
    ``rhs . delta - delta . H delta / 2`` the undamped quadratic model promises.
    """

    n, k = rhs_x.shape
    eye = np.eye(k)
    keep = np.ones((n, k)) if fixed is None else (~np.asarray(fixed, bool)).astype(np.float64)
    rhs_x = rhs_x * keep
    if prior.spatial is None:
        diagonal = np.einsum("nii->ni", blocks)
        damped = blocks + damping * (diagonal[:, :, None] * eye + 1e-12 * eye)
        pinned = 1.0 - keep
        damped = damped * keep[:, :, None] * keep[:, None, :] + pinned[:, :, None] * eye
        x = np.linalg.solve(damped, rhs_x[:, :, None])[..., 0] * keep
        predicted = float(np.sum(rhs_x * x) - 0.5 * np.einsum("ni,nij,nj->", x, blocks, x))
        return x, np.zeros(k), predicted
    inverse_tau2 = 1.0 / prior.tau2
    q1 = prior.ones_response
    free = prior.free
    safe_variance = np.where(free, prior.mean_variance, 1.0)
    mean_diagonal = np.where(free, prior.ones_energy * inverse_tau2 + 1.0 / safe_variance, 1.0)
    prior_diagonal = prior.unit_diagonal() * inverse_tau2[None, :]
    diagonal = np.einsum("nii->ni", blocks) + prior_diagonal
    damped_blocks = blocks + damping * (diagonal[:, :, None] * eye + 1e-12 * eye)
    mean_damped = mean_diagonal * (1.0 + damping)
    spatial = prior.spatial
    fourier = FourierPreconditioner(spatial.shape, spatial.index, spatial.texel_area, prior.tau2,
                                    damped_blocks.mean(axis=0), spatial.correlation_mm, spatial.order)

    def apply(z):
        x, mu = z[:n * k].reshape(n, k), z[n * k:]
        pinned = x * (1.0 - keep)
        x = x * keep
        mu = np.where(free, mu, 0.0)
        y = (np.einsum("nij,nj->ni", damped_blocks, x) + prior.apply_unit(x) * inverse_tau2[None, :]
             - q1 * (mu * inverse_tau2)[None, :]
             + prior.level_weights[:, None] * (prior.level_precision * (prior.level_weights @ x))[None, :])
        y = y * keep + pinned
        y_mu = np.where(free, -np.sum(q1 * x, axis=0) * inverse_tau2 + mean_damped * mu, z[n * k:])
        return np.concatenate([y.ravel(), y_mu])

    def precondition(z):
        x, mu = z[:n * k].reshape(n, k), z[n * k:]
        return np.concatenate([(fourier(x * keep) * keep + x * (1.0 - keep)).ravel(), mu / mean_damped])

    size = n * k + k
    rhs = np.concatenate([rhs_x.ravel(), np.where(free, rhs_mu, 0.0)])
    operator = LinearOperator((size, size), matvec=apply, dtype=np.float64)
    solution, _ = cg(operator, rhs, x0=precondition(rhs), rtol=rtol, maxiter=max_iterations,
                     M=LinearOperator((size, size), matvec=precondition, dtype=np.float64))
    x, mu = solution[:n * k].reshape(n, k) * keep, np.where(free, solution[n * k:], 0.0)
    # the undamped quadratic model's decrease, r.d - d.H d / 2, with H d = A d - damping D d
    undamped = apply(np.concatenate([x.ravel(), mu])) - damping * np.concatenate(
        [(diagonal * x).ravel(), np.where(free, mean_diagonal * mu, 0.0)])
    solution = np.concatenate([x.ravel(), mu])
    predicted = float(rhs @ solution - 0.5 * solution @ undamped)
    return x, mu, predicted


def _evaluate(data, values, names, fixed):
    """The data term at NumPy maps with the fitted maps' gradients enabled: ``(loss, params, value)``;
    :func:`_gradient` then runs the reverse pass only if the point is kept."""
    Float, _, _ = jit_types()
    params = dict(fixed)
    for n in names:
        params[n] = to_jit(Float, values[n], np.float32)
        dr.enable_grad(params[n])
    value = data(params)
    return float(value[0]), params, value


def _gradient(evaluated, names):
    """(n_texels, len(names)) gradient of an :func:`_evaluate` data term, through the blur."""
    _, params, value = evaluated
    dr.backward(value)
    return np.stack([np.array(dr.grad(params[n]), dtype=np.float64) for n in names], axis=-1)


def gauss_newton(data, prior, maps, fixed_maps, bounds, movable, iterations, tolerance, progress=None,
                 damping=INITIAL_DAMPING):
    """Minimize data term + prior over the maps ``prior.names`` and their free face means.

    Parameters
    ----------
    data : DataTerm
    prior : PriorTerms
        Its ``mu`` is updated in place.
    maps : dict
        ``name -> (T, T)`` values of every map the data term reads (fitted and fixed).
    fixed_maps : list of str
        Maps the data term reads but the fit does not move.
    bounds : dict
        ``name -> (low, high)`` of each fitted map.
    movable : (T*T,) bool
        The unknowns' texels (the spatial prior's, in its order).
    iterations, tolerance :
        Steps at most; a step that lowers the loss by less than ``tolerance`` of it ends the fit.
    damping : float
        The Levenberg-Marquardt damping of the first step, relative to the diagonal.

    A step solves ``(H + mu diag(H)) delta = -g`` (:func:`solve_step`); a step that does not
    lower the loss is tried at :data:`ARC_FRACTIONS` of its length along the projected arc
    ``clip(x + t delta)``, then with the damping grown; an accepted one updates the damping
    by Nielsen's rule (Madsen, Nielsen and Tingleff, Methods for non-linear least squares
    problems, 2004, sec. 3.2), starting from ``damping``. Returns ``(maps, first loss, last
    loss, accepted losses, damping)``: the last is the damping the last accepted step left
    (``damping`` if none was), where the next round starts (its objective moves only by the
    noise and spreads the round re-estimates); not the damping grown past every step when
    the round found no lower loss, which would leave the next round no step to try.
    """
    Float, _, _ = jit_types()
    names = prior.names
    fixed = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in fixed_maps}
    flat = {n: np.asarray(maps[n], np.float64).ravel().copy() for n in maps}

    def total(values, means):
        evaluated = _evaluate(data, values, names, fixed)
        X = np.stack([values[n][movable] for n in names], axis=-1)
        value, grad_x, grad_mu = prior.energy(X, means)
        return evaluated[0] + value, evaluated, grad_x, grad_mu

    mean = prior.mu.copy()
    loss, evaluated, prior_x, prior_mu = total(flat, mean)
    gradient = _gradient(evaluated, names)[movable] + prior_x
    first = loss
    losses = [loss]
    growth = 2.0
    settled = damping  # the damping of the last accepted step: where the next round starts
    lows = np.array([bounds[n][0] for n in names])
    highs = np.array([bounds[n][1] for n in names])
    margin = BOUND_MARGIN * (highs - lows)
    for step_index in range(int(iterations)):
        blocks, _ = data.precision(flat, names, movable)
        X = np.stack([flat[n][movable] for n in names], axis=-1)
        pinned = ((X <= lows + margin) & (gradient > 0)) | ((X >= highs - margin) & (gradient < 0))
        accepted = False
        while damping < 1e8:
            step, step_mu, predicted = solve_step(blocks, prior, -gradient, -prior_mu, damping, fixed=pinned)
            # along the projected arc: the values that still cross a bound make the full
            # step's clipped loss unreliable, a shorter one often is not
            for fraction in ARC_FRACTIONS:
                trial = {n: v.copy() for n, v in flat.items()}
                for k, n in enumerate(names):
                    trial[n][movable] = np.clip(X[:, k] + fraction * step[:, k], lows[k], highs[k])
                trial_mean = np.clip(mean + fraction * step_mu, lows, highs)
                trial_loss, trial_evaluated, trial_prior_x, trial_prior_mu = total(trial, trial_mean)
                if np.isfinite(trial_loss) and trial_loss < loss:
                    accepted = True
                    break
            if accepted:
                break
            damping *= growth
            growth *= 2.0
        if not accepted:
            break
        linear = float(-np.sum(gradient * step) - np.sum(prior_mu * step_mu))
        model = fraction * linear - fraction ** 2 * (linear - predicted)
        ratio = min((loss - trial_loss) / max(model, 1e-30), 1.0)
        damping = max(damping * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 1e-6)
        settled = damping
        growth = 2.0
        decrease = (loss - trial_loss) / max(abs(loss), 1e-30)
        flat, mean, loss = trial, trial_mean, trial_loss
        losses.append(loss)
        if progress:
            progress(f"step {step_index + 1}/{iterations}: loss {loss:.6g}")
        if decrease < tolerance:
            break
        gradient = _gradient(trial_evaluated, names)[movable] + trial_prior_x
        prior_mu = trial_prior_mu
    out = dict(maps)
    for n in names:
        out[n] = flat[n].reshape(np.shape(maps[n]))
    prior.mu = mean
    return out, first, loss, losses, settled
