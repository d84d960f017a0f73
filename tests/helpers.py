"""Helpers shared by the tests (on the pytest path through ``pythonpath``)."""

import numpy as np


def mueller_to_numpy(M):
    """4x4 Dr.Jit/Mitsuba matrix -> float64 array (4, 4, N) for mono entries,
    (4, 4, N, C) for spectral ones; constant entries are broadcast."""
    entries = [[np.array(M[i, j], dtype=np.float64) for j in range(4)] for i in range(4)]
    entries = [[e.T if e.ndim == 2 else np.atleast_1d(e) for e in row] for row in entries]
    shape = np.broadcast_shapes(*[e.shape for row in entries for e in row])
    return np.array([[np.broadcast_to(e, shape) for e in row] for row in entries])
