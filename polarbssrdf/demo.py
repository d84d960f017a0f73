"""``polarbssrdf demo OUTDIR``: the whole acquisition on a synthetic face, end to end.

The demo runs what a user would run, in this process, and prints each step as
the command that repeats it by hand:

1. ``polarbssrdf synth OUTDIR/capture``: a face seen by ``views`` cameras
   through the polarization sensor (raw 12-bit mosaics with sensor noise,
   demosaicked on load), ``frames`` frames with a hemoglobin flush in the
   cheeks, truth maps whose eta and roughness are far from the fit's start
   values (:data:`TRUTH_SETTINGS`);
2. ``polarbssrdf reconstruct OUTDIR/capture OUTDIR/result --holdout CAM``:
   the static, dynamic and biophysical stages, one camera held out;
   (:func:`polarbssrdf.inverse.pipeline.reconstruct`);
3. the evaluation of every stage and frame against the truth
   (:func:`polarbssrdf.inverse.evaluation.scores.evaluate_stages`), written to
   ``OUTDIR/metrics.json`` with the wall time of every step;
4. ``polarbssrdf report OUTDIR``: ``OUTDIR/report.html`` (:mod:`polarbssrdf.report`).

``--resume`` continues an interrupted demo: each step resumes its own
checkpoints. ``OUTDIR/demo.json`` records the settings, so a resume with
other settings is refused with the differences named.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from polarbssrdf.errors import EXIT_USER_ERROR, USER_ERRORS, CommandError, run_command
from polarbssrdf.inverse.commands import integer_at_least
from polarbssrdf.inverse.frames import check_scheduler
from polarbssrdf.inverse.resources import check_memory
from polarbssrdf.inverse.results.directory import STAGES, TIMINGS_FILE
from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.demo_layout import DEMO_ENTRIES, DEMO_FILE
from polarbssrdf.report import commands as report_commands
from polarbssrdf.synth import commands as synth_commands

DEMO_SCHEMA = "polarbssrdf.demo"
METRICS_SCHEMA = "polarbssrdf.demo_metrics"
SCHEMA_VERSION = 1

TRUTH_SETTINGS = {"reflectance": {"eta": [1.50, 0.04, 1.3, 1.6],
                                  "alpha_s": [0.38, 0.05, 0.1, 0.7]}}
"""Truth whose means differ from the fit's start values (eta 1.4, alpha_s 0.35) and vary
more than synth's defaults, so a stage that does not move scores badly."""


@dataclass(frozen=True)
class DemoSettings:
    """The size of the demo.

    Parameters
    ----------
    views : int
        Cameras of the ring rig (each with its coaxial light); one is held out
        of the fit and re-rendered for validation. At least 3.
    frames : int
        Frames; frame 0 is the static frame, the others carry the flush. At least 2.
    texture : int
        Map size T x T, texels (also the truth's).
    resolution : int
        Image width and height, px.
    spp : int
        Samples per pixel of the synthetic images.
    iterations : int or None
        Epochs of the static stage and of each dynamic frame (None: the
        config's defaults, 150 and 30).
    raw : bool
        Raw sensor mosaics with noise (True) or noise-free analyser images.
    seed : int
        Seed of the truth maps, render and sensor noise.
    """

    views: int = 8
    frames: int = 4
    texture: int = 256
    resolution: int = 384
    spp: int = 8
    iterations: int | None = None
    raw: bool = True
    seed: int = 0

    def __post_init__(self):
        for name, minimum in (("views", 3), ("frames", 2), ("texture", 16), ("resolution", 32),
                              ("spp", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < minimum:
                raise ValueError(f"demo --{name} must be an integer >= {minimum}, got {value!r}")
        if self.iterations is not None and self.iterations < 1:
            raise ValueError(f"demo --iterations must be >= 1, got {self.iterations}")
        if self.raw and self.resolution % 2:
            raise ValueError(f"demo --resolution must be even for raw sensor mosaics (2 x 2 "
                             f"polarizer cells), got {self.resolution}; or pass --analyser")
        try:  # whatever else synth would refuse, refused now, before anything is written
            self.synthesis_settings()
        except ValueError as error:
            raise ValueError(f"demo: synth would refuse these settings: {error}") from None

    def synthesis_settings(self):
        """The :class:`~polarbssrdf.synth.synthesize.SynthesisSettings` of the demo's capture
        (what :func:`synth_arguments` asks ``polarbssrdf synth`` for)."""
        # deferred: the renderer's modules take a second to import, and the command line
        # imports this module for its parser at start-up
        from polarbssrdf.synth.synthesize import SynthesisSettings

        return SynthesisSettings(object="face", views=self.views, frames=self.frames,
                                 resolution=self.resolution, texture=self.texture,
                                 spp=self.spp, seed=self.seed, raw=self.raw)

    @property
    def holdout(self) -> str:
        """The camera left out of the fit: the middle one of the ring."""
        return f"cam{self.views // 2:02d}"


def synth_arguments(settings, capture_dir, params_path, resume) -> list[str]:
    """``polarbssrdf synth`` arguments of the demo's capture."""
    arguments = ["synth", str(capture_dir), "--object", "face", "--views", str(settings.views),
                 "--frames", str(settings.frames), "--resolution", str(settings.resolution),
                 "--texture", str(settings.texture), "--spp", str(settings.spp),
                 "--seed", str(settings.seed), "--params", str(params_path)]
    if settings.raw:
        arguments.append("--raw")
    if resume:
        arguments.append("--resume")
    return arguments


def reconstruct_arguments(settings, capture_dir, result_dir, resume, workers=None,
                          scheduler=None) -> list[str]:
    """``polarbssrdf reconstruct`` arguments of the demo's run (all stages)."""
    arguments = ["reconstruct", str(capture_dir), str(result_dir), "--holdout",
                 settings.holdout]
    if settings.iterations is not None:
        arguments += ["--iterations", str(settings.iterations)]
    if workers:
        arguments += ["--workers", str(workers)]
    if scheduler:
        arguments += ["--scheduler", scheduler]
    if resume:
        arguments.append("--resume")
    return arguments


def prepare_demo_directory(outdir: Path, settings: DemoSettings, *, resume=False,
                           overwrite=False) -> None:
    """Create ``outdir`` or check it for ``resume``/``overwrite``; write ``demo.json``."""
    record = outdir / DEMO_FILE
    if outdir.exists() and not outdir.is_dir():
        raise CommandError(f"'{outdir}' exists and is not a directory")
    existing = outdir.is_dir() and any(outdir.iterdir())
    if existing and not record.is_file():
        raise CommandError(f"'{outdir}' is not empty and holds no {DEMO_FILE}: it is not a demo "
                           "directory; choose a new or empty one (nothing was changed)")
    if existing and resume:
        try:
            earlier = json.loads(record.read_text())["settings"]
        except (ValueError, KeyError) as error:
            raise CommandError(f"{record} is unreadable ({error}); use --overwrite to start "
                               "over") from None
        current = asdict(settings)
        differences = [f"--{k}: {earlier.get(k)!r} (first run) vs {v!r} (now)"
                       for k, v in current.items() if earlier.get(k) != v]
        if differences:
            raise CommandError(f"cannot resume the demo in '{outdir}': it was started with other "
                               f"settings ({'; '.join(differences)}); rerun with them, or use "
                               "--overwrite to start over")
        return
    if existing and not overwrite:
        raise CommandError(f"'{outdir}' holds a demo: use --resume to continue it, or "
                           "--overwrite to start over")
    if existing:
        for name in DEMO_ENTRIES:
            path = outdir / name
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
    outdir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(record, json.dumps({"schema": DEMO_SCHEMA,
                                          "schema_version": SCHEMA_VERSION,
                                          "settings": asdict(settings)}, indent=1) + "\n",
                      overwrite=True)


RERUN_ADVICE = ("once the cause is fixed, rerun the same demo command with --resume to go on "
                "(with other options, --overwrite starts over: --resume needs the same ones)")
"""What to do after a step failed. The demo's options were checked before anything was
written, so such a failure is not in them: the same command with --resume is accepted."""


def _run_step(command_module, arguments, say) -> None:
    """Run ``polarbssrdf ARGUMENTS`` through its command module's own parser and handler."""
    say("$ polarbssrdf " + " ".join(arguments))
    parser = argparse.ArgumentParser(prog="polarbssrdf")
    command_module.register(parser.add_subparsers(dest="command", required=True))
    status = run_command(parser.parse_args(arguments))
    if status:
        raise CommandError(f"'polarbssrdf {arguments[0]}' failed (status {status}; its message "
                           f"is above); {RERUN_ADVICE}")


def _reconstruct_step(settings, capture_dir, result_dir, resume, workers, scheduler, quiet,
                      say) -> None:
    """``polarbssrdf reconstruct`` of the demo, through the Python API."""
    # deferred: the pipeline imports every stage, and the command line imports this module
    # for its parser at start-up
    from polarbssrdf.inverse.pipeline import reconstruct

    say("$ polarbssrdf " + " ".join(reconstruct_arguments(settings, capture_dir, result_dir,
                                                          resume, workers, scheduler)
                                    + (["--quiet"] if quiet else [])))
    try:
        result = reconstruct(capture_dir, result_dir, holdout=[settings.holdout],
                             iterations=settings.iterations, workers=workers,
                             scheduler=scheduler, resume=resume, progress=not quiet)
    except USER_ERRORS as error:
        print(f"polarbssrdf reconstruct: error: {error}", file=sys.stderr)
        raise CommandError(f"'polarbssrdf reconstruct' failed (status {EXIT_USER_ERROR}; its "
                           f"message is above); {RERUN_ADVICE}") from None
    print(result.summary())
    if result.failed:
        for frame, reason in sorted(result.failed.items()):
            print(f"polarbssrdf reconstruct: frame {frame} failed: {reason}", file=sys.stderr)
        raise CommandError(f"'polarbssrdf reconstruct' failed ({len(result.failed)} frame(s); "
                           f"their messages are above); {RERUN_ADVICE}")
    return result


def _earlier_seconds(outdir: Path) -> dict:
    """``seconds`` of the demo's earlier ``metrics.json`` (empty when it has none)."""
    try:
        seconds = json.loads((outdir / "metrics.json").read_text()).get("seconds", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return seconds if isinstance(seconds, dict) else {}


def headline_figures(evaluation) -> dict:
    """The figures a reader looks for first, from :func:`evaluate_stages`'s output."""
    figures = {}
    static = evaluation.get("static")
    if static:
        maps = static["maps"]
        for name in ("eta", "alpha_s"):
            figures[f"static {name} MAE"] = round(maps[name]["mae"], 4)
            figures[f"static {name} MAE of the best constant map"] = round(
                maps[name]["constant_mae"], 4)
        figures["static rho_sss relative error (mean of bands)"] = round(
            maps["rho_sss"]["mean_relative_error"], 4)
        figures["static normal error, degrees"] = round(maps["normal"]["mean_deg"], 3)
        for name in ("eta", "alpha_s", "displacement"):
            if maps[name].get("coverage") is not None:
                figures[f"static {name} fraction within 2 std"] = round(maps[name]["coverage"], 3)
        bands = [entry.get("coverage") for entry in maps["rho_sss"].get("bands", {}).values()]
        bands = [c for c in bands if c is not None and c == c]
        if bands:
            figures["static rho_sss fraction within 2 std (mean of bands)"] = round(
                sum(bands) / len(bands), 3)
        holdout = static.get("holdout") or {}
        if holdout.get("mean"):
            figures["held-out I_s RMSE / mean I_sss"] = round(
                holdout["mean"]["relative_rmse_I_s"], 4)
            figures["held-out I_sss RMSE / mean I_sss"] = round(
                holdout["mean"]["relative_rmse_I_sss"], 4)
    bio = evaluation.get("bio") or {}
    if bio:
        for parameter in ("C_m", "beta_m", "C_h_out", "C_h_in"):
            values = [entry["maps"][parameter]["mae_of_range"] for entry in bio.values()]
            figures[f"bio {parameter} MAE / Table 2 range (mean over frames)"] = round(
                sum(values) / len(values), 4)
            constants = [entry["maps"][parameter]["constant_mae_of_range"] for entry in bio.values()]
            figures[f"bio {parameter} MAE of the best constant map / Table 2 range"] = round(
                sum(constants) / len(constants), 4)
            coverages = [entry["maps"][parameter].get("coverage") for entry in bio.values()]
            coverages = [c for c in coverages if c is not None and c == c]
            if coverages:
                figures[f"bio {parameter} fraction within 2 std (mean over frames)"] = round(
                    sum(coverages) / len(coverages), 3)
    return figures


def static_notes_of(result_dir) -> dict:
    """``{map: note}`` of the static map file of a result
    (:func:`polarbssrdf.inverse.evaluation.trust.static_map_notes`): the maps held at one
    face value."""
    # deferred with the evaluation (see run_demo)
    from polarbssrdf.inverse.evaluation.trust import static_map_notes
    from polarbssrdf.inverse.results.directory import read_result
    from polarbssrdf.io.exr import read_exr

    for record in read_result(result_dir).maps:
        if record["stage"] == "static":
            return static_map_notes(read_exr(Path(result_dir) / record["path"])[1])
    return {}


def bio_notes_of(result_dir) -> dict:
    """``{frame: bio_map_notes}`` of every registered biophysical map file of a result
    (:func:`polarbssrdf.inverse.evaluation.trust.bio_map_notes`; frames as strings)."""
    # deferred with the evaluation (see run_demo)
    from polarbssrdf.inverse.evaluation.trust import bio_map_notes
    from polarbssrdf.inverse.results.directory import read_result
    from polarbssrdf.io.exr import read_exr

    notes = {}
    for record in read_result(result_dir).maps:
        if record["stage"] == "bio":
            found = bio_map_notes(*read_exr(Path(result_dir) / record["path"]))
            if found:
                notes[str(record["frame"])] = found
    return notes


CONSTANT_PARTNER = (" MAE", " MAE of the best constant map")
"""A headline MAE's key -> the key of the best constant map's MAE beside it (with
" (mean over frames)" dropped)."""


def closing_lines(metrics) -> list[str]:
    """The headline figures as the demo prints them: each MAE beside the best constant
    map's and marked, as the report marks it, when it is no better; each 2-std coverage
    beside its ideal; then every map the report marks, and the biophysical maps that are
    held or prior-dominated (:func:`polarbssrdf.inverse.evaluation.trust.bio_map_notes`,
    ``metrics["bio_notes"]``), and the static maps held at one face value
    (``metrics["static_notes"]``)."""
    # deferred: the scores' module imports the renderer (seconds); the parser does not need it
    from polarbssrdf.inverse.evaluation.scores import (
        COVERAGE_IDEAL,
        LOSES,
        loses_to_constant,
        losing_maps,
    )
    from polarbssrdf.inverse.evaluation.trust import unmeasured_summary

    headline = metrics.get("headline") or {}
    constant_of = {}  # a map's headline key -> the best constant map's key beside it
    for key in headline:
        constant_key = key.replace(*CONSTANT_PARTNER, 1).replace(" (mean over frames)", "")
        if CONSTANT_PARTNER[1] not in key and constant_key != key and constant_key in headline:
            constant_of[key] = constant_key
    lines = []
    for key, value in headline.items():
        if key in constant_of.values():
            continue  # printed beside its map's figure
        line = f"  {key}: {value}"
        if key in constant_of:
            constant = headline[constant_of[key]]
            line += f" (best constant map: {constant})"
            if loses_to_constant(value, constant):
                line += f"  <- {LOSES}"
        if "within 2 std" in key:
            line += f" (ideal {COVERAGE_IDEAL:.3f})"
        lines.append(line)
    losers = losing_maps(metrics.get("evaluation"))
    marked = [f"{name} (static)" for name in losers["static"]]
    by_map = {}
    for frame, names in sorted(losers["bio"].items(), key=lambda item: int(item[0])):
        for name in names:
            by_map.setdefault(name, []).append(frame)
    marked += [f"{name} (bio, frame{'s' if len(frames) > 1 else ''} {', '.join(frames)})"
               for name, frames in by_map.items()]
    if marked:
        lines.append(f"  {LOSES} (marked in the report): {', '.join(marked)}")
    held = metrics.get("static_notes") or {}
    if held:
        lines.append("  static maps the views do not resolve, held at one face value (said "
                     f"beside them in the report): {', '.join(held)}")
    said = unmeasured_summary(metrics.get("bio_notes") or {})
    if said:
        lines.append(f"  bio maps the bands do not measure (said beside them in the "
                     f"report): {said}")
    return lines


def run_demo(outdir, settings=DemoSettings(), *, resume=False, overwrite=False, workers=None,
             scheduler=None, quiet=False) -> dict:
    """Run the demo into ``outdir``; returns the contents of ``OUTDIR/metrics.json``."""
    # deferred, like the pipeline (see _reconstruct_step); the spectral data pulls in
    # colour-science
    from polarbssrdf.inverse.evaluation.scores import evaluate_stages
    from polarbssrdf.spectral import shipped_default_bands

    outdir = Path(outdir)

    def say(message):
        if not quiet:
            print(message, file=sys.stderr, flush=True)

    # refused before anything is written: the run's memory (synth's bands, every view but
    # the held-out one fitted), the scheduler
    check_memory(settings.texture, len(shipped_default_bands()), settings.views - 1,
                 ("static", "dynamic", "bio"), what="the demo")
    if scheduler is not None:
        check_scheduler(scheduler)
    prepare_demo_directory(outdir, settings, resume=resume, overwrite=overwrite)
    capture_dir, result_dir = outdir / "capture", outdir / "result"
    params = outdir / "truth_settings.json"
    atomic_write_text(params, json.dumps(TRUTH_SETTINGS, indent=1) + "\n", overwrite=True)
    seconds = {}
    quiet_flag = ["--quiet"] if quiet else []
    # a resume keeps the seconds of the run that did a step's work (metrics.json, written
    # once reconstruct had finished): a step it finds done takes none
    earlier = _earlier_seconds(outdir) if resume else {}
    reused = []

    say(f"polarbssrdf demo: [1/4] a synthetic face capture: {settings.views} views, "
        f"{settings.frames} frames")
    started = time.perf_counter()
    synth_resume = resume and capture_dir.is_dir() and any(capture_dir.iterdir())
    synth_done = synth_resume and (capture_dir / "capture.json").is_file()  # written last
    _run_step(synth_commands, synth_arguments(settings, capture_dir, params, synth_resume)
              + quiet_flag, say)
    seconds["synth"] = time.perf_counter() - started
    if synth_done and "synth" in earlier:
        seconds["synth"] = earlier["synth"]
        reused.append("synth")

    say("polarbssrdf demo: [2/4] reconstruct: static, dynamic and biophysical stages")
    started = time.perf_counter()
    result_resume = resume and result_dir.is_dir() and any(result_dir.iterdir())
    result = _reconstruct_step(settings, capture_dir, result_dir, result_resume, workers,
                               scheduler, quiet, say)
    seconds["reconstruct"] = time.perf_counter() - started
    if set(result.reused) == set(STAGES) and "reconstruct" in earlier:
        seconds["reconstruct"] = earlier["reconstruct"]
        reused.append("reconstruct")
    if reused:
        say(f"polarbssrdf demo: reused the finished {' and '.join(reused)} of the earlier run; "
            "metrics.json keeps that run's times")
    try:
        stage_seconds = json.loads((result_dir / TIMINGS_FILE).read_text())
    except (FileNotFoundError, ValueError):
        stage_seconds = {}

    say("polarbssrdf demo: [3/4] evaluate every stage and frame against the truth")
    started = time.perf_counter()
    evaluation = evaluate_stages(result_dir, capture_dir, holdout=True,
                                 progress=lambda stage, frame: say(f"  {stage}, frame {frame}"))
    seconds["evaluate"] = time.perf_counter() - started
    metrics = {"schema": METRICS_SCHEMA, "schema_version": SCHEMA_VERSION,
               "settings": asdict(settings), "holdout": [settings.holdout],
               "headline": headline_figures(evaluation),
               "static_notes": static_notes_of(result_dir),
               "bio_notes": bio_notes_of(result_dir),
               "seconds": {**{k: round(v, 2) for k, v in seconds.items()},
                           "stages": stage_seconds, "reused": reused},
               "evaluation": evaluation}

    atomic_write_text(outdir / "metrics.json", json.dumps(metrics, indent=1) + "\n",
                      overwrite=True)

    say("polarbssrdf demo: [4/4] the report")
    started = time.perf_counter()
    # the report command reads the demo directory: its result/ and the evaluation above
    _run_step(report_commands, ["report", str(outdir)] + quiet_flag, say)
    seconds["report"] = time.perf_counter() - started
    metrics["seconds"]["report"] = round(seconds["report"], 2)
    atomic_write_text(outdir / "metrics.json", json.dumps(metrics, indent=1) + "\n",
                      overwrite=True)
    metrics["report"] = str(outdir / "report.html")
    return metrics


# --------------------------------------------------------------------------- command
def register(subparsers) -> None:
    """Add ``demo`` to the ``polarbssrdf`` argument parser."""
    defaults = DemoSettings()
    parser = subparsers.add_parser(
        "demo", help="synthesize a face capture, reconstruct it, evaluate it, write a report",
        description="The whole acquisition on a synthetic face: 'polarbssrdf synth' (raw "
                    "polarization mosaics with sensor noise, a hemoglobin flush over the "
                    "frames), 'polarbssrdf reconstruct' (static, dynamic and biophysical "
                    "stages, one camera held out), the evaluation of every stage against the "
                    "truth (OUTDIR/metrics.json) and OUTDIR/report.html. The defaults take "
                    "about 10 minutes on 2 cores (bench/RESULTS.md).")
    parser.add_argument("outdir", type=Path, metavar="OUTDIR",
                        help="demo directory: new or empty, or an earlier demo with --resume "
                             "or --overwrite")
    parser.add_argument("--views", type=integer_at_least(3), default=defaults.views,
                        help="cameras; the middle one is held out (default: %(default)s)")
    parser.add_argument("--frames", type=integer_at_least(2), default=defaults.frames,
                        help="frames, the first one static (default: %(default)s)")
    parser.add_argument("--texture", type=integer_at_least(16), default=defaults.texture,
                        metavar="T", help="map size T x T, texels (default: %(default)s)")
    parser.add_argument("--resolution", type=integer_at_least(32),
                        default=defaults.resolution, help="image size, px (default: "
                                                          "%(default)s)")
    parser.add_argument("--spp", type=integer_at_least(1), default=defaults.spp,
                        help="samples per pixel of the synthetic images (default: %(default)s)")
    parser.add_argument("--iterations", type=integer_at_least(1), default=None, metavar="N",
                        help="epochs of the static stage and of each dynamic frame (default: "
                             "150 and 30)")
    parser.add_argument("--analyser", action="store_true",
                        help="noise-free analyser images instead of raw sensor mosaics")
    parser.add_argument("--seed", type=integer_at_least(0), default=defaults.seed,
                        help="seed of the truth, render and noise (default: %(default)s)")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--resume", action="store_true",
                          help="continue an interrupted demo in OUTDIR (same settings)")
    existing.add_argument("--overwrite", action="store_true",
                          help="start over in OUTDIR (removes only what the demo wrote)")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=integer_at_least(1), default=None, metavar="N",
                         help="run the per-frame fits on a local Dask cluster of N processes")
    cluster.add_argument("--scheduler", default=None, metavar="ADDRESS",
                         help="run the per-frame fits on an existing Dask cluster")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.set_defaults(run=run)


def run(args) -> int:
    """Execute ``polarbssrdf demo``; prints the headline figures, returns 0."""
    try:
        settings = DemoSettings(views=args.views, frames=args.frames, texture=args.texture,
                                resolution=args.resolution, spp=args.spp,
                                iterations=args.iterations, raw=not args.analyser,
                                seed=args.seed)
    except ValueError as error:
        raise CommandError(str(error)) from None
    started = time.perf_counter()
    metrics = run_demo(args.outdir, settings, resume=args.resume, overwrite=args.overwrite,
                       workers=args.workers, scheduler=args.scheduler, quiet=args.quiet)
    print(f"polarbssrdf demo: {args.outdir} in {time.perf_counter() - started:.0f} s")
    if metrics["seconds"].get("reused"):
        print(f"  reused from the earlier run: {', '.join(metrics['seconds']['reused'])} "
              "(metrics.json keeps its times)")
    for line in closing_lines(metrics):
        print(line)
    print(f"  report: {metrics['report']}")
    print(f"  metrics: {Path(args.outdir) / 'metrics.json'}; maps: "
          f"{Path(args.outdir) / 'result'}")
    return 0
