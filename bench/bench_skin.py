"""Skin optics throughput (issue 3).

1. Totals (eq. 47) for 1,000,000 texels x 6 bands: biophysical parameters ->
   band-effective layer coefficients -> closed-form multipole totals ->
   two-layer combination (``reflectance_from_basis``), float64 and float32.
   Target: < 1 s.
2. Inversion throughput (eq. 41) for per-band inputs (``invert_bands``,
   6 default bands), noise-free and with 1% multiplicative noise, in texels
   per second (lookup table already built and cached, as in a per-frame run;
   the one-off table build is printed separately). Target: >= 100,000/s.

Each figure is the median of ``--repeat`` runs. Run
``python bench/bench_skin.py`` from the repository root.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from polarbssrdf.skin.inversion import invert_bands
from polarbssrdf.skin.model import band_chromophore_basis, band_reflectance, reflectance_from_basis
from polarbssrdf.skin.parameters import table2_ranges
from polarbssrdf.spectral import default_bands

NAMES = ("C_m", "beta_m", "C_h_out", "C_h_in")


def timed(fn, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--texels", type=int, default=1_000_000, help="texels for the totals (default 1e6)")
    parser.add_argument("--inversion-texels", type=int, default=200_000, help="texels for the inversion")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    ranges = table2_ranges()
    bands = default_bands()
    basis = band_chromophore_basis(bands)

    params = [rng.uniform(*ranges[n], args.texels) for n in NAMES]
    reflectance_from_basis(basis, *(p[:1000] for p in params))  # warm-up
    for dtype in (np.float64, np.float32):
        seconds, out = timed(lambda: reflectance_from_basis(basis, *params, dtype=dtype), args.repeat)
        print(f"totals eq. 47: {args.texels:,} texels x {out.shape[-1]} bands, {np.dtype(dtype).name}: "
              f"{seconds:.3f} s ({args.texels / seconds / 1e6:.2f} M texels/s)  [target < 1 s]")

    n = args.inversion_texels
    truth = [rng.uniform(*ranges[name], n) for name in NAMES]
    clean = band_reflectance(*truth, bands)
    start = time.perf_counter()
    invert_bands(clean[:10], bands)  # builds and caches the lookup table
    print(f"inversion lookup table build (once per band set): {time.perf_counter() - start:.2f} s")
    span = np.array([ranges[name][1] - ranges[name][0] for name in NAMES])
    for label, noise in (("noise-free", 0.0), ("1% noise", 0.01)):
        observed = clean * (1.0 + noise * rng.standard_normal(clean.shape))
        seconds, result = timed(lambda: invert_bands(observed, bands), args.repeat)
        errors = np.stack([np.abs(getattr(result, name) - t) for name, t in zip(NAMES, truth)], -1) / span
        median = ", ".join(f"{name} {e:.3f}" for name, e in zip(NAMES, np.median(errors, axis=0)))
        print(f"inversion, {len(bands)} bands, {label}: {n:,} texels in {seconds:.2f} s = "
              f"{n / seconds:,.0f} texels/s  [target >= 100,000]; median |error|/Table-2 range: {median}; "
              f"median RMSE {np.median(result.rmse):.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
