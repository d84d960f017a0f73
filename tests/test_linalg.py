"""The batched inverse of symmetric positive-definite matrices (polarbssrdf._linalg)."""

import numpy as np
import pytest

from polarbssrdf._linalg import batched_spd_inverse


def _spd(rng, n, k, spread_decades):
    factor = rng.normal(size=(n, k, k))
    matrices = factor @ np.swapaxes(factor, 1, 2) + 0.05 * np.eye(k)
    scale = np.logspace(-spread_decades / 2, spread_decades / 2, k)
    return matrices * scale[:, None] * scale[None, :]


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6])
def test_the_inverse_times_the_matrix_is_the_identity(k):
    """Within 1e-9 in the matrices' own scaling: ``D A^-1 D`` of ``D^-1 A D^-1`` (a
    texel's precision spans decades between a chromophore and a nuisance)."""
    rng = np.random.default_rng(3 + k)
    scale = np.logspace(-4, 4, k)
    balanced = _spd(rng, 500, k, 0.0)
    matrices = balanced * scale[:, None] * scale[None, :]
    inverse = batched_spd_inverse(matrices)
    rebalanced = inverse * scale[:, None] * scale[None, :]
    assert np.allclose(rebalanced @ balanced, np.eye(k), atol=1e-9)
    assert np.allclose(inverse, np.swapaxes(inverse, -1, -2), rtol=0, atol=0)


def test_it_equals_numpys_inverse_over_any_batch_shape():
    rng = np.random.default_rng(11)
    matrices = _spd(rng, 24, 4, 6.0).reshape(2, 3, 4, 4, 4)
    reference = np.linalg.inv(matrices)
    inverse = batched_spd_inverse(matrices)
    assert inverse.shape == matrices.shape
    relative = np.abs(inverse - reference) / np.abs(reference).max(axis=(-2, -1), keepdims=True)
    assert relative.max() < 1e-9


def test_a_matrix_that_is_not_positive_definite_gets_numpys_inverse():
    """An indefinite (but invertible) matrix among positive-definite ones: its Cholesky fails,
    so it takes NumPy's general inverse and the others keep theirs."""
    rng = np.random.default_rng(5)
    matrices = _spd(rng, 6, 3, 0.0)
    matrices[2] = np.diag([1.0, -2.0, 3.0])
    inverse = batched_spd_inverse(matrices)
    assert np.allclose(inverse[2], np.diag([1.0, -0.5, 1.0 / 3.0]))
    assert np.allclose(inverse @ matrices, np.eye(3), atol=1e-10)


def test_a_matrix_that_is_not_square_is_refused():
    with pytest.raises(ValueError, match=r"\(\.\.\., k, k\)"):
        batched_spd_inverse(np.ones((5, 3, 4)))
