"""What the bands can tell (``polarbssrdf skin bands`` / ``design-bands``): timings, the default
bands against the best designed sets, and the Cramér-Rao bound against the spread of a per-texel
least-squares fit as the noise grows (where the bound stops being reachable).

    .venv/bin/python bench/bench_bands.py
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import least_squares

from polarbssrdf.render.subsurface import subsurface_exit_fraction
from polarbssrdf.skin import band_information as info
from polarbssrdf.skin.model import band_chromophore_basis, reflectance_from_basis
from polarbssrdf.skin.parameters import TABLE2
from polarbssrdf.spectral import bandpass_bands, shipped_default_bands

ROW = ("forehead", "IV")
DRAWS = 200


def per_texel_spread(bands, sigma, rng):
    """Spread (std) and bias of a bounded least-squares fit of DRAWS noisy draws of ROW."""
    skin = TABLE2[ROW]
    truth = np.array([skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in])
    basis = band_chromophore_basis(bands)
    clean = reflectance_from_basis(basis, *truth, eta=skin.eta, workers=1)
    estimates = []
    for _ in range(DRAWS):
        observed = clean * (1.0 + sigma * rng.standard_normal(clean.shape))
        fit = least_squares(
            lambda p: (reflectance_from_basis(basis, *p, eta=skin.eta, workers=1) - observed) / (sigma * observed),
            truth, bounds=([0.001, 0.0, 0.0, 0.001], [0.5, 1.0, 0.3, 0.3]), x_scale=np.full(4, 0.01),
            diff_step=1e-6)
        estimates.append(fit.x)
    estimates = np.array(estimates)
    return estimates.std(axis=0), estimates.mean(axis=0) - truth


def main():
    bands = shipped_default_bands()
    noise = info.white_noise(0.01)
    start = time.perf_counter()
    bounds = info.band_bounds(bands, noise, exit_fraction=subsurface_exit_fraction)
    pins = info.band_pins(bounds, exit_fraction=subsurface_exit_fraction)
    print(f"report of the 6 default bands at 8 rows (with pins): {time.perf_counter() - start:.2f} s")
    print(info.format_report(bounds, pins))

    candidates = bandpass_bands(np.arange(410, 691, 10), 10)
    for search in ("greedy", "exhaustive"):
        start = time.perf_counter()
        design = info.design_bands(candidates, 6, noise, search=search, exit_fraction=subsurface_exit_fraction)
        names = sorted(b.name for b in design.bands)
        print(f"design 6 of 29 10-nm bandpass filters, {search}: {names}, criterion "
              f"{100 * design.value:.1f}% ({design.evaluated} sets, {time.perf_counter() - start:.1f} s)")
    for k in (4, 5, 8):
        design = info.design_bands(candidates, k, noise, exit_fraction=subsurface_exit_fraction)
        print(f"  k={k} greedy: {sorted(b.name for b in design.bands)}, {100 * design.value:.1f}%")
    start = time.perf_counter()
    period, phase, value, grid = info.design_comb_pair(np.arange(40, 121, 5), np.arange(400, 516, 5), noise,
                                                       exit_fraction=subsurface_exit_fraction)
    print(f"comb pair: best period {period:g} nm, phase {phase:g} nm: {100 * value:.1f}% "
          f"(default 70/440: {100 * bounds.criterion('mean'):.1f}%; {len(grid)} pairs, "
          f"{time.perf_counter() - start:.1f} s)")

    n = len(bands)
    measured = info.NoiseModel("covariance", matrix=0.0135 ** 2 * np.eye(n) + 0.031 ** 2 * np.ones((n, n)))
    white = info.band_bounds(bands, info.white_noise(np.sqrt(0.0135 ** 2 + 0.031 ** 2)))
    common = info.band_bounds(bands, measured)
    print("issue 20's static albedo error (3.1% common + 1.35% per band, 3.4% rms) vs white 3.4%, "
          "mean over rows, % of range:")
    for j, name in enumerate(info.PARAMETERS):
        print(f"  {name}: correlated {100 * common.fraction_of_range[:, j].mean():.1f}%, "
              f"white {100 * white.fraction_of_range[:, j].mean():.1f}%")

    rng = np.random.default_rng(1)
    print(f"bound vs per-texel fit ({ROW[0]} {ROW[1]}, default bands, {DRAWS} draws, bounded "
          "least squares), spread / bound and bias / bound:")
    for sigma in (0.0005, 0.001, 0.003, 0.01):
        bound = info.band_bounds(bands, info.white_noise(sigma), [ROW]).std[0]
        start = time.perf_counter()
        spread, bias = per_texel_spread(bands, sigma, rng)
        cells = ", ".join(f"{name} {s / b:.2f} ({m / b:+.2f})" for name, s, m, b in
                          zip(info.PARAMETERS, spread, bias, bound))
        print(f"  noise {100 * sigma:g}%: {cells}  [{time.perf_counter() - start:.1f} s]")


if __name__ == "__main__":
    main()
