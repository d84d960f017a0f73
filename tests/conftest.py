"""Shared fixtures. Mitsuba's variant is process-global: tests set the one they need."""

import os

import drjit as dr
import numpy as np
import pytest
from threadpoolctl import threadpool_limits

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


SLOWEST_FILES = (
    "tests/inverse/biophysical/test_freckles.py",  # 218 s (one fit fewer since: about 185 s)
    "tests/inverse/biophysical/test_bio_calibration.py",  # 135 s
    "tests/test_demo.py",  # 119 s
    "tests/inverse/polarimetric/test_dynamic.py",  # 113 s
    "tests/inverse/biophysical/test_bio_stage.py",  # 88 s
    "tests/skin/test_skin_band_information.py",  # 51 s
    "tests/inverse/biophysical/test_biophysical.py",  # 46 s
    "tests/inverse/polarimetric/test_relief_std.py",  # 27 s alone on two cores (2026-12-07)
    "tests/inverse/biophysical/test_texel_noise.py",  # 32 s
    "tests/inverse/test_run_inputs.py",  # 30 s
)
"""The files that take longest, longest first, with their time in ``make test`` at 5dbb9ba
(2026-12-07, kernel cache cold; bench/RESULTS.md). ``make test`` hands whole files to its
workers in collection order (``--dist loadfile --no-loadscope-reorder``): starting the
longest first keeps one worker from finishing a long file alone at the end (longest
processing time first; Graham, SIAM J. Appl. Math. 17, 1969). Files not listed keep their
order after these."""


def pytest_collection_modifyitems(session, config, items):
    rank = {path: index for index, path in enumerate(SLOWEST_FILES)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: keeps the rest's order


def _cores_per_worker():
    """Each pytest-xdist worker's share of the cores, or None outside xdist (or with one worker)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers < 2:
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // workers)


DEFAULT_JIT_THREADS = dr.thread_count()


@pytest.fixture(scope="module", autouse=True)
def threads_per_worker(request):
    """Under pytest-xdist, Dr.Jit and BLAS on each worker's share of the cores, except in
    files marked ``all_cores``.

    Both start a thread per core in every process, and idle threads of both wait spinning:
    test_bio_stage and test_dynamic run side by side on two cores took 159 s with two
    Dr.Jit threads each and 115 s with one (2026-12-06); with Dr.Jit on one thread,
    test_bio_stage beside test_texel_noise and test_biophysical took 134 s with two BLAS
    threads each and 94 s with one (2026-12-07, bench/RESULTS.md). Neither library's
    numbers depend on the limit inside a test: Dr.Jit's never do, and what BLAS would
    split differently is computed inside :func:`polarbssrdf._threads.one_blas_thread`
    anyway. The exceptions: with one thread, Mitsuba 3.9 hangs reading or writing an EXR
    through ``mi.Bitmap`` (this package reads and writes them with OpenEXR; only
    tests/plugins/test_pbssrdf.py does through Mitsuba), and tests/inverse/test_frames.py
    shows that BLAS on two threads gives other last bits than on one. Commands a test starts
    get BLAS's share through the environment (Dr.Jit has no such variable)."""
    share = _cores_per_worker()
    if share is None or request.node.get_closest_marker("all_cores"):
        if dr.thread_count() != DEFAULT_JIT_THREADS:
            dr.set_thread_count(DEFAULT_JIT_THREADS)
        yield
        return
    if dr.thread_count() != share:
        dr.set_thread_count(share)
    with threadpool_limits(limits=share), pytest.MonkeyPatch.context() as patch:
        for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # the commands a test starts
            patch.setenv(variable, str(share))
        yield
