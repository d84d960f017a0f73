"""BLAS on one thread where numbers must not depend on the machine's thread count.

A multithreaded OpenBLAS splits a reduction (a dot product, a matrix product's
inner sums) into per-thread partial sums, so the same call gives other last bits
on one thread than on two. Dask starts its workers with BLAS on one thread and
this process gives it every core. On some CPUs (OpenBLAS's Zen and Haswell
kernels, which ``OPENBLAS_CORETYPE`` selects) the difference is there, and two
computations amplify it: the empirical spectral quadrature's greedy node
selection (:mod:`polarbssrdf.skin.quadrature`), cached per process, and a
Gauss-Newton fit that stops at a tolerance. Together they put a biophysical
frame fitted in-process 3.5e-4 of C_h_out away from the same frame on a worker.
"""

from __future__ import annotations

import contextlib

from threadpoolctl import threadpool_limits


@contextlib.contextmanager
def one_blas_thread():
    """BLAS and OpenMP libraries on one thread inside the block (threadpoolctl), as in a Dask
    worker; also a decorator. It cost nothing measurable on the biophysical frames (6.9 s
    either way at 64^2): their linear algebra is vectors and small blocks."""
    with threadpool_limits(limits=1):
        yield
