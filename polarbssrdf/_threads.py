"""BLAS on one thread where numbers must not depend on the machine's thread count.

A multithreaded OpenBLAS splits a reduction (a dot product, a matrix product's
inner sums) into per-thread partial sums, so the same call gives other last bits
on one thread than on two (a 200,000-element dot product did on every OpenBLAS
kernel tried). Dask starts its workers with BLAS on one thread and this process
gives it every core. Two computations amplify the last bits: the empirical
spectral quadrature's greedy node selection (:mod:`polarbssrdf.skin.quadrature`),
cached per process, and a Gauss-Newton fit that stops at a tolerance. With
OpenBLAS's Zen or Haswell kernels (an AMD EPYC's, or ``OPENBLAS_CORETYPE=Zen``)
they put a biophysical frame fitted in-process 3.5e-4 of C_h_out away from the
same frame on a worker, and CI failed on it.
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
