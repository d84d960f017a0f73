"""What a run needs before it starts: the memory it will take, against the machine's.

A run's full-texture arrays (the texel atlas, the maps with their gradients
and optimizer state, the per-texel statistics, the filled maps, the
biophysical maps) grow with the texture size T as T^2, and so do the
observation build's (one view's texel-views at a time, and a strip of all
views' when they are merged). :func:`run_memory_bytes` estimates the peak
resident memory as a fixed part plus bytes per texel, for a number of bands
and views, with constants measured by ``bench/bench_memory.py``
(bench/RESULTS.md). :func:`check_memory` refuses a run whose estimate exceeds
the machine's physical memory before anything is allocated or written: a
``--texture 100000`` run raised NumPy's ``_ArrayMemoryError`` after
``result.json`` was written.
"""

from __future__ import annotations

import sys

from polarbssrdf.errors import CommandError

BASE_BYTES = 280 * 2**20
"""Resident memory before any texture-sized array (Python, Mitsuba, Dr.Jit, LLVM)."""

STAGE_COSTS = {
    "static": (0, 900, 40, 30),
    "dynamic": (0, 900, 40, 30),
    "bio": (160 * 2**20, 0, 2150, 0),
}
"""Per stage: ``(fixed bytes, bytes per texel, per texel and band, per texel and view)``,
fitted to ``bench/bench_memory.py`` (6 bands, 4 views; bench/RESULTS.md). The
polarimetric stages hold the atlas, the maps with gradients and optimizer state and
the statistics, ``rho_sss`` per band and the observation build's texel-views (about
1.26 KB per texel at 6 bands and 4 views); the biophysical stage's Gauss-Newton steps
hold per band the albedo, its blurred model and their derivatives (12.9 KB per texel at
6 bands, so far the most demanding stage)."""


def _stage_bytes(texture: int, bands: int, views: int, stage: str) -> int:
    fixed, texel, band, view = STAGE_COSTS[stage]
    return fixed + int(texture) ** 2 * (texel + band * int(bands) + view * int(views))


def run_memory_bytes(texture: int, bands: int, views: int, stages=("static",)) -> int:
    """Estimated peak resident memory (bytes) of a run of ``stages`` at ``texture`` x
    ``texture`` texels with ``bands`` bands and ``views`` images in the fitted frame: the
    base and the most demanding stage's part (the stages run one after another)."""
    return int(BASE_BYTES + max(_stage_bytes(texture, bands, views, stage)
                                for stage in (stages or ("static",))))


def largest_texture(memory_bytes: int, bands: int, views: int, stages=("static",)) -> int:
    """The largest T whose :func:`run_memory_bytes` fits in ``memory_bytes``."""
    low, high = 0, 1
    while run_memory_bytes(high, bands, views, stages) <= memory_bytes:
        low, high = high, 2 * high
    while high - low > 1:  # run_memory_bytes grows with T
        middle = (low + high) // 2
        low, high = (middle, high) if run_memory_bytes(middle, bands, views,
                                                       stages) <= memory_bytes else (low, middle)
    return low


def machine_memory() -> tuple[int, int]:
    """``(total, available)`` bytes of physical memory."""
    import psutil  # deferred: only a run that checks its size needs it

    memory = psutil.virtual_memory()
    return int(memory.total), int(memory.available)


def _gigabytes(value: int) -> str:
    return f"{value / 2**30:,.1f} GB" if value < 2**40 * 10 else f"{value / 2**40:,.0f} TB"


def check_memory(texture: int, bands: int, views: int, stages=("static",),
                 what: str = "the run") -> int:
    """Refuse (:class:`CommandError`) a run whose estimated memory exceeds the machine's;
    warn on stderr when it exceeds what is free now. Returns the estimate (bytes)."""
    needed = run_memory_bytes(texture, bands, views, stages)
    total, available = machine_memory()
    sizes = f"{texture} x {texture} texels, {bands} bands, {views} views"
    if needed > total:
        raise CommandError(f"{what} would need about {_gigabytes(needed)} of memory ({sizes}), "
                           f"more than this machine's {_gigabytes(total)}: use a smaller "
                           f"--texture (about {largest_texture(total, bands, views, stages):,} "
                           "at most here)")
    if needed > available:
        print(f"polarbssrdf: warning: {what} will need about {_gigabytes(needed)} of memory "
              f"({sizes}); {_gigabytes(available)} of {_gigabytes(total)} are free now",
              file=sys.stderr, flush=True)
    return needed
