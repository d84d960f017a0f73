"""``polarbssrdf reconstruct`` and ``polarbssrdf evaluate``: the command line of the acquisition.

Argument parsing only: ``reconstruct CAPTURE OUTDIR`` calls
:func:`polarbssrdf.inverse.pipeline.reconstruct` (the stages, the result
directory's life cycle, the timings) and prints its summary; ``evaluate
OUTDIR`` calls :func:`polarbssrdf.inverse.pipeline.evaluate` and prints the
scores as JSON. See ``docs/reconstruct.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from polarbssrdf.inverse.config import DEFAULT_TEXTURE
from polarbssrdf.inverse.evaluation.rerender import DEFAULT_SPP
from polarbssrdf.inverse.polarimetric.config import DEFAULT_DYNAMIC_ITERATIONS, StaticConfig
from polarbssrdf.inverse.results.directory import STAGES
from polarbssrdf.variants import DEFAULT_VARIANT

DOC = "docs/reconstruct.md"


def integer_at_least(minimum: int):
    """argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, "
                                             f"got '{text}'") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
        return value

    return parse


def _name_list(text: str) -> list[str]:
    """``"a, b,a"`` -> ``["a", "b"]`` (order kept, duplicates and empty items dropped)."""
    names = []
    for item in text.split(","):
        item = item.strip()
        if item and item not in names:
            names.append(item)
    return names


def register(subparsers) -> None:
    """Add ``reconstruct`` and ``evaluate`` to the ``polarbssrdf`` argument parser."""
    parser = subparsers.add_parser(
        "reconstruct", help="recover per-texel maps (eta, roughness, albedos, displacement) "
                            "from a capture",
        description="Run the acquisition stages on a capture (real or synthetic) and write a "
                    "result directory: result.json, <stage>/maps_f####.exr (float32, the "
                    "channels and texture convention of a capture's truth maps), previews and "
                    f"metrics.json. See {DOC}.")
    parser.add_argument("capture", type=Path, metavar="CAPTURE",
                        help="capture directory (capture.json, images/, mesh); never modified")
    parser.add_argument("outdir", type=Path, metavar="OUTDIR",
                        help="result directory: new or empty, or an earlier run with --resume "
                             "(continue) or --overwrite (start over); not inside CAPTURE")
    parser.add_argument("--stages", default=",".join(STAGES), metavar="S[,S...]",
                        help=f"stages to run, comma-separated; known: {', '.join(STAGES)} "
                             "(default: %(default)s)")
    parser.add_argument("--texture", type=integer_at_least(8), default=None, metavar="T",
                        help="map size T x T in texels (default: the capture's truth texture "
                             f"size if it has ground truth, else {DEFAULT_TEXTURE})")
    parser.add_argument("--iterations", type=integer_at_least(0), default=None, metavar="N",
                        help="epochs of the static stage and of each dynamic frame (default: "
                             f"the config's, {StaticConfig.iterations} and {DEFAULT_DYNAMIC_ITERATIONS} unless --config "
                             "sets them)")
    parser.add_argument("--config", type=Path, default=None, metavar="FILE.json",
                        help=f"JSON object overriding any StaticConfig key ({DOC}; default: "
                             "the paper's settings); --iterations wins over its 'iterations'")
    parser.add_argument("--holdout", default="", metavar="CAM[,CAM...]",
                        help="cameras left out of the fit, for validation re-renders with "
                             "'polarbssrdf evaluate' (default: none)")
    parser.add_argument("--frame", type=integer_at_least(0), default=0, metavar="F",
                        help="frame index of the capture to fit (default: %(default)s)")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--resume", action="store_true",
                          help="continue the run in OUTDIR from its last checkpoint; needs the "
                               "same capture and settings (differences are named)")
    existing.add_argument("--overwrite", action="store_true",
                          help="start over in OUTDIR, removing the earlier run's outputs and "
                               "its observation cache")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help="Mitsuba variant, a JIT autodiff polarized one "
                             "(default: %(default)s)")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=integer_at_least(1), default=None, metavar="N",
                         help="run the dynamic and biophysical stages' frames on a local Dask "
                              "cluster of N single-threaded worker processes (default: one "
                              "after another in this process)")
    cluster.add_argument("--scheduler", default=None, metavar="ADDRESS",
                         help="run those frames on an existing Dask cluster, e.g. "
                              "tcp://10.0.0.1:8786 (its workers must see CAPTURE and OUTDIR at "
                              "the same paths)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.set_defaults(run=run_reconstruct)

    parser = subparsers.add_parser(
        "evaluate", help="score a result's maps against a synthetic capture's ground truth",
        description="Compare the maps of a result directory with the ground truth of a capture "
                    "(MAE, relative errors, normal angles, each next to a constant-map "
                    "baseline) and re-render the cameras the run held out; print JSON. "
                    f"See {DOC}.")
    parser.add_argument("outdir", type=Path, metavar="OUTDIR",
                        help="result directory written by 'polarbssrdf reconstruct'")
    parser.add_argument("--truth", type=Path, default=None, metavar="CAPTURE",
                        help="capture with ground truth (default: the capture recorded in "
                             "OUTDIR/result.json)")
    parser.add_argument("--frame", type=integer_at_least(0), default=0, metavar="F",
                        help="frame to score (default: %(default)s)")
    parser.add_argument("--stage", default="static", choices=STAGES,
                        help="stage whose maps are scored (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=None, metavar="FILE.json",
                        help="also write the JSON to this file (atomically; default: print only)")
    parser.add_argument("--spp", type=integer_at_least(1), default=DEFAULT_SPP,
                        help="samples per pixel of the held-out re-renders "
                             "(default: %(default)s)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help="Mitsuba variant of the re-renders, a mono polarized one "
                             "(default: %(default)s)")
    parser.add_argument("--force", action="store_true",
                        help="score against a capture that is not the result's (result.json "
                             "records which capture the maps were fitted on; another one is "
                             "refused with what differs)")
    parser.set_defaults(run=run_evaluate)


# --------------------------------------------------------------------------- handlers
# The pipeline imports every stage (Mitsuba scenes, zarr, SciPy's sparse solvers, Dask):
# the handlers import it when they run, so that 'polarbssrdf --help' starts fast.


def run_reconstruct(args) -> int:
    """Execute ``polarbssrdf reconstruct``; returns the exit status (1 if a frame failed)."""
    from polarbssrdf.inverse.pipeline import reconstruct

    result = reconstruct(args.capture, args.outdir, stages=_name_list(args.stages),
                         config=args.config, holdout=_name_list(args.holdout),
                         texture=args.texture, frame=args.frame, iterations=args.iterations,
                         workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                         overwrite=args.overwrite, progress=not args.quiet,
                         variant=args.variant)
    print(result.summary())
    if result.failed:
        for frame, reason in sorted(result.failed.items()):
            print(f"polarbssrdf reconstruct: frame {frame} failed: {reason}", file=sys.stderr)
        print(f"polarbssrdf reconstruct: {len(result.failed)} frame(s) failed; result.json lists "
              "the others; fix the input and rerun with --resume to do only the missing ones",
              file=sys.stderr)
        return 1
    return 0


def run_evaluate(args) -> int:
    """Execute ``polarbssrdf evaluate``; prints the JSON, returns the exit status 0."""
    from polarbssrdf.inverse.pipeline import evaluate

    report = evaluate(args.outdir, args.truth, frame=args.frame, stage=args.stage, spp=args.spp,
                      variant=args.variant, force=args.force, out=args.out)
    sys.stdout.write(json.dumps(report, indent=2) + "\n")
    return 0
