"""What the batched Cholesky inverse saves the biophysical fit (``polarbssrdf._linalg``).

The biophysical posterior solves a k x k system per texel and per frequency of the
lattice spectrum (:func:`~polarbssrdf.inverse.biophysical.prior.held_map_error_covariance`,
:func:`~polarbssrdf.inverse.biophysical.prior.expected_prior_energy`): hundreds of batched
inverses per fit. This times, in one process, (1) one batched inverse of 4 x 4 matrices by
NumPy and by :func:`~polarbssrdf._linalg.batched_spd_inverse`, and (2) the whole fit of an
unseen face (:func:`~polarbssrdf.synth.unseen_faces.unseen_face`, 128^2, the face values
told, as ``tests/inverse/biophysical/test_bio_calibration.py`` fits it) with NumPy's inverse
put back and with the Cholesky one, in alternating order, and prints each map's largest
difference between the two fits.

Usage: ``python bench/bench_spd_inverse.py [--face 0] [--texture 128] [--repeat 2]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import mitsuba as mi

from polarbssrdf._linalg import batched_spd_inverse
from polarbssrdf.inverse.biophysical import prior
from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
from polarbssrdf.inverse.biophysical.fit import fit_biophysical
from polarbssrdf.synth.unseen_faces import unseen_face


def time_inverses(n, k, repeat=20):
    rng = np.random.default_rng(0)
    factor = rng.normal(size=(n, k, k))
    matrices = factor @ np.swapaxes(factor, 1, 2) + 0.1 * np.eye(k)
    out = {}
    for name, inverse in (("numpy.linalg.inv", np.linalg.inv), ("batched_spd_inverse", batched_spd_inverse)):
        started = time.perf_counter()
        for _ in range(repeat):
            inverse(matrices)
        out[name] = (time.perf_counter() - started) / repeat
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--face", type=int, default=0)
    parser.add_argument("--texture", type=int, default=128)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    mi.set_variant("llvm_ad_mono_polarized")

    times = time_inverses(12000, 4)
    print(f"12,000 4x4 inverses: numpy {times['numpy.linalg.inv'] * 1e3:.2f} ms, Cholesky "
          f"{times['batched_spd_inverse'] * 1e3:.2f} ms, ratio "
          f"{times['numpy.linalg.inv'] / times['batched_spd_inverse']:.2f}")

    atlas, _, bands, inputs = unseen_face(args.face, args.texture, 0.01, thickness_mm=0.25, gamma=0.75)
    config = BiophysicalConfig(oxygenation="held", thickness_mm=0.25, gamma=0.75,
                               nuisance_mean={"thickness_mm": [0.25, 0.0], "gamma": [0.75, 0.0]})
    fit_biophysical(inputs, bands, atlas, config)  # compiles the kernels: not timed
    seconds = {"numpy.linalg.inv": [], "batched_spd_inverse": []}
    maps = {}
    for _ in range(args.repeat):
        for name, inverse in (("numpy.linalg.inv", np.linalg.inv), ("batched_spd_inverse", batched_spd_inverse)):
            prior.batched_spd_inverse = inverse
            started = time.perf_counter()
            result = fit_biophysical(inputs, bands, atlas, config)
            seconds[name].append(time.perf_counter() - started)
            maps[name] = result
    prior.batched_spd_inverse = batched_spd_inverse
    for name, values in seconds.items():
        print(f"fit with {name}: " + ", ".join(f"{v:.2f} s" for v in values))
    ratio = np.median(seconds["numpy.linalg.inv"]) / np.median(seconds["batched_spd_inverse"])
    print(f"fit time ratio numpy / Cholesky (medians): {ratio:.3f}")
    for key in maps["numpy.linalg.inv"].maps:
        a = np.asarray(maps["numpy.linalg.inv"].maps[key], np.float64)
        b = np.asarray(maps["batched_spd_inverse"].maps[key], np.float64)
        sa = np.asarray(maps["numpy.linalg.inv"].std[key], np.float64) if key in maps["numpy.linalg.inv"].std else None
        sb = np.asarray(maps["batched_spd_inverse"].std[key], np.float64) if sa is not None else None
        line = f"  {key}: largest map difference {np.nanmax(np.abs(a - b)):.3g}"
        if sa is not None:
            line += f", std {np.nanmax(np.abs(sa - sb)):.3g} (median std {np.nanmedian(sa):.3g})"
        print(line)


if __name__ == "__main__":
    main()
