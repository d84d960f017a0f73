"""A pytest plugin that counts the Dr.Jit kernels each test launches and compiles (on demand only).

Loaded by :mod:`bench_kernels` (``-p kernel_census`` with ``bench/`` on the
path), never by ``make test``. For every test (set-up, call and tear-down
together, so a module fixture is charged to the first test that uses it) it
records, from Dr.Jit's kernel history of this process:

* ``launches``: JIT kernels launched;
* ``distinct``: distinct kernel hashes among them;
* ``compiled``: kernels found neither in the in-memory nor in the on-disk
  cache, i.e. compiled by LLVM (``backend_ms`` is their compile time; Dr.Jit's
  ``cache_hit`` is true for both caches);
* ``from_disk``: kernels loaded from ``~/.drjit`` (``cache_hit`` and ``cache_disk``);

and, for the kernels of child processes too (CLI tests, Dask workers), the
growth of ``$HOME/.drjit`` in files (``new_files``). One JSON object per test
is appended to the file named by ``KERNEL_CENSUS_OUT``, with the hashes the
test compiled, so that two runs can be compared hash by hash.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import drjit as dr
import pytest

_CACHE = Path(os.environ.get("HOME", "~")).expanduser() / ".drjit"


def _cache_files():
    try:
        return len(os.listdir(_CACHE))
    except FileNotFoundError:
        return 0


def pytest_configure(config):
    dr.set_flag(dr.JitFlag.KernelHistory, True)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    if report.failed:
        item.census_outcome = "error" if report.when != "call" else "failed"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    dr.kernel_history_clear()
    files = _cache_files()
    start = time.perf_counter()
    yield
    seconds = time.perf_counter() - start
    history = dr.kernel_history([dr.KernelType.JIT])
    compiled = [h for h in history if not h["cache_hit"]]
    row = {"test": item.nodeid, "outcome": getattr(item, "census_outcome", "passed"),
           "seconds": round(seconds, 3), "launches": len(history),
           "distinct": len({h["hash"] for h in history}),
           "compiled": len(compiled),
           "from_disk": sum(1 for h in history if h["cache_hit"] and h["cache_disk"]),
           "backend_ms": round(sum(h["backend_time"] for h in compiled), 1),
           "new_files": _cache_files() - files,
           "compiled_hashes": sorted({h["hash"] for h in compiled})}
    out = os.environ.get("KERNEL_CENSUS_OUT")
    if out:
        with open(out, "a") as handle:
            handle.write(json.dumps(row) + "\n")
