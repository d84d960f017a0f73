"""A frame's numbers do not depend on where it runs (polarbssrdf._threads, polarbssrdf.inverse.frames).

Dask starts its workers with BLAS on one thread; this process gives BLAS every core, and a
multithreaded OpenBLAS dot product sums per-thread partials in another order. The frame
functions therefore fit with BLAS on one thread wherever they run.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from polarbssrdf._threads import one_blas_thread

pytestmark = pytest.mark.all_cores  # BLAS on two threads where a test compares it with one

SIZE = 200_000
"""Long enough that OpenBLAS splits the dot product over its threads."""


def _vectors():
    rng = np.random.default_rng(1)
    return rng.standard_normal(SIZE), rng.standard_normal(SIZE)


def _worker_dot():
    """``x @ y`` in a fresh interpreter with the thread settings a Dask nanny gives its worker."""
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    code = ("import json, numpy as np; rng = np.random.default_rng(1); "
            f"x, y = rng.standard_normal({SIZE}), rng.standard_normal({SIZE}); print(json.dumps(float(x @ y)))")
    out = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def _blas_threads():
    return max(pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas")


def test_a_dot_product_inside_one_blas_thread_is_the_workers_to_the_bit():
    x, y = _vectors()
    with one_blas_thread():
        inside = float(x @ y)
        assert _blas_threads() == 1
    assert inside == _worker_dot()
    if _blas_threads() > 1:  # the block is what makes them equal: outside, the partial sums differ
        assert float(x @ y) != inside


class _Stop(Exception):
    pass


def _record_blas_threads(seen):
    def record(*args, **kwargs):
        seen.append(_blas_threads())
        raise _Stop

    return record


def test_the_biophysical_frame_fits_with_one_blas_thread(monkeypatch):
    from polarbssrdf.inverse.biophysical import stage

    seen = []
    monkeypatch.setattr(stage, "bio_config", _record_blas_threads(seen))
    with pytest.raises(_Stop):
        stage.write_frame(None, "unused", 1, "dynamic", 32, {})
    assert seen == [1]


def test_the_dynamic_frame_fits_with_one_blas_thread(monkeypatch):
    from polarbssrdf.inverse.polarimetric import dynamic

    seen = []
    monkeypatch.setattr(dynamic, "select_variant", _record_blas_threads(seen))
    with pytest.raises(_Stop):
        dynamic.fit_frame("unused", "unused", 1, 32, {})
    assert seen == [1]
