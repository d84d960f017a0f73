"""What the static stage's posterior costs (issue 33 item 6: within 1.3x of the stage without it).

Runs the static stage's fit (:func:`~polarbssrdf.inverse.polarimetric.fit.run_polarimetric_fit`)
on one capture in this process, timing its parts: the optimization (the stage as it was
before the posterior), the posterior std (:func:`~polarbssrdf.inverse.polarimetric.posterior.map_posterior_std`,
eight forward-mode passes) and the face-level step of the held maps
(:func:`~polarbssrdf.inverse.polarimetric.face_level.hold_at_face_level`). The observations
are built first (cached in the work directory) and not counted: both versions share them.
Prints the stage's time with and without the posterior and their ratio; the first run
compiles the kernels (a cold cache pays that once), so ``--repeat 2`` shows a warm one too.
Each repeat runs the stage twice: with the displacement's noise from the cameras'
disagreement (the stage's posterior, ``capture_blur_mm`` estimated as the static stage
does) and with the model's noise alone (``posterior.displacement_noise_inflation`` 1), so
the cost of the cameras' part is a ratio in one process.

Usage: ``python bench/bench_posterior.py CAPTURE [--texture 256] [--holdout cam04] [--repeat 2]``
(e.g. the demo's ``out/demo/capture``).
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path


def timed(function, record, key):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            record[key] = record.get(key, 0.0) + time.perf_counter() - started
    return wrapper


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture")
    parser.add_argument("--texture", type=int, default=256)
    parser.add_argument("--holdout", default="cam04")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--workdir", default="bench_out/posterior")
    args = parser.parse_args()

    # deferred: the renderer's modules take seconds to import, after the arguments are checked
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.observations.build import load_or_build_observations
    from polarbssrdf.inverse.polarimetric import fit, posterior
    from polarbssrdf.inverse.polarimetric.static import with_capture_blur
    from polarbssrdf.io import load_capture
    from polarbssrdf.variants import ensure_jit_variant

    ensure_jit_variant("llvm_ad_mono_polarized")
    capture = load_capture(args.capture, check_images=False)
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    holdout = tuple(args.holdout.split(",")) if args.holdout else ()
    store = load_or_build_observations(capture, 0, args.texture, work / f"f0000_{args.texture}.zarr",
                                       exclude_cameras=holdout, progress=False)
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), args.texture)
    config = with_capture_blur(static_config({}), capture, atlas, 0, holdout)
    runs = []
    cameras_noise = posterior.displacement_noise_inflation
    for run, noise in ((run, noise) for run in range(args.repeat) for noise in ("cameras", "model")):
        posterior.displacement_noise_inflation = (cameras_noise if noise == "cameras"
                                                  else lambda *arguments: 1.0)
        parts = {}
        originals = {name: getattr(fit, name) for name in ("optimize_maps", "map_posterior_std", "hold_at_face_level")}
        try:
            for name, function in originals.items():
                setattr(fit, name, timed(function, parts, name))
            started = time.perf_counter()
            result = fit.run_polarimetric_fit(store, atlas, config, progress=False)
            total = time.perf_counter() - started
        finally:
            for name, function in originals.items():
                setattr(fit, name, function)
            posterior.displacement_noise_inflation = cameras_noise
        posterior_s = parts.get("map_posterior_std", 0.0) + parts.get("hold_at_face_level", 0.0)
        without = total - posterior_s
        runs.append({"run": run + 1, "displacement_noise": noise, "total_s": round(total, 2), "optimize_s": round(parts["optimize_maps"], 2),
                     "posterior_std_s": round(parts.get("map_posterior_std", 0.0), 2),
                     "face_level_s": round(parts.get("hold_at_face_level", 0.0), 2),
                     "without_posterior_s": round(without, 2), "ratio": round(total / without, 3),
                     "held": sorted(result.held)})
        print(json.dumps(runs[-1]))


if __name__ == "__main__":
    main()
