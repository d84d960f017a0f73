"""The result format: ``result.json`` and per-stage, per-frame float32 EXR maps.

A result directory mirrors a capture's ``truth/``: maps are T x T float32
OpenEXR files whose channel names, texture convention and units are those of
the truth maps (``eta``, ``alpha_s``, ``alpha_ss``, ``rho_s``, ``rho_ss``,
``displacement``, ``rho_sss.<band>``; plus ``normal.x/y/z`` and
``confidence``), so :mod:`polarbssrdf.inverse.evaluation.scores` compares like with
like and every later stage reads the earlier ones from disk::

    OUTDIR/result.json            schema "polarbssrdf.result", version 1
    OUTDIR/static/maps_f0000.exr  the static stage's maps
    OUTDIR/<stage>/maps_f####.exr later stages, one file per frame

``result.json`` lists ``{frame, stage, path, channels}`` per map file and
is rewritten atomically each time a map is added, so it only ever lists
complete files. Its ``capture_identity``
(:func:`polarbssrdf.io.identity.capture_identity`) says which capture the maps
were fitted on, whatever its path: :func:`check_result_capture` refuses
another one.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import shutil
from pathlib import Path

from polarbssrdf.errors import CommandError, option
from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.exr import read_exr, write_exr
from polarbssrdf.io.identity import capture_identity, identity_differences
from polarbssrdf.io.jsonfile import read_json_file
from polarbssrdf.io.truth import DEFAULT_TRUTH_UNITS, TEXTURE_CONVENTION

RESULT_SCHEMA = "polarbssrdf.result"
RESULT_SCHEMA_VERSION = 1
RESULT_FILE = "result.json"
STAGES = ("static", "dynamic", "bio")
"""The stages whose maps a result holds, in the order they run (each reads the earlier ones)."""
METRICS_FILE = "metrics.json"
"""``OUTDIR/metrics.json``: the loss history of every stage (``{stage: history}``), and under
``confidence`` the confident share of the surface per polarimetric stage and frame."""
TIMINGS_FILE = "timings.json"
"""``OUTDIR/timings.json``: wall seconds of the last run of each stage."""
REPORT_FILE = "report.html"
"""``OUTDIR/report.html``: the report (``polarbssrdf report``), when one was written."""

RESULT_UNITS = dict(DEFAULT_TRUTH_UNITS, normal="1", confidence="1", specular_peak_angle="deg")
"""Units of result channels (the truth's, plus unit normals, the confidence in [0, 1] and the
specular peak angle in degrees)."""


def stage_map_path(stage, frame):
    """Relative path of a stage's map file: ``static/maps_f0000.exr``."""
    return f"{stage}/maps_f{int(frame):04d}.exr"


@dataclasses.dataclass
class ResultManifest:
    """Contents of ``result.json``."""

    capture: str
    texture_size: int
    units: dict
    maps: list = dataclasses.field(default_factory=list)
    settings: dict = dataclasses.field(default_factory=dict)
    texture_convention: str = TEXTURE_CONVENTION
    capture_identity: dict | None = None
    """:func:`polarbssrdf.io.identity.capture_identity` of the capture at the run's start
    (None in results written before it was recorded)."""

    def to_json(self):
        data = {"schema": RESULT_SCHEMA, "schema_version": RESULT_SCHEMA_VERSION,
                "capture": self.capture, "texture_size": self.texture_size,
                "texture_convention": self.texture_convention, "units": dict(self.units),
                "settings": self.settings, "maps": list(self.maps)}
        if self.capture_identity is not None:
            data["capture_identity"] = self.capture_identity
        return data

    @classmethod
    def from_json(cls, data, where):
        if not isinstance(data, dict) or data.get("schema") != RESULT_SCHEMA:
            raise ValueError(f"{where}: not a polarbssrdf result (schema {RESULT_SCHEMA!r} expected)")
        version = data.get("schema_version")
        if not isinstance(version, int) or version > RESULT_SCHEMA_VERSION:
            raise ValueError(f"{where}: schema_version {version!r} is not supported "
                             f"(this polarbssrdf reads up to {RESULT_SCHEMA_VERSION})")
        for key in ("capture", "texture_size", "units", "maps"):
            if key not in data:
                raise ValueError(f"{where}: missing key {key!r}")
        return cls(capture=data["capture"], texture_size=data["texture_size"],
                   units=data["units"], maps=list(data["maps"]),
                   settings=data.get("settings", {}),
                   texture_convention=data.get("texture_convention", TEXTURE_CONVENTION),
                   capture_identity=data.get("capture_identity"))

    def record(self, stage, frame):
        for record in self.maps:
            if record["stage"] == stage and record["frame"] == frame:
                return record
        return None


def read_result(outdir) -> ResultManifest:
    """The ``result.json`` of ``outdir`` (errors name the file)."""
    path = Path(outdir) / RESULT_FILE
    return ResultManifest.from_json(read_json_file(path, "result file"), str(path))


def write_result(outdir, manifest):
    """Write ``result.json`` atomically."""
    text = json.dumps(manifest.to_json(), indent=2) + "\n"
    atomic_write_text(Path(outdir) / RESULT_FILE, text, overwrite=True)


def record_settings(outdir, settings) -> None:
    """Replace the run settings in ``result.json`` (a resume that raised the epoch counts)."""
    manifest = read_result(outdir)
    manifest.settings = settings
    write_result(outdir, manifest)


def register_map(outdir, stage, frame, channels):
    """Add (or replace) the record of ``stage``/``frame`` in ``result.json``."""
    manifest = read_result(outdir)
    manifest.maps = [r for r in manifest.maps if not (r["stage"] == stage and r["frame"] == frame)]
    manifest.maps.append({"frame": int(frame), "stage": stage, "path": stage_map_path(stage, frame),
                          "channels": list(channels)})
    manifest.maps.sort(key=lambda r: (r["stage"], r["frame"]))
    write_result(outdir, manifest)


def write_stage_maps(outdir, stage, frame, channels, metadata=None):
    """Write a stage's maps of one frame (atomically) and register them; returns the path."""
    path = Path(outdir) / stage_map_path(stage, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"stage": stage, "frame": int(frame),
            "written": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    meta.update(metadata or {})
    write_exr(path, channels, metadata=meta, overwrite=True)
    register_map(outdir, stage, frame, channels)
    return path


def read_stage_maps(outdir, stage, frame):
    """Channel -> (T, T) float32 map of a registered stage/frame."""
    manifest = read_result(outdir)
    record = manifest.record(stage, frame)
    if record is None:
        have = sorted({r["stage"] for r in manifest.maps})
        raise FileNotFoundError(f"{Path(outdir) / RESULT_FILE}: no {stage!r} maps for frame "
                                f"{frame} (stages present: {', '.join(have) or 'none'})")
    channels, _ = read_exr(Path(outdir) / record["path"])
    return channels


def continue_result_directory(outdir, capture_directory, texture_size):
    """The :class:`ResultManifest` of an earlier run in ``outdir`` that later stages extend.

    The capture and texture size must be the run's (a later stage reads its maps).
    """
    outdir = Path(outdir)
    if not (outdir / RESULT_FILE).is_file():
        raise FileNotFoundError(f"{outdir} holds no {RESULT_FILE}: the stages asked for read "
                                f"an earlier stage's maps; include it in {option('stages')} "
                                f"(e.g. {option('stages', 'static,bio')})")
    manifest = read_result(outdir)
    differences = _settings_differences(manifest, str(Path(capture_directory).resolve()),
                                        texture_size, manifest.settings)
    if differences:
        raise ValueError(f"{outdir} holds a run of another capture or texture size "
                         f"({'; '.join(differences)}): later stages must read its own maps")
    return manifest


def prepare_result_directory(outdir, capture_directory, texture_size, settings, *, resume=False,
                             overwrite=False, identity=None):
    """Create ``outdir`` for a run, or check that it holds the same run for ``resume``.

    Refuses a non-empty directory unless ``resume`` (same capture and
    settings: the differing ones are named) or ``overwrite``; refuses to
    write inside the capture. A new ``result.json`` records ``identity``
    (:func:`polarbssrdf.io.identity.capture_identity`). Returns the
    :class:`ResultManifest`.
    """
    outdir = Path(outdir).resolve()
    capture_directory = Path(capture_directory).resolve()
    if outdir == capture_directory or capture_directory in outdir.parents:
        raise ValueError(f"output directory {outdir} is inside the capture {capture_directory}: "
                         "a run never writes into its input")
    existing = outdir.is_dir() and any(outdir.iterdir())
    manifest_path = outdir / RESULT_FILE
    if existing and resume:
        if not manifest_path.is_file():
            raise FileExistsError(f"{outdir} is not empty and holds no {RESULT_FILE}: it is not "
                                  "a reconstruction to resume")
        manifest = read_result(outdir)
        differences = _settings_differences(manifest, str(capture_directory), texture_size,
                                            settings)
        if differences:
            raise ValueError(f"{outdir} holds another run ({'; '.join(differences)}): rerun with "
                             f"its settings to resume, or use {option('overwrite', True)} to "
                             "start over")
        return manifest
    if existing and not overwrite:
        raise FileExistsError(f"{outdir} is not empty: use {option('resume', True)} to "
                              f"continue the run in it, or {option('overwrite', True)} to start "
                              "over")
    outdir.mkdir(parents=True, exist_ok=True)
    if existing and overwrite:
        _remove_run_files(outdir)
    units = dict(RESULT_UNITS)
    manifest = ResultManifest(capture=str(capture_directory), texture_size=int(texture_size),
                              units=units, settings=settings, capture_identity=identity)
    write_result(outdir, manifest)
    return manifest


def capture_differences(manifest: ResultManifest, capture) -> list[str]:
    """How ``capture`` differs from the one ``manifest``'s run was fitted on (empty: it is
    that capture, or the result predates recorded identities)."""
    recorded = manifest.capture_identity
    if not recorded:
        return []
    frame = recorded.get("frame", 0)
    if frame not in [f.index for f in capture.manifest.frames]:
        return [f"it has no frame {frame}, the frame whose images identify the result's capture"]
    return identity_differences(recorded, capture_identity(capture, frame))


def check_result_capture(outdir, capture, what, *, force=False) -> list[str]:
    """Refuse (:class:`CommandError`) unless ``capture`` is the result's capture.

    ``what`` names the capture for the message, e.g. ``"--truth 'face'"``. With
    ``force`` the differences are returned instead (the caller says it goes on).
    """
    manifest = read_result(outdir)
    differences = capture_differences(manifest, capture)
    if differences and not force:
        raise CommandError(f"{what} is not the capture the result in '{outdir}' was fitted on "
                           f"('{manifest.capture}'): {'; '.join(differences)}; pass --force to "
                           "use it anyway")
    return differences


def _settings_differences(manifest, capture, texture_size, settings):
    differences = []
    if manifest.capture != capture:
        differences.append(f"capture {manifest.capture} vs {capture}")
    if manifest.texture_size != texture_size:
        differences.append(f"texture {manifest.texture_size} vs {texture_size}")
    for key in sorted(set(manifest.settings) | set(settings)):
        old, new = manifest.settings.get(key), settings.get(key)
        if json.dumps(old, sort_keys=True) != json.dumps(new, sort_keys=True):
            differences.append(f"{key}: {json.dumps(old)} vs {json.dumps(new)}")
    return differences


OBSERVATIONS_DIR = "observations"
"""``OUTDIR/observations/f####.zarr``: the observation cache of each frame."""

RUN_ENTRIES = (RESULT_FILE, *STAGES, METRICS_FILE, TIMINGS_FILE, REPORT_FILE, OBSERVATIONS_DIR)
"""What a run writes in OUTDIR; ``--overwrite`` removes only these, the observation cache
too: starting over must not depend on the cache's fingerprint being right."""


def _remove_run_files(outdir):
    for name in RUN_ENTRIES:
        path = Path(outdir) / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            os.remove(path)


def write_metrics(outdir, stage, history):
    """Add a stage's loss history to ``OUTDIR/metrics.json`` (atomically)."""
    path = Path(outdir) / METRICS_FILE
    metrics = json.loads(path.read_text()) if path.is_file() else {}
    metrics[stage] = history
    atomic_write_text(path, json.dumps(metrics, indent=1) + "\n", overwrite=True)


def write_confidence(outdir, stage, summaries) -> None:
    """Record ``{frame: confidence summary}`` of a stage under ``confidence`` in
    ``OUTDIR/metrics.json`` (atomically): what share of the surface was measured."""
    path = Path(outdir) / METRICS_FILE
    metrics = json.loads(path.read_text()) if path.is_file() else {}
    metrics.setdefault("confidence", {})[stage] = {str(k): v for k, v in summaries.items()}
    atomic_write_text(path, json.dumps(metrics, indent=1) + "\n", overwrite=True)


def record_stage_seconds(outdir, seconds: dict) -> None:
    """Merge ``{stage: wall seconds}`` into ``OUTDIR/timings.json`` (atomically).

    The last run of a stage replaces its entry; a resumed stage records the
    seconds of the resumed part only. A stage a resume finds finished is not
    recorded (:func:`polarbssrdf.inverse.pipeline.reconstruct`): its entry stays
    the run's that did the work.
    """
    path = Path(outdir) / TIMINGS_FILE
    try:
        timings = json.loads(path.read_text())
    except (FileNotFoundError, ValueError):
        timings = {}
    timings.update({stage: round(float(value), 3) for stage, value in seconds.items()})
    atomic_write_text(path, json.dumps(timings, indent=1) + "\n", overwrite=True)


RESULT_OWNED_FILES = (RESULT_FILE, METRICS_FILE, TIMINGS_FILE, REPORT_FILE)
"""Files at the top of a result directory that belong to the run (``--out`` may not replace
them; the report may rewrite its own :data:`REPORT_FILE`)."""
RESULT_OWNED_DIRECTORIES = (*STAGES, OBSERVATIONS_DIR)
"""Directories of a result that hold only the run's files (maps, checkpoints, previews,
summaries, the observation cache): ``--out`` may not write anything inside them."""


def result_owned_reason(target: Path, outdir: Path, *, allowed=()) -> str | None:
    """Why the resolved path ``target`` belongs to the result in ``outdir`` (None: it does not).

    ``allowed`` names top-level files the caller may rewrite (the report its own page).
    """
    outdir = Path(outdir).resolve()
    owned_files = {outdir / name for name in RESULT_OWNED_FILES if name not in allowed}
    try:  # maps registered at any path, older results included
        owned_files |= {(outdir / record["path"]).resolve()
                        for record in read_result(outdir).maps}
    except (FileNotFoundError, ValueError):
        pass
    if target in owned_files:
        name = target.relative_to(outdir) if outdir in target.parents else target.name
        return f"it is the result's {name}"
    for name in RESULT_OWNED_DIRECTORIES:
        if outdir / name == target or outdir / name in target.parents:
            return (f"it is inside the result's {name}/ directory (its maps, checkpoints, "
                    "previews and caches)")
    return None


def check_report_path(out: Path, outdir: Path, capture_dir: Path | None, *, allowed=(),
                      protected=()) -> None:
    """``--out`` must not replace an input: a file the result owns, anything in the capture.

    A result owns ``result.json``, ``metrics.json``, ``timings.json``, ``report.html``
    (unless named in ``allowed``) and everything under its stage directories and
    observation cache (maps, checkpoints, previews, summaries); ``protected`` adds files
    (e.g. a demo directory's own). Raises :class:`CommandError`, one line.
    """
    out, outdir = Path(out), Path(outdir)
    target = out.resolve()
    if out.exists() and out.is_dir():
        raise CommandError(f"--out '{out}' is a directory; give a file name, e.g. "
                           f"{out / 'evaluation.json'}")
    reason = result_owned_reason(target, outdir, allowed=allowed)
    if reason is None and target in {Path(p).resolve() for p in protected}:
        reason = f"it is {Path(out).name} of the directory being reported"
    if reason is not None:
        raise CommandError(f"--out '{out}' would overwrite a file of the result in '{outdir}' "
                           f"({reason}); choose another file name")
    if capture_dir is not None:
        capture_dir = Path(capture_dir).resolve()
        if target == capture_dir or capture_dir in target.parents:
            raise CommandError(f"--out '{out}' is inside the capture {capture_dir}: polarbssrdf "
                               "never writes into its inputs")


class ResultDirectory:
    """A result directory read from Python: maps as NumPy arrays, loss histories, timings.

    ``ResultDirectory(outdir)`` reads ``result.json`` (a clear error when
    ``outdir`` holds none); map files are read when asked for, never cached,
    so a long sequence costs one frame's memory at a time.

    Parameters
    ----------
    outdir : path
        A directory written by ``polarbssrdf reconstruct`` or
        :func:`polarbssrdf.inverse.reconstruct`.
    """

    def __init__(self, outdir):
        self.path = Path(outdir)
        if not (self.path / RESULT_FILE).is_file():
            if not self.path.exists():
                raise FileNotFoundError(f"result directory '{self.path}' does not exist")
            raise FileNotFoundError(f"'{self.path}' holds no {RESULT_FILE}: not a result "
                                    "directory (write one with 'polarbssrdf reconstruct')")

    @property
    def manifest(self) -> ResultManifest:
        """``result.json`` as it is on disk now."""
        return read_result(self.path)

    @property
    def stages(self) -> list:
        """The stages with registered maps, in the order they run."""
        present = {record["stage"] for record in self.manifest.maps}
        return [s for s in STAGES if s in present] + sorted(present - set(STAGES))

    def frames(self, stage) -> list:
        """The frames of ``stage`` with registered maps, sorted."""
        return sorted(int(r["frame"]) for r in self.manifest.maps if r["stage"] == stage)

    def maps(self, stage="static", frame=None) -> dict:
        """``channel -> (T, T) float32`` of ``stage`` at ``frame`` (default: its first frame)."""
        if frame is None:
            frames = self.frames(stage)
            if not frames:
                return read_stage_maps(self.path, stage, 0)  # the error that names the stages
            frame = frames[0]
        return read_stage_maps(self.path, stage, int(frame))

    @property
    def metrics(self) -> dict:
        """``metrics.json``: the loss history of every stage that ran."""
        return _json_or_empty(self.path / METRICS_FILE)

    @property
    def timings(self) -> dict:
        """``timings.json``: wall seconds of the last run of each stage."""
        return _json_or_empty(self.path / TIMINGS_FILE)

    def __repr__(self):
        return f"{type(self).__name__}({str(self.path)!r})"


def _json_or_empty(path):
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return {}
