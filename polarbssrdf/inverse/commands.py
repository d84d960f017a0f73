"""``polarbssrdf reconstruct`` and ``polarbssrdf evaluate``: captures to maps, maps to scores.

``polarbssrdf reconstruct CAPTURE OUTDIR`` runs the acquisition stages
(today the static stage, :mod:`polarbssrdf.inverse.static`) on a capture and
writes a result directory (:mod:`polarbssrdf.inverse.result`);
``polarbssrdf evaluate OUTDIR`` compares its maps with a synthetic capture's
ground truth and re-renders the cameras the run held out
(:mod:`polarbssrdf.inverse.evaluate`). See ``docs/reconstruct.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from polarbssrdf.errors import CommandError

STAGES = ("static", "dynamic", "bio")
"""The stages ``--stages`` accepts, in the order they run."""

DEFAULT_STAGES = STAGES
DEFAULT_VARIANT = "llvm_ad_mono_polarized"
DEFAULT_TEXTURE = 512
"""Texture size without ``--texture`` when the capture has no ground truth."""

DOC = "docs/reconstruct.md"

STAGE_TITLES = {
    "static": "polarimetric inverse rendering of the static frame (eq. 26-35)",
    "dynamic": "every other frame, from the static maps (eq. 36-39)",
    "bio": "melanin and hemoglobin per frame (eq. 40-47)",
}
"""What each stage does, for its header line on the progress display."""

TIMINGS_FILE = "timings.json"
"""``OUTDIR/timings.json``: wall seconds of the last run of each stage."""


def _integer_at_least(minimum: int):
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
    from polarbssrdf.inverse.config import StaticConfig
    from polarbssrdf.inverse.rerender import DEFAULT_SPP

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
    parser.add_argument("--stages", default=",".join(DEFAULT_STAGES), metavar="S[,S...]",
                        help=f"stages to run, comma-separated; known: {', '.join(STAGES)} "
                             "(default: %(default)s)")
    parser.add_argument("--texture", type=_integer_at_least(8), default=None, metavar="T",
                        help="map size T x T in texels (default: the capture's truth texture "
                             f"size if it has ground truth, else {DEFAULT_TEXTURE})")
    parser.add_argument("--iterations", type=_integer_at_least(0), default=None, metavar="N",
                        help="epochs of the static stage and of each dynamic frame (default: "
                             f"the config's, {StaticConfig.iterations} and 30 unless --config "
                             "sets them)")
    parser.add_argument("--config", type=Path, default=None, metavar="FILE.json",
                        help=f"JSON object overriding any StaticConfig key ({DOC}; default: "
                             "the paper's settings); --iterations wins over its 'iterations'")
    parser.add_argument("--holdout", default="", metavar="CAM[,CAM...]",
                        help="cameras left out of the fit, for validation re-renders with "
                             "'polarbssrdf evaluate' (default: none)")
    parser.add_argument("--frame", type=_integer_at_least(0), default=0, metavar="F",
                        help="frame index of the capture to fit (default: %(default)s)")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--resume", action="store_true",
                          help="continue the run in OUTDIR from its last checkpoint; needs the "
                               "same capture and settings (differences are named)")
    existing.add_argument("--overwrite", action="store_true",
                          help="start over in OUTDIR, removing the earlier run's outputs (the "
                               "observation cache is reused if its inputs match)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help="Mitsuba variant, a JIT autodiff polarized one "
                             "(default: %(default)s)")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=_integer_at_least(1), default=None, metavar="N",
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
    parser.add_argument("--frame", type=_integer_at_least(0), default=0, metavar="F",
                        help="frame to score (default: %(default)s)")
    parser.add_argument("--stage", default="static", choices=STAGES,
                        help="stage whose maps are scored (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=None, metavar="FILE.json",
                        help="also write the JSON to this file (atomically; default: print only)")
    parser.add_argument("--spp", type=_integer_at_least(1), default=DEFAULT_SPP,
                        help="samples per pixel of the held-out re-renders "
                             "(default: %(default)s)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help="Mitsuba variant of the re-renders, a mono polarized one "
                             "(default: %(default)s)")
    parser.set_defaults(run=run_evaluate)


# --------------------------------------------------------------------------- reconstruct
def parse_stages(text: str) -> list[str]:
    """The stages of ``--stages``, in run order; unknown names are a :class:`CommandError`."""
    names = _name_list(text)
    if not names:
        raise CommandError(f"--stages is empty; known stages: {', '.join(STAGES)}")
    unknown = [name for name in names if name not in STAGES]
    if unknown:
        raise CommandError(f"unknown stage{'s' if len(unknown) > 1 else ''} "
                           f"{', '.join(repr(n) for n in unknown)} in --stages; known stages: "
                           f"{', '.join(STAGES)}")
    return [stage for stage in STAGES if stage in names]


def autodiff_polarized_variants(available) -> list[str]:
    """The variants the stages run in: JIT (LLVM or CUDA), autodiff, polarized."""
    return [v for v in available
            if v.startswith(("llvm_", "cuda_")) and "_ad_" in v and v.endswith("polarized")]


def check_variant(variant: str, available) -> None:
    """Raise :class:`CommandError` unless ``variant`` is an available JIT AD polarized variant."""
    usable = autodiff_polarized_variants(available)
    if variant in usable:
        return
    choices = ", ".join(usable) or "none in this Mitsuba build"
    if variant not in available:
        reason = f"Mitsuba variant {variant!r} is not available in this build"
    elif not variant.endswith("polarized"):
        reason = f"variant {variant!r} is not polarized: the stages fit Stokes observations"
    else:
        reason = (f"variant {variant!r} is not a JIT autodiff variant: the stages need "
                  "Dr.Jit's autodiff (llvm_ad_* or cuda_ad_*)")
    raise CommandError(f"{reason}; use one of: {choices}")


def select_variant(variant: str) -> None:
    """Activate ``variant`` and register the package's plugins in it."""
    import mitsuba as mi

    import polarbssrdf

    try:
        mi.set_variant(variant)
    except (ImportError, RuntimeError) as error:  # e.g. a CUDA variant without a GPU
        raise CommandError(f"cannot activate Mitsuba variant '{variant}': {error}") from None
    polarbssrdf.register_plugins()


def load_config(path, iterations):
    """The :class:`StaticConfig` of ``--config`` and ``--iterations`` (errors name the key)."""
    from polarbssrdf.inverse.config import load_static_config, static_config

    changes = {} if iterations is None else {"iterations": iterations}
    config = static_config(**changes) if path is None else load_static_config(path, **changes)
    if iterations is not None and "iterations" not in config.dynamic:
        # --iterations sets the epochs of both polarimetric stages
        config.dynamic = {**config.dynamic, "iterations": iterations}
    return config


def load_input_capture(path: Path, frame: int | None = None):
    """The capture of ``CAPTURE`` (manifests only), with a one-line error for each problem.

    With ``frame``, only that frame's image files must exist: the dynamic stage
    checks every other frame when it starts it, so a missing image fails only its frame.
    """
    from polarbssrdf.io import load_capture

    if not path.exists():
        raise FileNotFoundError(f"capture directory '{path}' does not exist")
    if not path.is_dir():
        raise CommandError(f"capture '{path}' is not a directory")
    capture = load_capture(path, check_images=False, frames=None if frame is None else [frame])
    if capture.manifest.mesh is None:
        raise CommandError(f"capture '{path}' has no mesh: the stages work in the texture space "
                           "of the object's mesh (with UVs); add one to capture.json ('mesh')")
    return capture


def check_frame_and_holdout(capture, frame: int, holdout: list[str]) -> None:
    """The frame exists, has polarization images, and ``holdout`` names cameras that have them."""
    manifest = capture.manifest
    indices = [f.index for f in manifest.frames]
    if frame not in indices:
        raise CommandError(f"capture '{capture.directory}' has no frame {frame} (frames: "
                           f"{', '.join(map(str, indices))})")
    cameras = [camera.name for camera in manifest.cameras]
    unknown = [name for name in holdout if name not in cameras]
    if unknown:
        raise CommandError(f"--holdout names unknown camera{'s' if len(unknown) > 1 else ''} "
                           f"{', '.join(unknown)}; the capture's cameras are: "
                           f"{', '.join(cameras)}")
    polarized = [r for r in manifest.frame(frame).images if r.kind in ("analyser", "raw")]
    if not polarized:
        kinds = sorted({r.kind for r in manifest.frame(frame).images}) or ["none"]
        raise CommandError(f"frame {frame} of capture '{capture.directory}' has no polarization "
                           f"images (analyser or raw; it has: {', '.join(kinds)}): nothing to "
                           "fit")
    seen = {r.camera for r in polarized}
    without = [name for name in holdout if name not in seen]
    if without:
        raise CommandError(f"--holdout camera{'s' if len(without) > 1 else ''} "
                           f"{', '.join(without)} took no polarization image in frame {frame}: "
                           "nothing to validate against")
    if seen <= set(holdout):
        raise CommandError(f"--holdout leaves out every camera of frame {frame} "
                           f"({', '.join(sorted(seen))}): nothing left to fit")


def run_settings(stages, config, holdout, frame) -> dict:
    """What defines a run besides the capture and texture size (``result.json`` settings)."""
    return {"stages": list(stages), "frame": int(frame), "holdout": sorted(holdout),
            "config": config.to_json()}


def _short(value, limit=60) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def resume_differences(outdir: Path, capture_dir: Path, texture: int, settings: dict) -> list:
    """Settings of the run in ``outdir`` that differ from this one, as readable strings.

    Nested settings (the config) are compared key by key, so the message names
    e.g. ``config.iterations`` rather than the whole config.
    """
    from polarbssrdf.inverse.result import RESULT_FILE, read_result
    from polarbssrdf.io.capture import json_differences

    if not (outdir / RESULT_FILE).is_file():
        return []
    manifest = read_result(outdir)
    differences = []
    if Path(manifest.capture) != capture_dir.resolve():
        differences.append(f"capture: {manifest.capture} (first run) vs {capture_dir.resolve()} "
                           "(now)")
    if manifest.texture_size != texture:
        differences.append(f"--texture: {manifest.texture_size} (first run) vs {texture} (now)")
    names = {"stages": "--stages", "frame": "--frame", "holdout": "--holdout"}
    old = json.loads(json.dumps(manifest.settings))
    new = json.loads(json.dumps(settings))
    pairs = []
    for key in list(old) + [k for k in new if k not in old]:
        before, after = old.get(key, "<absent>"), new.get(key, "<absent>")
        if isinstance(before, dict) and isinstance(after, dict):
            pairs += json_differences(before, after, key)  # config: key by key
        elif before != after:
            pairs.append((key, before, after))  # lists (holdout, stages) whole
    for path, before, after in pairs:
        name = names.get(path, path)
        if path == "config.iterations":
            name = "config.iterations (--iterations)"
        differences.append(f"{name}: {_short(before)} (first run) vs {_short(after)} (now)")
    return differences


def record_stage_seconds(outdir: Path, seconds: dict) -> None:
    """Merge ``{stage: wall seconds}`` into ``OUTDIR/timings.json`` (atomically).

    The last run of a stage replaces its entry; a resumed stage records the
    seconds of the resumed part only.
    """
    from polarbssrdf.io.atomic import atomic_write_text

    path = Path(outdir) / TIMINGS_FILE
    try:
        timings = json.loads(path.read_text())
    except (FileNotFoundError, ValueError):
        timings = {}
    timings.update({stage: round(float(value), 3) for stage, value in seconds.items()})
    atomic_write_text(path, json.dumps(timings, indent=1) + "\n", overwrite=True)


def _texel_views(path: Path) -> int | None:
    from polarbssrdf.io.exr import read_exr

    try:
        _, metadata = read_exr(path)
    except (OSError, ValueError):
        return None
    value = (metadata or {}).get("texel_views")
    return int(value) if isinstance(value, (int, float)) else None


def run_reconstruct(args) -> int:
    """Execute ``polarbssrdf reconstruct``; returns the exit status 0."""
    import mitsuba as mi

    from polarbssrdf.inverse.result import prepare_result_directory

    started = time.perf_counter()
    stages = parse_stages(args.stages)
    check_variant(args.variant, mi.variants())
    holdout = _name_list(args.holdout)
    config = load_config(args.config, args.iterations)
    capture = load_input_capture(args.capture, args.frame)
    check_frame_and_holdout(capture, args.frame, holdout)
    if args.texture is not None:
        texture = args.texture
    elif capture.truth is not None:
        texture = int(capture.truth.texture_size)
    else:
        texture = DEFAULT_TEXTURE
    outdir = args.outdir
    if outdir.exists() and not outdir.is_dir():
        raise CommandError(f"output directory '{outdir}' exists and is not a directory")
    settings = run_settings(stages, config, holdout, args.frame)
    if args.overwrite and stages[0] != STAGES[0]:
        # --overwrite removes the static maps, which these stages would then read
        raise CommandError(f"--overwrite with --stages {','.join(stages)} would remove the "
                           "static maps those stages read; include 'static' in --stages to "
                           "start over, or drop --overwrite to add to the run in "
                           f"'{outdir}'")
    # later stages on an earlier run read its maps and add their own (no --resume needed)
    continuing = stages[0] != STAGES[0]
    if args.resume and not continuing and outdir.is_dir() and any(outdir.iterdir()):
        differences = resume_differences(outdir, capture.directory, texture, settings)
        if differences:
            raise CommandError(f"cannot resume in '{outdir}': it holds a run with other settings "
                               f"({'; '.join(differences)}); rerun with its settings to continue "
                               "it, or pass --overwrite instead of --resume to start over")
    select_variant(args.variant)
    if continuing:
        from polarbssrdf.inverse.result import continue_result_directory

        continue_result_directory(outdir, capture.directory, texture)
    else:
        prepare_result_directory(outdir, capture.directory, texture, settings,
                                 resume=args.resume, overwrite=args.overwrite)

    progress = not args.quiet
    lines = []
    failed = {}
    seconds_per_stage = {}
    for number, stage in enumerate(stages, start=1):
        # one display across stages: each stage's header and bars carry "[i/n] stage"
        label = f"[{number}/{len(stages)}] {stage}"
        if progress:
            print(f"polarbssrdf reconstruct: {label}: {STAGE_TITLES[stage]}", file=sys.stderr,
                  flush=True)
        stage_start = time.perf_counter()
        if stage == "static":
            from polarbssrdf.inverse.static import run_static_stage

            result = run_static_stage(capture, outdir, config, texture, frame=args.frame,
                                      holdout=tuple(holdout), progress=progress, label=label)
            views = _texel_views(result.path)
            epochs = len(result.history)
            final = result.history[-1].get("total") if result.history else None
            lines.append(f"  static: {result.path} ({len(result.maps)} channels, {epochs} "
                         f"epochs, {'?' if views is None else f'{views:,}'} texel-views"
                         + (f", final loss {final:.4g}" if final is not None else "")
                         + f", {time.perf_counter() - stage_start:.1f} s)")
        elif stage == "dynamic":
            from polarbssrdf.inverse.dynamic import run_dynamic_stage

            report = run_dynamic_stage(capture, outdir, texture, config, holdout=tuple(holdout),
                                       static_frame=args.frame, workers=args.workers,
                                       scheduler=args.scheduler,
                                       resume=args.resume or continuing, progress=progress,
                                       variant=args.variant, label=label)
            failed.update(report["failed"])
            lines.append(f"  dynamic: {len(report['done'])} frame(s) fitted"
                         + (f", {len(report['skipped'])} already done" if report["skipped"] else "")
                         + (f", {len(report['failed'])} failed" if report["failed"] else "")
                         + f" -> {outdir / 'dynamic'} ({time.perf_counter() - stage_start:.1f} s)")
        elif stage == "bio":
            from polarbssrdf.inverse.bio_stage import run_bio_stage

            summary = run_bio_stage(capture, outdir, texture, config.bio,
                                    resume=args.resume or continuing, progress=progress,
                                    workers=args.workers, scheduler=args.scheduler,
                                    variant=args.variant, label=label)
            failed.update({frame: f"bio: {reason}" for frame, reason in summary["failed"].items()})
            kinds = sorted(set(summary["source_stages"].values()))
            lines.append(f"  bio: {len(summary['frames'])} frame(s) from the "
                         f"{' and '.join(kinds)} maps -> {outdir / 'bio'} (maps, previews, "
                         f"summary.json; {time.perf_counter() - stage_start:.1f} s)")
        seconds_per_stage[stage] = time.perf_counter() - stage_start
        record_stage_seconds(outdir, {stage: seconds_per_stage[stage]})
    seconds = time.perf_counter() - started
    held = f"; held out {', '.join(holdout)}" if holdout else ""
    print(f"polarbssrdf reconstruct: {capture.directory} -> {outdir} ({texture} x {texture} "
          f"texels, frame {args.frame}{held}) in {seconds:.1f} s", file=sys.stdout)
    for line in lines:
        print(line)
    print(f"  result.json, metrics.json and previews in {outdir}; score it with "
          f"'polarbssrdf evaluate {outdir}'")
    if failed:
        for frame, reason in sorted(failed.items()):
            print(f"polarbssrdf reconstruct: frame {frame} failed: {reason}", file=sys.stderr)
        print(f"polarbssrdf reconstruct: {len(failed)} frame(s) failed; result.json lists the "
              "others; fix the input and rerun with --resume to do only the missing ones",
              file=sys.stderr)
        return 1
    return 0


# --------------------------------------------------------------------------- evaluate
def check_report_path(out: Path, outdir: Path, capture_dir: Path | None) -> None:
    """``--out`` must not replace an input: the result's own files or anything in the capture."""
    from polarbssrdf.inverse.result import RESULT_FILE, read_result

    target = out.resolve()
    if out.exists() and out.is_dir():
        raise CommandError(f"--out '{out}' is a directory; give a file name, e.g. "
                           f"{out / 'evaluation.json'}")
    protected = {(outdir / RESULT_FILE).resolve()}
    try:
        protected |= {(outdir / record["path"]).resolve() for record in read_result(outdir).maps}
    except (FileNotFoundError, ValueError):
        pass
    if target in protected:
        raise CommandError(f"--out '{out}' would overwrite a file of the result; choose another "
                           "name")
    if capture_dir is not None:
        capture_dir = Path(capture_dir).resolve()
        if target == capture_dir or capture_dir in target.parents:
            raise CommandError(f"--out '{out}' is inside the capture {capture_dir}: polarbssrdf "
                               "never writes into its inputs")


def run_evaluate(args) -> int:
    """Execute ``polarbssrdf evaluate``; prints the JSON, returns the exit status 0."""
    from polarbssrdf.inverse.evaluate import evaluate_result, truth_capture
    from polarbssrdf.inverse.rerender import RENDER_VARIANT
    from polarbssrdf.io.atomic import atomic_write_text

    import mitsuba as mi

    if not args.variant.endswith("mono_polarized") or args.variant not in mi.variants():
        usable = [v for v in mi.variants()
                  if v.endswith("mono_polarized") and v.startswith(("llvm_", "cuda_"))]
        raise CommandError(f"--variant {args.variant!r}: held-out views are re-rendered per band "
                           f"in an available JIT mono polarized variant; use one of: "
                           f"{', '.join(usable) or RENDER_VARIANT}")
    if not (args.outdir / "result.json").is_file():
        if not args.outdir.exists():
            raise FileNotFoundError(f"result directory '{args.outdir}' does not exist")
        raise FileNotFoundError(f"'{args.outdir}' holds no result.json: not a result directory "
                                "(write one with 'polarbssrdf reconstruct')")
    capture = truth_capture(args.outdir, args.truth)
    if args.out is not None:
        check_report_path(args.out, args.outdir, capture.directory)
    select_variant(args.variant)
    report = evaluate_result(args.outdir, capture, frame=args.frame, stage=args.stage,
                             spp=args.spp, variant=args.variant)
    text = json.dumps(report, indent=2) + "\n"
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, text, overwrite=True)
    sys.stdout.write(text)
    return 0
