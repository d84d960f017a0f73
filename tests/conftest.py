"""Shared fixtures. Mitsuba's variant is process-global: tests set the one they need."""

import numpy as np
import pytest

import polarbssrdf  # noqa: F401  (configures libLLVM, registers plugins on variant change)
import mitsuba as mi  # noqa: F401  (imported after polarbssrdf on purpose)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def hemisphere(rng):
    """Function ``(n, min_cos=0) -> n x 3`` uniform unit vectors with ``z >= min_cos``."""

    def sample(n, min_cos=0.0):
        out = np.empty((0, 3))
        while len(out) < n:
            v = rng.normal(size=(2 * n, 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            v[:, 2] = np.abs(v[:, 2])
            out = np.concatenate([out, v[v[:, 2] >= min_cos]])
        return out[:n]

    return sample
