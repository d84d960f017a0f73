"""``polarbssrdf reconstruct`` and ``polarbssrdf evaluate``: the command line of the acquisition.

Argument parsing and what the commands print: ``reconstruct CAPTURE OUTDIR``
calls :func:`polarbssrdf.inverse.pipeline.reconstruct` (the stages, the result
directory's life cycle, the timings) and prints its summary, closed by the next
command that applies to this result (:func:`closing_line`); ``evaluate OUTDIR``
calls :func:`polarbssrdf.inverse.pipeline.evaluate` and prints the scores as
JSON, or, for a capture without ground truth, the held-out re-render errors
alone (:func:`evaluate_without_truth`). See ``docs/reconstruct.md``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

from polarbssrdf.errors import CommandError
from polarbssrdf.inverse.config import DEFAULT_TEXTURE
from polarbssrdf.inverse.evaluation.rerender import DEFAULT_SPP
from polarbssrdf.inverse.polarimetric.config import DEFAULT_DYNAMIC_ITERATIONS, StaticConfig
from polarbssrdf.inverse.results.directory import (
    STAGES,
    check_report_path,
    read_result,
    read_stage_maps,
)
from polarbssrdf.io import load_capture
from polarbssrdf.io.atomic import atomic_write_text
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
    parser.add_argument("--frame", type=integer_at_least(0), default=None, metavar="F",
                        help="the static frame: the static stage fits it, the dynamic stage "
                             "starts from its maps and fits every other frame (default: 0; "
                             "without 'static' in --stages, the earlier run's static frame)")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--resume", action="store_true",
                          help="continue the run in OUTDIR from its last checkpoint; needs the "
                               "same capture and settings (differences are named), except a "
                               "larger --iterations, which continues every fit to the new count")
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
        "evaluate", help="score a result's maps against a synthetic capture's ground truth, "
                         "and re-render the held-out cameras",
        description="Compare the maps of a result directory with the ground truth of a capture "
                    "(MAE, relative errors, normal angles, each next to a constant-map "
                    "baseline) and re-render the cameras the run held out; print JSON. For a "
                    "capture without ground truth (a real one) only the held-out re-render "
                    f"errors are printed. See {DOC}.")
    parser.add_argument("outdir", type=Path, metavar="OUTDIR",
                        help="result directory written by 'polarbssrdf reconstruct'")
    parser.add_argument("--truth", type=Path, default=None, metavar="CAPTURE",
                        help="capture with ground truth, or without it for the held-out "
                             "re-renders only (default: the capture recorded in "
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


def closing_line(outdir, frame, holdout, texture, capture) -> str:
    """The last line ``reconstruct`` prints: where the outputs are and the next command that
    applies to this result.

    ``capture`` (a loaded :class:`~polarbssrdf.io.capture.Capture`, manifests only) tells
    whether ``evaluate`` can score the maps: its truth must have the fitted ``frame`` and the
    run's ``texture`` size. Otherwise the line says why not and offers what does apply: the
    held-out re-renders (``evaluate`` without truth) when the run held cameras out, and the
    report. ``capture`` None (it could not be read again): the report only.
    """
    frame_option = f" --frame {frame}" if frame else ""
    evaluate = f"'polarbssrdf evaluate {outdir}{frame_option}'"
    report = f"'polarbssrdf report {outdir}'"
    where = f"  result.json, metrics.json and previews in {outdir}; "
    if capture is None:
        return where + f"see them with {report}"
    truth = capture.truth
    truth_frames = {int(r.frame) for r in truth.maps} if truth is not None else set()
    if truth is not None and int(truth.texture_size) == int(texture) and frame in truth_frames:
        return where + f"score it with {evaluate}, see it with {report}"
    if truth is None:
        why = "the capture has no ground truth"
    elif int(truth.texture_size) != int(texture):
        size = int(truth.texture_size)
        why = (f"the capture's truth is {size} x {size} texels, this run {texture} x {texture} "
               f"(a run with --texture {size} can be scored)")
    else:
        why = f"the capture's truth has no frame {frame}"
    if holdout:
        return (where + f"{why}: {evaluate} re-renders the held-out camera"
                f"{'s' if len(holdout) > 1 else ''} {', '.join(holdout)}, {report} shows the "
                "maps")
    return (where + f"{why} and no camera was held out (--holdout CAM keeps one for "
            f"validation): {report} shows the maps and re-rendering residuals")


def run_reconstruct(args) -> int:
    """Execute ``polarbssrdf reconstruct``; returns the exit status (1 if a frame failed)."""
    from polarbssrdf.inverse.pipeline import reconstruct

    # the comma-separated lists go as they are: reconstruct() splits them, as from Python
    result = reconstruct(args.capture, args.outdir, stages=args.stages,
                         config=args.config, holdout=args.holdout,
                         texture=args.texture, frame=args.frame, iterations=args.iterations,
                         workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                         overwrite=args.overwrite, progress=not args.quiet,
                         variant=args.variant)
    # only the fitted frame's files are checked: a later frame's missing image fails that
    # frame alone (reported below), not this line
    try:
        capture = load_capture(result.capture, check_images=False, frames=[result.frame])
    except (OSError, ValueError):  # e.g. a stage that reads no image, and one is gone since
        capture = None
    print(result.summary(closing_line(result.path, result.frame, result.holdout,
                                      result.texture, capture)))
    if result.failed:
        for frame, reason in sorted(result.failed.items()):
            print(f"polarbssrdf reconstruct: frame {frame} failed: {reason}", file=sys.stderr)
        print(f"polarbssrdf reconstruct: {len(result.failed)} frame(s) failed; result.json lists "
              "the others; fix the input and rerun with --resume to do only the missing ones",
              file=sys.stderr)
        return 1
    return 0


def evaluate_without_truth(outdir, capture, *, frame=0, stage="static", spp=DEFAULT_SPP,
                           variant=DEFAULT_VARIANT) -> dict:
    """What ``evaluate`` prints for a capture without ground truth: the held-out cameras
    re-rendered with the maps of ``stage``/``frame`` against the capture
    (:func:`polarbssrdf.inverse.evaluation.rerender.holdout_errors`), in the schema of a
    scored evaluation with ``maps`` null.

    Raises :class:`CommandError` when there is nothing to compare: the run held no camera
    out, or ``stage`` is ``bio`` (its maps are not rendered).
    """
    # deferred: the re-renderer imports Mitsuba's scenes (seconds); 'polarbssrdf --help' does
    # not need it
    from polarbssrdf.inverse.evaluation import rerender
    from polarbssrdf.inverse.evaluation.scores import EVALUATION_SCHEMA, EVALUATION_SCHEMA_VERSION

    outdir = Path(outdir)
    manifest = read_result(outdir)
    cameras = list(manifest.settings.get("holdout") or [])
    if stage == "bio":
        raise CommandError(f"capture '{capture.directory}' has no ground truth, and the 'bio' "
                           "maps are not re-rendered: without truth evaluate re-renders the "
                           "held-out cameras with --stage static or dynamic")
    if not cameras:
        raise CommandError(f"capture '{capture.directory}' has no ground truth and the run in "
                           f"'{outdir}' held no camera out: nothing to evaluate against "
                           "(reconstruct with --holdout CAM keeps one for validation; "
                           f"'polarbssrdf report {outdir}' shows re-rendering residuals of a "
                           "fitted view)")
    maps = read_stage_maps(outdir, stage, int(frame))
    return {
        "schema": EVALUATION_SCHEMA, "schema_version": EVALUATION_SCHEMA_VERSION,
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "result": str(outdir.resolve()), "capture": str(Path(capture.directory).resolve()),
        "stage": stage, "frame": int(frame), "texture_size": int(manifest.texture_size),
        "truth": None,
        "scored": "the capture has no ground truth: held-out views only",
        "maps": None,
        "holdout": rerender.holdout_errors(capture, maps, cameras, int(frame), spp=spp,
                                           variant=variant),
    }


def run_evaluate(args) -> int:
    """Execute ``polarbssrdf evaluate``; prints the JSON, returns the exit status 0."""
    from polarbssrdf.inverse.evaluation.scores import truth_capture
    from polarbssrdf.inverse.pipeline import evaluate, evaluate_inputs
    from polarbssrdf.variants import select_variant

    if read_result_or_none(args.outdir) is not None and \
            truth_capture(args.outdir, args.truth).truth is None:
        capture = evaluate_inputs(args.outdir, args.truth, args.variant, args.force)
        if args.out is not None:
            check_report_path(args.out, args.outdir, capture.directory)
        select_variant(args.variant)
        report = evaluate_without_truth(args.outdir, capture, frame=args.frame,
                                        stage=args.stage, spp=args.spp, variant=args.variant)
        if args.out is not None:
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(args.out, json.dumps(report, indent=2) + "\n", overwrite=True)
    else:
        report = evaluate(args.outdir, args.truth, frame=args.frame, stage=args.stage,
                          spp=args.spp, variant=args.variant, force=args.force, out=args.out)
    sys.stdout.write(json.dumps(report, indent=2) + "\n")
    return 0


def read_result_or_none(outdir):
    """``result.json`` of ``outdir``, or None when it has none (``evaluate`` then says so)."""
    try:
        return read_result(outdir)
    except (FileNotFoundError, ValueError):
        return None
