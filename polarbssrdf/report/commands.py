"""``polarbssrdf report OUTDIR``: the command line of the HTML report (:mod:`.page`)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from polarbssrdf.inverse.results.directory import (
    REPORT_FILE,
    check_report_path,
    check_result_capture,
    read_result,
)
from polarbssrdf.io import load_capture
from polarbssrdf.io.demo_layout import DEMO_ENTRIES
from polarbssrdf.variants import DEFAULT_VARIANT, select_variant


def register(subparsers) -> None:
    """Add ``report`` to the ``polarbssrdf`` argument parser."""
    parser = subparsers.add_parser(
        "report", help="write the HTML report of a result directory (or a demo directory)",
        description="Write one self-contained HTML file (images inlined) with the input "
                    "views, the recovered maps next to the truth and their errors, normals, "
                    "hemoglobin over time, loss curves and metrics. Without ground truth it "
                    "shows maps, losses and re-rendering residuals.")
    parser.add_argument("outdir", type=Path, metavar="OUTDIR",
                        help="a result directory (result.json), or a directory written by "
                             "'polarbssrdf demo' (its result/ is reported, its metrics.json "
                             "reused)")
    parser.add_argument("--capture", type=Path, default=None, metavar="CAPTURE",
                        help="the capture (default: the one result.json records)")
    parser.add_argument("--out", type=Path, default=None, metavar="FILE.html",
                        help="where to write (default: OUTDIR/report.html)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help="Mitsuba variant of the re-rendered view (default: %(default)s)")
    parser.add_argument("--force", action="store_true",
                        help="report with a capture that is not the result's (result.json "
                             "records which capture the maps were fitted on; another one is "
                             "refused with what differs)")
    parser.add_argument("--quiet", action="store_true", help="no progress messages")
    parser.set_defaults(run=run_report)


def run_report(args) -> int:
    """Execute ``polarbssrdf report``; returns the exit status 0."""
    # The page imports the evaluation, the re-renderer and matplotlib: deferred to here so
    # that 'polarbssrdf --help' starts fast.
    from polarbssrdf.report.page import read_json_or_default, write_report

    outdir = args.outdir
    result_dir, evaluation, title, protected = outdir, None, None, ()
    if not (outdir / "result.json").is_file() and (outdir / "result" / "result.json").is_file():

        result_dir = outdir / "result"  # a demo directory
        # the demo's own files, but not its report.html (this command's output)
        protected = [outdir / name for name in DEMO_ENTRIES if name != REPORT_FILE]
        title = "polarbssrdf demo: a synthetic face"
        metrics = read_json_or_default(outdir / "metrics.json")
        if isinstance(metrics, dict) and "evaluation" in metrics:
            evaluation = metrics["evaluation"]
    out = args.out if args.out is not None else outdir / REPORT_FILE
    if (result_dir / "result.json").is_file():
        capture_dir = args.capture if args.capture is not None else read_result(result_dir).capture
        check_report_path(out, result_dir, capture_dir, allowed=(REPORT_FILE,),
                          protected=protected)
        capture = load_capture(capture_dir, check_images=False)
        what = (f"--capture '{capture_dir}'" if args.capture is not None
                else f"the capture '{capture_dir}' recorded in result.json")
        differences = check_result_capture(result_dir, capture, what, force=args.force)
        if differences:
            print(f"polarbssrdf report: warning: {what} is not the result's capture "
                  f"({'; '.join(differences)}); reporting with it anyway (--force)",
                  file=sys.stderr)
    select_variant(args.variant)
    started = time.perf_counter()

    def say(message):
        if not args.quiet:
            print(message, file=sys.stderr, flush=True)

    path = write_report(result_dir, out, capture=args.capture, evaluation=evaluation,
                        variant=args.variant, title=title, progress=say)
    print(f"polarbssrdf report: wrote {path} ({path.stat().st_size / 1e6:.1f} MB) in "
          f"{time.perf_counter() - started:.1f} s")
    return 0
