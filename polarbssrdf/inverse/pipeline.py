"""The acquisition as one call: a capture in, a result directory out (what ``reconstruct`` runs).

:func:`reconstruct` checks its inputs before any work, prepares (or resumes)
the result directory, and runs the stages in their order, each reading the
previous one's maps from disk:

    capture -> observations -> static (sec. 5.1) -> dynamic (sec. 5.2, per frame)
            -> biophysical (sec. 5.3, per frame) -> the result directory

It records each stage's wall time in ``OUTDIR/timings.json`` and returns a
:class:`Reconstruction`, which reads the maps back as NumPy arrays.
:func:`evaluate` scores a result against a synthetic capture's truth and
re-renders its held-out cameras (what ``evaluate`` prints). The ``reconstruct``
and ``evaluate`` commands (:mod:`polarbssrdf.inverse.commands`) and ``demo``
call these functions; a Python script can do the same::

    from polarbssrdf.inverse import evaluate, reconstruct

    result = reconstruct("capture", "result", stages=("static",), config={"iterations": 20},
                         holdout=("cam03",))
    eta = result.maps("static", 0)["eta"]          # (T, T) float32
    scores = evaluate("result")                     # the JSON ``evaluate`` prints, as a dict
"""

from __future__ import annotations

import json
import numbers
import sys
import time
from pathlib import Path

import mitsuba as mi

from polarbssrdf.errors import CommandError, option
from polarbssrdf.inverse.biophysical.model import PARAMETERS as BIO_PARAMETERS
from polarbssrdf.inverse.biophysical.stage import run_bio_stage
from polarbssrdf.inverse.config import DEFAULT_TEXTURE, run_config
from polarbssrdf.inverse.evaluation.rerender import DEFAULT_SPP
from polarbssrdf.inverse.evaluation.scores import evaluate_result, truth_capture
from polarbssrdf.inverse.evaluation.trust import (
    PRIOR_DOMINATED_VARIANCE,
    bio_map_notes,
    unmeasured_summary,
    untrusted_text,
    views_check,
)
from polarbssrdf.inverse.frames import check_scheduler
from polarbssrdf.inverse.polarimetric.dynamic import run_dynamic_stage, static_frame_of
from polarbssrdf.inverse.polarimetric.config import DEFAULT_DYNAMIC_ITERATIONS
from polarbssrdf.inverse.polarimetric.fit import LOW_CONFIDENT_FRACTION
from polarbssrdf.inverse.resources import check_memory
from polarbssrdf.inverse.polarimetric.static import run_static_stage
from polarbssrdf.inverse.results.directory import (
    METRICS_FILE,
    RESULT_FILE,
    STAGES,
    ResultDirectory,
    capture_differences,
    check_report_path,
    check_result_capture,
    continue_result_directory,
    prepare_result_directory,
    read_result,
    read_stage_maps,
    record_settings,
    stage_map_path,
    record_stage_seconds,
    write_metrics,
)
from polarbssrdf.io import load_capture
from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.capture import json_differences
from polarbssrdf.io.exr import read_exr
from polarbssrdf.io.identity import capture_identity
from polarbssrdf.variants import (
    DEFAULT_VARIANT,
    check_variant,
    jit_mono_polarized_variants,
    select_variant,
)

STAGE_TITLES = {
    "static": "polarimetric inverse rendering of the static frame (eq. 26-35)",
    "dynamic": "every other frame, from the static maps (eq. 36-39)",
    "bio": "melanin and hemoglobin per frame (eq. 40-47)",
}
"""What each stage does, for its header line on the progress display."""


class Reconstruction(ResultDirectory):
    """What :func:`reconstruct` returns: the result directory, and what this run did.

    Besides :class:`~polarbssrdf.inverse.results.directory.ResultDirectory`'s
    readers (``.maps(stage, frame)``, ``.metrics``, ``.timings``), it has
    ``capture`` (the capture directory), ``texture`` (T), ``frame`` (the static
    frame), ``holdout``, ``seconds`` (wall time of the call), ``stage_lines``
    (one line per stage that ran, as ``reconstruct`` prints them), ``failed``
    (``{frame: reason}`` of frames that did not finish; the others are written),
    ``reused`` (the stages a resume found finished: ``timings.json`` keeps their earlier
    seconds) and ``views_check`` (:func:`~polarbssrdf.inverse.evaluation.trust.views_check`
    of the static frame, with ``frame``; ``trusted`` False when the maps and the std
    cannot be trusted; None when neither the static nor the bio stage ran).
    """

    def __init__(self, outdir, *, capture, texture, frame, holdout, seconds, stage_lines,
                 failed, reused=(), views_check=None):
        super().__init__(outdir)
        self.capture, self.texture, self.frame = capture, texture, frame
        self.holdout, self.seconds = list(holdout), seconds
        self.stage_lines, self.failed = list(stage_lines), dict(failed)
        self.reused = list(reused)
        self.views_check = views_check

    def summary(self, closing=None) -> str:
        """The lines ``reconstruct`` prints when it finishes; ``closing`` replaces the last one
        (``polarbssrdf.inverse.commands.closing_line``: the next command that applies)."""
        held = f"; held out {', '.join(self.holdout)}" if self.holdout else ""
        lines = [f"polarbssrdf reconstruct: {self.capture} -> {self.path} ({self.texture} x "
                 f"{self.texture} texels, static frame {self.frame}{held}) in {self.seconds:.1f} s"]
        lines += self.stage_lines
        lines.append(closing if closing is not None else
                     f"  result.json, metrics.json and previews in {self.path}; score it with "
                     f"'polarbssrdf evaluate {self.path}'")
        return "\n".join(lines)


def name_list(value, parameter: str) -> list[str]:
    """Names from a string (``"static,bio"``, ``"cam03"``: comma-separated, as on the command
    line) or a sequence of strings; order kept, duplicates and blank items dropped.

    A string is never split into its letters; anything else is a :class:`CommandError`
    naming ``parameter``.
    """
    items = value.split(",") if isinstance(value, str) else value
    try:
        items = list(items)
    except TypeError:
        items = None
    if items is None or not all(isinstance(item, str) for item in items):
        raise CommandError(f"{option(parameter)} must be a string of comma-separated names or "
                           f"a sequence of strings, got {value!r}")
    return list(dict.fromkeys(item.strip() for item in items if item.strip()))


def stage_list(stages) -> list[str]:
    """``stages`` (a string ``"static,bio"`` or names, any order, duplicates allowed) in run
    order; unknown names are a :class:`CommandError` that lists the known ones."""
    names = name_list(stages, "stages")
    if not names:
        raise CommandError(f"{option('stages')} is empty; known stages: {', '.join(STAGES)}")
    unknown = [name for name in names if name not in STAGES]
    if unknown:
        raise CommandError(f"unknown stage{'s' if len(unknown) > 1 else ''} "
                           f"{', '.join(repr(n) for n in unknown)} in {option('stages')}; known "
                           f"stages: {', '.join(STAGES)}")
    return [stage for stage in STAGES if stage in names]


RUN_NUMBERS = {"texture": 8, "frame": 0, "iterations": 0, "workers": 1}
"""The integer settings of :func:`reconstruct` and their least values (the command line's
``integer_at_least``), checked before anything is written."""


def check_run_numbers(**values) -> None:
    """Each given value (None: the default) is an integer at least :data:`RUN_NUMBERS`'s; a
    :class:`CommandError` naming the parameter otherwise (e.g. ``texture=32.5``)."""
    for name, value in values.items():
        if value is None:
            continue
        least = RUN_NUMBERS[name]
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
            raise CommandError(f"{option(name)} must be an integer >= {least}, got {value!r}")


def load_input_capture(path: Path, frame: int | None = None):
    """The capture of ``CAPTURE`` (manifests only), with a one-line error for each problem.

    With ``frame``, only that frame's image files must exist: the dynamic stage
    checks every other frame when it starts it, so a missing image fails only its frame.
    """
    path = Path(path)
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
        raise CommandError(f"{option('holdout')} names unknown camera{'s' if len(unknown) > 1 else ''} "
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
        raise CommandError(f"{option('holdout')} camera{'s' if len(without) > 1 else ''} "
                           f"{', '.join(without)} took no polarization image in frame {frame}: "
                           "nothing to validate against")
    if seen <= set(holdout):
        raise CommandError(f"{option('holdout')} leaves out every camera of frame {frame} "
                           f"({', '.join(sorted(seen))}): nothing left to fit")


def static_frame(outdir: Path, frame: int | None, continuing: bool) -> int:
    """The run's static frame: ``frame`` (default 0) when this run fits the static stage; the
    one the earlier run fitted when later stages add to it (``frame`` None or that frame).

    The dynamic stage starts from the static frame's maps and fits every other frame; a
    continuing run with another ``frame`` is refused here, before any work.
    """
    if not continuing or not (Path(outdir) / RESULT_FILE).is_file():
        return 0 if frame is None else int(frame)
    try:
        fitted = static_frame_of(outdir)
    except FileNotFoundError:  # no static maps: the stage's own error says so, later
        return 0 if frame is None else int(frame)
    if frame is not None and int(frame) != fitted:
        raise CommandError(f"the run in '{outdir}' fitted static frame {fitted}, and the later "
                           f"stages start from its maps: {option('frame', frame)} would need "
                           f"another static fit; drop {option('frame')} (or pass "
                           f"{option('frame', fitted)}), or fit the static stage with "
                           f"{option('frame', frame)} into a new directory")
    return fitted


def check_stage_needs(capture, stages) -> None:
    """Refuse (:class:`CommandError`) a requested stage the capture cannot feed, before the
    first stage starts: not after the static and dynamic stages' minutes.

    The biophysical stage fits its parameters (C_m, beta_m, C_h_out, C_h_in) per texel
    from the subsurface albedo of every band: it needs at least as many bands.
    """
    bands = list(capture.manifest.band_names)
    if "bio" in stages and len(bands) < len(BIO_PARAMETERS):
        others = ",".join(stage for stage in stages if stage != "bio")
        advice = (f"drop 'bio' from {option('stages')} (e.g. {option('stages', others)})"
                  if others
                  else "fit it on a capture with more bands")
        raise CommandError(f"capture '{capture.directory}' has {len(bands)} band"
                           f"{'s' if len(bands) != 1 else ''} ({', '.join(bands)}): the 'bio' "
                           f"stage fits {len(BIO_PARAMETERS)} parameters "
                           f"({', '.join(BIO_PARAMETERS)}) from them and needs at least "
                           f"{len(BIO_PARAMETERS)}; {advice}")


def run_settings(stages, config, holdout, frame) -> dict:
    """What defines a run besides the capture and texture size (``result.json`` settings)."""
    return {"stages": list(stages), "frame": int(frame), "holdout": sorted(holdout),
            "config": config.to_json()}


def _short(value, limit=60) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


EXTENDABLE_EPOCHS = {"config.iterations": None,
                     "config.dynamic.iterations": DEFAULT_DYNAMIC_ITERATIONS}
"""Settings a resumed run may raise: the epochs of the static stage and of each dynamic
frame (each fit continues from its last checkpoint; the checkpoints' fingerprints leave
them out). The value is the default of a setting a config may omit."""


def _setting_pairs(old_settings: dict, new_settings: dict) -> list:
    """``(path, first run's value, this run's value)`` of every differing setting; the
    config key by key, lists (stages, holdout) whole."""
    old = json.loads(json.dumps(old_settings))
    new = json.loads(json.dumps(new_settings))
    pairs = []
    for key in list(old) + [k for k in new if k not in old]:
        before, after = old.get(key, "<absent>"), new.get(key, "<absent>")
        if isinstance(before, dict) and isinstance(after, dict):
            pairs += json_differences(before, after, key)  # config: key by key
        elif before != after:
            pairs.append((key, before, after))
    return pairs


def _added_epochs(path: str, before, after) -> bool | None:
    """For an epoch count (:data:`EXTENDABLE_EPOCHS`): whether ``after`` adds epochs to
    ``before`` (True), keeps them (never reported) or removes some (False); None for
    any other setting."""
    if path not in EXTENDABLE_EPOCHS:
        return None
    default = EXTENDABLE_EPOCHS[path]
    before = default if before == "<absent>" else before
    after = default if after == "<absent>" else after
    if not (isinstance(before, int) and isinstance(after, int)):
        return None
    return after >= before


def epochs_added(old_settings: dict, new_settings: dict) -> bool:
    """Whether ``new_settings`` differ from a run's only by more epochs (a resume that
    continues each fit)."""
    pairs = _setting_pairs(old_settings, new_settings)
    return bool(pairs) and all(_added_epochs(*pair) for pair in pairs)


def resume_differences(outdir: Path, capture, texture: int, settings: dict) -> list:
    """Settings of the run in ``outdir`` that differ from this one, as readable strings.

    Nested settings (the config) are compared key by key, so the message names
    e.g. ``config.iterations`` rather than the whole config; a capture at the
    same path whose contents changed is named too. More epochs
    (:data:`EXTENDABLE_EPOCHS`) alone are no difference: the resume continues each fit;
    fewer are one, and so are more when something else differs as well (all is named).
    """
    if not (outdir / RESULT_FILE).is_file():
        return []
    manifest = read_result(outdir)
    differences = []
    capture_dir = Path(capture.directory)
    if Path(manifest.capture) != capture_dir.resolve():
        differences.append(f"capture: {manifest.capture} (first run) vs {capture_dir.resolve()} "
                           "(now)")
    else:
        differences += [f"capture contents: {text}"
                        for text in capture_differences(manifest, capture)]
    if manifest.texture_size != texture:
        differences.append(f"{option('texture')}: {manifest.texture_size} (first run) vs "
                           f"{texture} (now)")
    names = {name: option(name) for name in ("stages", "frame", "holdout")}
    names.update({"config.iterations": f"config.iterations ({option('iterations')})"})
    pairs = _setting_pairs(manifest.settings, settings)
    blocking = [pair for pair in pairs if _added_epochs(*pair) is not True]
    for path, before, after in (pairs if (blocking or differences) else []):
        text = f"{names.get(path, path)}: {_short(before)} (first run) vs {_short(after)} (now)"
        if _added_epochs(path, before, after) is False:
            text += " (a resume can add epochs, not remove them)"
        differences.append(text)
    return differences


def _texel_views(path: Path) -> int | None:
    try:
        _, metadata = read_exr(path)
    except (OSError, ValueError):
        return None
    value = (metadata or {}).get("texel_views")
    return int(value) if isinstance(value, (int, float)) else None


def say_confidence(stage, summaries, progress=True) -> None:
    """Say on stderr what share of the surface ``stage`` measured (``{frame: summary}`` of
    :func:`~polarbssrdf.inverse.polarimetric.fit.confidence_summary`): one line with the
    progress display, and always a warning per frame below
    :data:`~polarbssrdf.inverse.polarimetric.fit.LOW_CONFIDENT_FRACTION`."""
    if not summaries:
        return
    fractions = [100 * s["confident_fraction"] for s in summaries.values()]
    if progress:
        low, high = f"{min(fractions):.1f}", f"{max(fractions):.1f}"
        share = (f"{high}%" if len(fractions) == 1 else
                 f"{high}% (every one of {len(fractions)} frames)" if low == high else
                 f"{low}-{high}% (over {len(fractions)} frames)")
        print(f"polarbssrdf reconstruct: {stage}: {share} of the surface is confident "
              "(metrics.json: confidence)", file=sys.stderr, flush=True)
    for frame, summary in sorted(summaries.items(), key=lambda item: int(item[0])):
        if summary["confident_fraction"] < LOW_CONFIDENT_FRACTION:
            print(f"polarbssrdf reconstruct: warning: {stage}, frame {frame}: only "
                  f"{100 * summary['confident_fraction']:.1f}% of the surface "
                  f"({summary['confident_texels']:,} of {summary['surface_texels']:,} texels) "
                  f"is confident (below {100 * LOW_CONFIDENT_FRACTION:.0f}%): the rest of its "
                  "maps is filled in from neighbours, not measured; cameras that cover more "
                  "of the object raise it", file=sys.stderr, flush=True)


def unmeasured_text(outdir, frames) -> str:
    """The end of the bio stage's line: the chromophore maps of the first and last of
    ``frames`` held at their face mean or prior-dominated (:func:`~polarbssrdf.inverse
    .evaluation.trust.bio_map_notes`; the frames the report shows, and two files read
    however long the sequence), "" when every fitted map is measured. A later frame
    holding the first frame's melanin is the stage's design and not repeated here."""
    notes = {}
    frames = sorted(int(f) for f in frames)
    for frame in sorted({frames[0], frames[-1]}) if frames else []:
        try:
            notes[frame] = bio_map_notes(*read_exr(Path(outdir) / stage_map_path("bio",
                                                                                 int(frame))))
        except (OSError, ValueError):  # a frame that failed: its own line says so
            continue
    said = unmeasured_summary(notes)
    return (f"; not measured by the bands (posterior std above "
            f"{PRIOR_DOMINATED_VARIANCE ** 0.5:.2f} of the prior spread, or held): {said}"
            if said else "")


def warn_if_untrusted(outdir, frame) -> dict | None:
    """Warn on stderr (also with ``--quiet``) when the static frame's maps, and the
    biophysical std if the run has one, cannot be trusted: too few usable views per
    confident texel (:func:`~polarbssrdf.inverse.evaluation.trust.views_check`). Records
    the check, with the frame, under ``views`` in ``OUTDIR/metrics.json`` and returns it
    (None without static maps or confident texels)."""
    outdir = Path(outdir)
    try:
        maps = read_stage_maps(outdir, "static", int(frame))
        manifest = read_result(outdir)
    except (OSError, ValueError):  # no static maps (a failed stage said why)
        return None
    if "confidence" not in maps:
        return None
    check = views_check(maps["confidence"])  # confidence is 0 off the mesh
    if check is None:
        return None
    check = {"frame": int(frame), **check}
    write_metrics(outdir, "views", check)  # for scripts: metrics.json says it too
    if check["trusted"]:
        return check
    has_std = manifest.record("bio", int(frame)) is not None
    print(f"polarbssrdf reconstruct: warning: static frame {frame}: "
          f"{untrusted_text(check, has_std)}", file=sys.stderr, flush=True)
    return check


def reconstruct(capture, outdir, stages=STAGES, config=None, holdout=(), *, texture=None,
                frame=None, iterations=None, workers=None, scheduler=None, resume=False,
                overwrite=False, progress=True, variant=DEFAULT_VARIANT) -> Reconstruction:
    """Run the acquisition stages on ``capture`` into the result directory ``outdir``.

    Parameters
    ----------
    capture : path
        Capture directory (``capture.json``, images, mesh; docs/capture_format.md).
        Never written to.
    outdir : path
        Result directory: new or empty; an earlier run with ``resume`` (continue it,
        same settings) or ``overwrite`` (start over). Stages without ``"static"``
        add to an earlier run of the same capture and texture size.
    stages : str or sequence of str
        Any of ``"static"``, ``"dynamic"``, ``"bio"``, as a sequence or a comma-separated
        string (``"static"``, ``"static,dynamic"``); run in that order.
    config : None, StaticConfig, dict or path
        The run's settings (docs/reconstruct.md); None: the paper's.
    holdout : str or sequence of str
        Cameras left out of the fit, for held-out re-renders (:func:`evaluate`): a sequence
        or a comma-separated string (``"cam03"``).
    texture : int, optional
        Maps are T x T texels; default the capture's truth size, else
        :data:`DEFAULT_TEXTURE`.
    frame : int, optional
        The static frame: the static stage fits it (default 0); the dynamic stage starts
        from its maps and fits every other frame. Stages without ``"static"`` use the
        earlier run's static frame (another ``frame`` is refused).
    iterations : int, optional
        Epochs of the static stage and of each dynamic frame (as ``--iterations``).
    workers, scheduler : optional
        Run the dynamic and biophysical frames on a local Dask cluster of
        ``workers`` single-threaded processes, or on the Dask scheduler at
        ``scheduler`` (e.g. ``"tcp://10.0.0.1:8786"``); default: in this process.
    resume, overwrite : bool
        See ``outdir``.
    progress : bool
        Stage headers and progress bars on stderr.
    variant : str
        A JIT autodiff polarized Mitsuba variant (``cuda_ad_mono_polarized`` on a GPU).

    Every argument is checked before anything is written; errors name these parameters
    (on the command line, its options).

    Returns
    -------
    Reconstruction
        Reads the maps (``.maps(stage, frame)``), loss histories (``.metrics``)
        and stage times (``.timings``); ``.failed`` lists frames that did not finish.
    """
    started = time.perf_counter()
    stages = stage_list(stages)
    holdout = name_list(holdout, "holdout")
    check_run_numbers(texture=texture, frame=frame, iterations=iterations, workers=workers)
    check_variant(variant, mi.variants())
    config = run_config(config, iterations)
    # later stages on an earlier run read its maps and add their own (no resume needed)
    continuing = stages[0] != STAGES[0]
    frame = static_frame(Path(outdir), frame, continuing)
    capture = load_input_capture(capture, frame)
    check_frame_and_holdout(capture, frame, holdout)
    check_stage_needs(capture, stages)
    if texture is None:
        texture = (int(capture.truth.texture_size) if capture.truth is not None
                   else DEFAULT_TEXTURE)
    views = sum(r.kind in ("analyser", "raw") and r.camera not in holdout
                for r in capture.manifest.frame(frame).images)
    check_memory(texture, len(capture.manifest.bands), views, stages)  # before any writing
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise CommandError(f"output directory '{outdir}' exists and is not a directory")
    settings = run_settings(stages, config, holdout, frame)
    if overwrite and stages[0] != STAGES[0]:
        # overwriting removes the static maps, which these stages would then read
        raise CommandError(f"{option('overwrite', True)} with {option('stages', ','.join(stages))} "
                           "would remove the static maps those stages read; include 'static' in "
                           f"{option('stages')} to start over, or drop {option('overwrite')} "
                           f"to add to the run in '{outdir}'")
    extended = False  # a resume with more epochs: each fit continues, later stages redo
    if resume and not continuing and outdir.is_dir() and any(outdir.iterdir()):
        differences = resume_differences(outdir, capture, texture, settings)
        if differences:
            raise CommandError(f"cannot resume in '{outdir}': it holds a run with other settings "
                               f"({'; '.join(differences)}); rerun with its settings to continue "
                               f"it, or pass {option('overwrite', True)} instead of "
                               f"{option('resume', True)} to start over")
        extended = ((outdir / RESULT_FILE).is_file()
                    and epochs_added(read_result(outdir).settings, settings))
    if scheduler is not None and set(stages) & {"dynamic", "bio"}:
        check_scheduler(scheduler)  # before any stage: not after the static stage's minutes
    select_variant(variant)
    if continuing:
        continue_result_directory(outdir, capture.directory, texture)
        check_result_capture(outdir, capture, f"capture '{capture.directory}'")
    else:
        if extended:  # every check passed: the run now goes to the larger epoch counts
            record_settings(outdir, settings)
        prepare_result_directory(outdir, capture.directory, texture, settings, resume=resume,
                                 overwrite=overwrite, identity=capture_identity(capture, frame))

    lines, failed, reused = [], {}, []
    for number, stage in enumerate(stages, start=1):
        # one display across stages: each stage's header and bars carry "[i/n] stage"
        label = f"[{number}/{len(stages)}] {stage}"
        if progress:
            print(f"polarbssrdf reconstruct: {label}: {STAGE_TITLES[stage]}", file=sys.stderr,
                  flush=True)
        stage_start = time.perf_counter()
        if stage == "static":
            if resume and _static_fit_done(outdir, frame, config.iterations):
                reused.append(stage)
            result = run_static_stage(capture, outdir, config, texture, frame=frame,
                                      holdout=tuple(holdout), progress=progress, label=label)
            say_confidence(stage, {frame: result.confidence}, progress)
            views = _texel_views(result.path)
            epochs = len(result.history)
            final = result.history[-1].get("total") if result.history else None
            lines.append(f"  static: {result.path} ({len(result.maps)} channels, {epochs} "
                         f"epochs, {'?' if views is None else f'{views:,}'} texel-views"
                         + (f", final loss {final:.4g}" if final is not None else "")
                         + f", {_seconds_text(stage, reused, stage_start)})")
        elif stage == "dynamic":
            report = run_dynamic_stage(capture, outdir, texture, config, holdout=tuple(holdout),
                                       static_frame=frame, workers=workers, scheduler=scheduler,
                                       resume=(resume or continuing) and not extended,
                                       progress=progress,
                                       variant=variant, label=label)
            failed.update(report["failed"])
            if report["skipped"] and not report["done"] and not report["failed"]:
                reused.append(stage)
            say_confidence(stage, report["confidence"], progress)
            lines.append(f"  dynamic: {len(report['done'])} frame(s) fitted"
                         + (f", {len(report['skipped'])} already done" if report["skipped"] else "")
                         + (f", {len(report['failed'])} failed" if report["failed"] else "")
                         + f" -> {outdir / 'dynamic'} ({_seconds_text(stage, reused, stage_start)})")
        elif stage == "bio":
            # after more epochs its albedo maps changed: every frame is fitted again
            bio_resume = (resume or continuing) and not extended
            written = _bio_frames_written(outdir) if bio_resume else set()
            summary = run_bio_stage(capture, outdir, texture, config.bio,
                                    resume=bio_resume, progress=progress,
                                    workers=workers, scheduler=scheduler, variant=variant,
                                    label=label)
            failed.update({f: f"bio: {reason}" for f, reason in summary["failed"].items()})
            if summary["frames"] and set(summary["frames"]) <= written and not summary["failed"]:
                reused.append(stage)
            kinds = sorted(set(summary["source_stages"].values()))
            lines.append(f"  bio: {len(summary['frames'])} frame(s) from the "
                         f"{' and '.join(kinds)} maps -> {outdir / 'bio'} (maps, previews, "
                         f"summary.json; {_seconds_text(stage, reused, stage_start)})"
                         + unmeasured_text(outdir, summary["frames"]))
        if stage not in reused:  # timings.json keeps the seconds of the run that did the work
            record_stage_seconds(outdir, {stage: time.perf_counter() - stage_start})
    views = warn_if_untrusted(outdir, frame) if {"static", "bio"} & set(stages) else None
    return Reconstruction(outdir, capture=capture.directory, texture=texture, frame=frame,
                          holdout=holdout, seconds=time.perf_counter() - started,
                          stage_lines=lines, failed=failed, reused=reused, views_check=views)


def _static_fit_done(outdir: Path, frame: int, iterations: int) -> bool:
    """Whether an earlier run in ``outdir`` finished the static fit of ``frame`` to
    ``iterations`` epochs (its maps registered, its loss history that long): a resume then
    reuses it."""
    try:
        if read_result(outdir).record("static", frame) is None:
            return False
        history = json.loads((outdir / METRICS_FILE).read_text()).get("static", [])
    except (OSError, ValueError):
        return False
    return isinstance(history, list) and len(history) >= iterations


def _bio_frames_written(outdir: Path) -> set:
    """Frames whose biophysical map file exists (a resume skips them)."""
    return {int(path.stem.removeprefix("maps_f")) for path in (outdir / "bio").glob("maps_f*.exr")
            if path.stem.removeprefix("maps_f").isdigit()}


def _seconds_text(stage, reused, stage_start) -> str:
    """``12.3 s``, or for a stage whose work an earlier run did, where its time is kept."""
    seconds = f"{time.perf_counter() - stage_start:.1f} s"
    if stage in reused:
        return f"{seconds}; reused the earlier run's fit, whose time timings.json keeps"
    return seconds


def evaluate_inputs(outdir, truth=None, variant=DEFAULT_VARIANT, force=False):
    """Check :func:`evaluate`'s inputs before any work; returns the capture with the truth.

    The capture must be the one the result was fitted on (``result.json``'s
    ``capture_identity``), unless ``force``: then a line on stderr says how it differs.
    """
    if not variant.endswith("mono_polarized") or variant not in mi.variants():
        usable = jit_mono_polarized_variants(mi.variants())
        raise CommandError(f"--variant {variant!r}: held-out views are re-rendered per band "
                           f"in an available JIT mono polarized variant; use one of: "
                           f"{', '.join(usable) or DEFAULT_VARIANT}")
    ResultDirectory(outdir)  # the clear error when outdir is not a result
    capture = truth_capture(Path(outdir), truth)
    what = (f"the capture '{capture.directory}' recorded in result.json" if truth is None
            else f"--truth '{capture.directory}'")
    differences = check_result_capture(outdir, capture, what, force=force)
    if differences:
        print(f"polarbssrdf evaluate: warning: {what} is not the result's capture "
              f"({'; '.join(differences)}); scoring it anyway (--force)", file=sys.stderr)
    return capture


def evaluate(outdir, truth=None, *, frame=0, stage="static", spp=DEFAULT_SPP,
             variant=DEFAULT_VARIANT, force=False, out=None) -> dict:
    """Score a result's maps against a synthetic capture's ground truth (what ``evaluate``
    prints).

    Parameters
    ----------
    outdir : path
        A result directory.
    truth : path or Capture, optional
        The capture with ground truth; default the one ``result.json`` records.
    frame : int
        The frame to score.
    stage : str
        Whose maps: ``"static"``, ``"dynamic"`` or ``"bio"``.
    spp : int
        Samples per pixel of the held-out re-renders.
    variant : str
        A JIT mono polarized Mitsuba variant for the re-renders.
    force : bool
        Score against a capture that is not the result's (``result.json``
        records the identity of the capture it was fitted on; another one is
        refused with what differs).
    out : path, optional
        Also write the JSON there (atomically); it may not replace one of the
        result's files or lie inside the capture (checked before any work).

    Returns
    -------
    dict
        MAE, relative errors and normal angles next to the best constant map's,
        and the held-out re-render errors (docs/reconstruct.md).
    """
    capture = evaluate_inputs(outdir, truth, variant, force)
    if out is not None:
        check_report_path(out, outdir, capture.directory)
    select_variant(variant)
    scores = evaluate_result(Path(outdir), capture, frame=frame, stage=stage, spp=spp,
                             variant=variant)
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out, json.dumps(scores, indent=2) + "\n", overwrite=True)
    return scores
