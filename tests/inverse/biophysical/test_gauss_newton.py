"""The biophysical fit's solver (:func:`~polarbssrdf.inverse.biophysical.gauss_newton.gauss_newton`)
on a problem whose answer is known: a quadratic data term over one map, no spatial prior."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi

N = 64
BOUNDS = {"m": (0.0, 1.0)}


class _Quadratic:
    """``0.5 sum_i (m_i - target_i)^2`` as the fit's data terms are called: Dr.Jit maps in,
    a one-element Dr.Jit loss out, and its exact Gauss-Newton blocks (the identity)."""

    def __init__(self, target):
        self.target = np.asarray(target, np.float64)

    def __call__(self, params):
        from polarbssrdf._arrays import to_jit
        from polarbssrdf.inverse.biophysical.model import jit_types

        Float, _, _ = jit_types()
        residual = params["m"] - to_jit(Float, self.target, np.float32)
        return dr.sum(0.5 * dr.square(residual))

    def precision(self, maps, names, movable):
        return np.ones((int(np.sum(movable)), 1, 1)), None


def _solve(start, target, damping, iterations=12):
    from polarbssrdf.inverse.biophysical.gauss_newton import PriorTerms, gauss_newton

    mi.set_variant("llvm_ad_mono_polarized")
    prior = PriorTerms(["m"], None, std=[1.0], mean0=[0.5], mean_variance=[0.0], start=[0.5],
                       adapt=[False])
    maps = {"m": np.asarray(start, np.float64).copy()}
    return gauss_newton(_Quadratic(target), prior, maps, [], BOUNDS, np.ones(N, bool), iterations, 1e-6,
                        damping=damping)


def test_a_round_that_finds_no_lower_loss_hands_the_next_its_damping_not_the_grown_one():
    """At the minimum no step lowers the loss: the damping grows past every step and the round
    ends. The damping it returns, where the next round starts, is the one it started from;
    the grown one (1e8 and more) left the next round no step to try, so a round whose noise
    or spreads had moved the minimum stopped where it was."""
    target = np.linspace(0.2, 0.8, N)
    maps, first, last, losses, damping = _solve(target, target, 1e-3)
    assert last == first and len(losses) == 1
    assert damping == 1e-3
    moved = target + 0.1
    maps, first, last, _, _ = _solve(target, moved, damping)
    assert last < 1e-3 * first
    np.testing.assert_allclose(maps["m"], moved, atol=1e-3)


def test_an_accepted_step_hands_on_the_damping_nielsens_rule_left():
    """Gauss-Newton on a quadratic is exact: one step (damped by 1e-3) lands on the target,
    the gain ratio is about 1 and Nielsen's rule divides the damping by 3."""
    target = np.linspace(0.2, 0.8, N)
    _, first, last, _, damping = _solve(np.full(N, 0.5), target, 1e-3, iterations=1)
    assert last < 1e-5 * first
    assert damping == pytest.approx(1e-3 / 3.0, rel=1e-12)
