"""How much of a face's relief the static stage recovers: issue 33's geometry figures.

Synthesizes (cached under --workdir) a face with synth's default relief (smooth field,
forehead lines, crow's feet, nasolabial folds, pores; docs/synth.md) at a seed the
defaults were not tuned on: 8 views of the demo's rig, raw noisy mosaics, 384 px, a
512^2 texture. Reconstructs its static frame, scores it with ``polarbssrdf evaluate``
and prints, beside the issue's targets:

* the mean normal error against the base mesh's (target at most 0.3x);
* the regression slope of the recovered displacement on the truth's (target 0.8-1.2), and
  its 2-std coverage (target 0.90-0.98);
* the transfer curve: gain and correlation per octave of spatial scale;
* the same inside the wrinkles alone (texels where the relief carves > 0.03 mm).

Usage: ``python bench/geometry_recovery.py [--workdir DIR] [--texture 512] [--seed 7]
[--face-level-start]``; the last fits the glossy maps' face levels before the epochs
(``face_level_evaluations`` 12, off by default: docs/reconstruct.md, "Face levels first").
About 8 minutes on 2 cores at 512^2.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

NORMAL_RATIO_TARGET = 0.3
SLOPE_TARGET = (0.8, 1.2)


def polarbssrdf(*args):
    from polarbssrdf.cli import main

    code = main([str(a) for a in args])
    if code:
        raise SystemExit(f"polarbssrdf {' '.join(map(str, args))} exited {code}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", default="bench_out/geometry")
    parser.add_argument("--texture", type=int, default=512)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--face-level-start", action="store_true",
                        help="start the epochs at the glossy maps' fitted face levels")
    args = parser.parse_args()
    work = Path(args.workdir)
    capture = work / f"face_{args.texture}_seed{args.seed}"
    tag = f"{args.texture}_seed{args.seed}" + ("_face_start" if args.face_level_start else "")
    result = work / f"result_{tag}"
    timings = {}
    if not (capture / "capture.json").exists():
        started = time.perf_counter()
        polarbssrdf("synth", capture, "--object", "face", "--views", 8, "--resolution", 384,
                    "--texture", args.texture, "--spp", 8, "--raw", "--seed", args.seed, "--quiet",
                    "--overwrite")
        timings["synth_s"] = time.perf_counter() - started
    started = time.perf_counter()
    settings = []
    if args.face_level_start:
        config = work / "face_level_start.json"
        config.write_text(json.dumps({"face_level_evaluations": 12}))
        settings = ["--config", config]
    polarbssrdf("reconstruct", capture, result, "--stages", "static", "--overwrite", "--quiet",
                *settings)
    timings["static_s"] = time.perf_counter() - started
    evaluation = work / f"evaluation_{tag}.json"
    evaluation.unlink(missing_ok=True)
    polarbssrdf("evaluate", result, "--out", evaluation)
    scores = json.loads(evaluation.read_text())["maps"]

    # deferred: only the wrinkles' score needs the maps themselves
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.exr import read_exr

    truth = load_capture(capture, check_images=False).truth_maps(0)
    maps, _ = read_exr(result / "static" / "maps_f0000.exr")
    scored = np.asarray(maps["confidence"]) > 0
    height, true_height = (np.asarray(m["displacement"], np.float64) for m in (maps, truth))
    slope = float(np.polyfit(true_height[scored], height[scored], 1)[0])
    normal = scores["normal"]
    ratio = normal["mean_deg"] / normal["base_mesh_mean_deg"]
    print(f"face {args.texture}^2, seed {args.seed}"
          f"{', face-level start' if args.face_level_start else ''}: {json.dumps(timings)}")
    print(f"  normal error {normal['mean_deg']:.3f} deg mean (base mesh {normal['base_mesh_mean_deg']:.3f}): "
          f"{ratio:.2f}x (target <= {NORMAL_RATIO_TARGET})")
    print(f"  displacement slope on the truth {slope:.3f} (target {SLOPE_TARGET[0]}-{SLOPE_TARGET[1]}); "
          f"MAE {scores['displacement']['mae']:.4f} mm (constant map {scores['displacement']['constant_mae']:.4f}), "
          f"2-std coverage {scores['displacement'].get('coverage', float('nan')):.3f} (issue 33: 0.90-0.98)")
    for band in scores["displacement"]["transfer"]:
        low, high = band["sigma_mm"]
        print(f"  scale {low:5.2f}-{high:5.2f} mm: gain {band['gain']:.3f}, correlation "
              f"{band['correlation']:.3f}, truth rms {band['truth_rms_mm']:.4f} mm")
    # the wrinkles' footprint, recomputed from synth's default face wrinkles
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.synth.microgeometry import face_wrinkle_paths, wrinkle_depth
    from polarbssrdf.variants import ensure_jit_variant

    ensure_jit_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), args.texture)
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    carved = sum(wrinkle_depth(atlas, w, texel) for w in face_wrinkle_paths(face_mesh(0)))
    inside = scored & (carved > 0.03)
    if inside.any():
        slope_in = float(np.polyfit(true_height[inside], height[inside], 1)[0])
        print(f"  inside the wrinkles ({int(inside.sum())} texels): slope {slope_in:.3f}, "
              f"MAE {np.mean(np.abs(height - true_height)[inside]):.4f} mm")


if __name__ == "__main__":
    main()
