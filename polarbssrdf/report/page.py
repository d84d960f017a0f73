"""The HTML report of a result directory (``polarbssrdf report OUTDIR``, :mod:`.commands`).

:func:`write_report` turns a result directory (``polarbssrdf reconstruct``)
into one self-contained HTML file: every figure is a PNG inlined as a
``data:`` URI, so the file can be mailed or archived alone. The figures
(:mod:`polarbssrdf.report.figures`, matplotlib) are:

* the capture's input views, I0 and I90 of one band;
* each static map next to its truth and its error map, with colour bars and units;
* the normal map, the truth's, and the angle between them;
* the dynamic frames' change of subsurface albedo against the first frame;
* the biophysical maps of the first and last frame (each chromophore beside its
  posterior std and, with truth, its error over std; a map the bands did not
  measure says so), their region means over time with the truth, the
  calibration of the std against k, and the region summary in the layout of the
  supplement's Table 2 (its +- is the spatial std, said above it);
* a view re-rendered with the recovered maps beside the capture
  (:mod:`polarbssrdf.inverse.evaluation.rerender`), the held-out camera if the run held one out;
* the loss curves of every stage, and the metrics table
  (:func:`polarbssrdf.inverse.evaluation.scores.evaluate_stages`).

Without ground truth (a real capture) the report shows the recovered maps,
the loss curves and the re-rendering residuals only. At the top, the page says
when most of the surface is unconfident, and when the confident texels had too
few views for the maps and their std to be trusted
(:mod:`polarbssrdf.inverse.evaluation.trust`).

A small script at the end of the page marks images that failed to decode
(``<body data-images-broken>``) and records how many images the page's grids hold and in
how many rows they sit (``data-grid-images``, ``data-grid-rows``), which the browser tests
read.
"""

from __future__ import annotations

import base64
import datetime
import html
import json
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarbssrdf.errors import CommandError
from polarbssrdf.geometry import texel_atlas, to_mitsuba
from polarbssrdf.geometry.height import normals_from_height
from polarbssrdf.inverse.biophysical.model import PARAMETERS as BIO_PARAMETERS
from polarbssrdf.inverse.biophysical.stage import UNITS, region_masks, region_summary
from polarbssrdf.inverse.evaluation.rerender import captured_view, render_view, separation_errors
from polarbssrdf.inverse.evaluation.scores import (
    COVERAGE_IDEAL,
    LOSES,
    evaluate_stages,
    loses_to_constant,
    losing_maps,
    truth_capture,
)
from polarbssrdf.inverse.evaluation.trust import (
    bio_map_notes,
    notes_by_map,
    static_map_notes,
    untrusted_text,
    views_check,
)
from polarbssrdf.inverse.polarimetric.fit import LOW_CONFIDENT_FRACTION
from polarbssrdf.inverse.results.directory import REPORT_FILE, RESULT_FILE, read_result
from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.exr import read_exr
from polarbssrdf.report.calibration import COVERAGE_K, coverage_fractions
from polarbssrdf.report.figures import (
    RADIANCE_UNIT,
    calibration_png,
    changes_over_frames_png,
    input_views_png,
    loss_curves_png,
    map_comparison_png,
    normals_png,
    region_series_png,
    rerender_png,
    transfer_png,
    unit_label,
)
from polarbssrdf.variants import DEFAULT_VARIANT

INPUT_VIEWS = 3
"""Cameras of the static frame shown as input views."""
RERENDER_SPP = 4
"""Samples per pixel of the report's re-rendered view (its residuals are dominated by the
fit, not by 4 spp of a direct-light render)."""

STATIC_MAPS = ("eta", "alpha_s", "alpha_ss", "rho_s", "rho_ss", "displacement")
RELATIVE_ERROR_MAPS = ("rho_s", "rho_ss")
STD_SUFFIX = "_std"
"""A biophysical map's posterior standard deviation is the channel ``<name>_std`` (same unit);
``C_m_std`` etc. are optional: panels and the calibration plot are left out without them."""
ALBEDO_GAIN = "albedo_gain"
"""Optional biophysical channel: the per-texel gain on the input albedo (unitless)."""
RADIANCE_HTML = "W sr<sup>-1</sup> mm<sup>-2</sup>"


class LazyFrames(Mapping):
    """``frame -> channels``, read from disk when asked for; the last few are kept.

    A sequence of 2K maps is gigabytes: the report holds a handful of frames
    at a time, never the whole sequence.
    """

    KEEP = 3

    def __init__(self, frames, read):
        self._frames = sorted(int(f) for f in frames)
        self._read = read
        self._cache = OrderedDict()

    def __getitem__(self, frame):
        frame = int(frame)
        if frame not in self._frames:
            raise KeyError(frame)
        if frame in self._cache:
            self._cache.move_to_end(frame)
        else:
            self._cache[frame] = self._read(frame)
            while len(self._cache) > self.KEEP:
                self._cache.popitem(last=False)
        return self._cache[frame]

    def __iter__(self):
        return iter(self._frames)

    def __len__(self):
        return len(self._frames)

    def __contains__(self, frame):
        return int(frame) in self._frames


def shown_frames(frames, count=4):
    """Up to ``count`` frames spread over ``frames`` (sorted), the first and last included."""
    frames = sorted(frames)
    if len(frames) <= count:
        return frames
    picks = np.linspace(0, len(frames) - 1, count).round().astype(int)
    return [frames[i] for i in sorted(set(picks))]


@dataclass
class ReportData:
    """Everything the report shows, read from a result directory and its capture."""

    result_dir: Path
    manifest: object
    capture: object
    atlas: object
    maps: dict = field(default_factory=dict)
    """``{stage: LazyFrames}`` of the registered maps."""
    truth: Mapping = field(default_factory=dict)
    """``LazyFrames`` of the capture's ground truth (empty for a real capture)."""
    losses: dict = field(default_factory=dict)
    """``OUTDIR/metrics.json``: loss history per stage."""
    bio_summary: dict | None = None
    timings: dict = field(default_factory=dict)
    evaluation: dict | None = None
    """:func:`polarbssrdf.inverse.evaluation.scores.evaluate_stages` (None without truth)."""
    no_truth_reason: str | None = None
    """Why the report is without ground truth (None when it has truth)."""
    metadata: dict = field(default_factory=dict)
    """``{stage: {frame: metadata}}`` of the map files read so far (:func:`map_metadata`)."""
    computed: dict = field(default_factory=dict)
    """Figures two parts of the page share (:func:`calibration_curves`)."""

    @property
    def bands(self):
        return list(self.capture.manifest.band_names)

    @property
    def units(self):
        return dict(self.manifest.units)


def read_json_or_default(path, default=None):
    """The JSON in ``path``; ``default`` if there is no such file; a clear error if it is not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return default
    except ValueError as error:
        raise CommandError(f"'{path}' is not valid JSON ({error})") from None


def load_report_data(result_dir, capture=None, evaluation=None, progress=None) -> ReportData:
    """Read a result directory, its capture and (with truth) score it.

    ``evaluation``: scores already computed (the demo's); computed here otherwise
    (maps only, no held-out re-render). ``progress``: a callable given one-line
    messages.
    """

    result_dir = Path(result_dir)
    if not (result_dir / RESULT_FILE).is_file():
        if not result_dir.exists():
            raise FileNotFoundError(f"result directory '{result_dir}' does not exist")
        raise FileNotFoundError(f"'{result_dir}' holds no {RESULT_FILE}: not a result directory "
                                "(write one with 'polarbssrdf reconstruct')")
    manifest = read_result(result_dir)
    if not manifest.maps:
        raise CommandError(f"'{result_dir}' lists no maps yet: run 'polarbssrdf reconstruct' "
                           "to the end (or with --resume) first")
    try:
        capture = truth_capture(result_dir, capture)
    except FileNotFoundError as error:
        raise FileNotFoundError(str(error).replace("pass --truth CAPTURE",
                                                   "pass --capture CAPTURE")) from None
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), manifest.texture_size)
    data = ReportData(result_dir=result_dir, manifest=manifest, capture=capture, atlas=atlas)
    paths = {}
    for record in manifest.maps:
        paths.setdefault(record["stage"], {})[int(record["frame"])] = result_dir / record["path"]
    for stage, files in paths.items():
        data.maps[stage] = LazyFrames(files, _channels_reader(files,
                                                              data.metadata.setdefault(stage, {})))
    data.no_truth_reason = no_truth_reason(capture, manifest.texture_size)
    if data.no_truth_reason is None:
        data.truth = LazyFrames([r.frame for r in capture.truth.maps], capture.truth_maps)
    elif capture.truth is not None and progress:
        progress(f"report: {data.no_truth_reason}: shown without truth")
    data.losses = read_json_or_default(result_dir / "metrics.json", {}) or {}
    data.bio_summary = read_json_or_default(result_dir / "bio" / "summary.json")
    data.timings = read_json_or_default(result_dir / "timings.json", {}) or {}
    if data.truth:
        data.evaluation = evaluation if evaluation is not None else evaluate_stages(
            result_dir, capture, holdout=False)
    return data


def _channels_reader(files, metadata):
    """``frame -> channels`` of ``files``; each file's metadata is kept in ``metadata``
    (small: a map file's JSON header), so a frame is read once for both."""
    def read(frame):
        channels, header = read_exr(files[frame])
        metadata[frame] = header or {}
        return channels
    return read


def map_metadata(data, stage, frame) -> dict:
    """The JSON metadata of ``stage``'s map file of ``frame`` ({} when it has none)."""
    if frame not in data.maps.get(stage, {}):
        return {}
    known = data.metadata.get(stage, {})
    if frame not in known:
        data.maps[stage][frame]  # reading the frame records its metadata
    return known.get(frame, {})


def no_truth_reason(capture, texture_size) -> str | None:
    """Why a result of ``texture_size`` texels cannot be shown against ``capture``'s truth
    (None when it can)."""
    if capture.truth is None:
        return "the capture has no ground truth"
    if int(capture.truth.texture_size) != int(texture_size):
        size = int(capture.truth.texture_size)
        return (f"the capture's truth is {size} x {size} texels and the result "
                f"{int(texture_size)} x {int(texture_size)} (scores need one size; "
                f"reconstruct with --texture {size})")
    return None


# --------------------------------------------------------------------------- figures
def _image(png: bytes, alt: str) -> str:
    encoded = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{encoded}" alt="{html.escape(alt)}">'


def _static_mask(data, maps):
    return np.asarray(data.atlas.valid, bool) & (np.asarray(maps["confidence"]) > 0)


def _bio_mask(data, maps):
    return np.asarray(data.atlas.valid, bool) & (np.asarray(maps.get("flagged", 0.0)) == 0)


def _static_frame(data):
    return int(data.manifest.settings.get("frame", 0))


def _holdout(data) -> list:
    """Cameras the run held out of the fit (``result.json``'s settings)."""
    return list(data.manifest.settings.get("holdout") or [])


def _grid(parts) -> str:
    """Figures side by side, as many per row as the page is wide."""
    return '<div class="grid">' + "\n".join(parts) + "</div>"


def input_views_section(data) -> str:

    frame = _static_frame(data)
    records = [r for r in data.capture.manifest.frame(frame).images
               if r.kind in ("analyser", "raw")]
    chosen, seen = [], set()
    for record in records:
        if record.camera not in seen:
            chosen.append(record)
            seen.add(record.camera)
    step = max(len(chosen) // INPUT_VIEWS, 1)
    chosen = chosen[::step][:INPUT_VIEWS]
    band = _display_band(data.bands)
    holdout = _holdout(data)
    views = []
    for record in chosen:
        images = captured_view(data.capture, record)[band]
        held = ", held out" if record.camera in holdout else ""
        views.append((f"{record.camera} ({band}{held})", images["I0"], images["I90"]))
    kind = "raw sensor mosaics, demosaicked" if chosen and chosen[0].kind == "raw" else \
        "analyser images"
    shown_held = [r.camera for r in chosen if r.camera in holdout]
    if shown_held:
        held_text = (f" Camera {', '.join(shown_held)} was held out of the fit (marked "
                     "\"held out\"): it is shown as captured, and re-rendered below for "
                     "validation.")
    elif holdout:
        held_text = f" Held out of the fit (not shown): {', '.join(holdout)}."
    else:
        held_text = ""
    return (f"<p>Frame {frame}, {len(seen)} cameras ({kind}); {len(chosen)} shown, radiance "
            f"in {RADIANCE_HTML}. I90 blocks most "
            "of the specular reflection (the light is polarized at 0 degrees), so "
            "I0 - I90 is the specular part and 2 I90 the subsurface part (eq. 22-24)."
            f"{held_text}</p>"
            + _image(input_views_png(views, RADIANCE_UNIT), "input views"))


def _display_band(bands):
    for band in bands:
        if band.upper().startswith("G"):
            return band
    return bands[len(bands) // 2]


def static_maps_section(data) -> str:

    frame = _static_frame(data)
    maps = data.maps["static"][frame]
    truth = data.truth.get(frame)
    mask = _static_mask(data, maps)
    losers = losing_maps(data.evaluation)
    notes = static_map_notes(map_metadata(data, "static", frame))
    parts, singles = [], []
    has_std = False
    names = list(STATIC_MAPS) + [f"rho_sss.{band}" for band in data.bands]
    for name in names:
        if name not in maps:
            continue
        reference = truth.get(name) if truth is not None else None
        relative = name in RELATIVE_ERROR_MAPS or name.startswith("rho_sss")
        unit = data.units.get(name.split(".")[0], "1")
        std = maps.get(name + STD_SUFFIX)
        has_std |= std is not None
        note = notes.get(name)
        # without truth a map and its std are two one-panel figures in the grid
        image = _image(map_comparison_png(name, maps[name], reference, mask, unit, relative,
                                          std=std if reference is not None else None,
                                          note=f"{name}: {note['label']}" if note else None),
                       f"{name} map")
        if reference is None and std is not None:
            image += _image(map_comparison_png(f"{name} posterior std", std, None, mask, unit),
                            f"{name} posterior std")
        if note:
            image = f'<p class="held">{html.escape(name)}: {html.escape(note["text"])}.</p>' + image
        if name in losers.get("static", {}):
            image = (f'<p class="loses">{html.escape(name)}: {losers["static"][name]}</p>'
                     + image)
        (parts if reference is not None else singles).append(image)
    singles.append(_image(map_comparison_png("confidence", maps["confidence"], None,
                                             np.asarray(data.atlas.valid, bool)),
                          "confidence map"))
    note = ""
    if "specular_peak_angle" in maps:
        singles.append(_image(map_comparison_png("specular_peak_angle",
                                                 maps["specular_peak_angle"], None, mask,
                                                 "deg"), "specular peak angle map"))
        note = (" The specular peak angle is the angle between the normal and the closest half "
                "vector of the texel's views: where it is large the glossy lobes were seen on "
                "their tails only, and alpha_s and rho_s rest on the smoothness prior.")
    if truth is not None:
        intro = ("Each map: recovered, truth (one colour scale) and the error; albedo errors "
                 "are relative to the truth, in percent.")
        if has_std:
            intro += (" Then the posterior standard deviation (same unit as the map) and the "
                      "error divided by it (a calibrated std leaves 95% of the texels within "
                      "+-2).")
    else:
        intro = f"Recovered maps only ({html.escape(data.no_truth_reason or 'no truth')})."
        if has_std:
            intro += " Beside each map: its posterior standard deviation (same unit)."
    return ("<p>Texels with confidence 0 (too few views, or a fit far worse than the median) "
            f"and texels off the mesh are grey. {intro}" + note + "</p>"
            + "\n".join(parts) + _grid(singles))


def normals_section(data) -> str:

    frame = _static_frame(data)
    maps = data.maps["static"][frame]
    recovered = np.stack([maps[f"normal.{axis}"] for axis in "xyz"], axis=-1)
    truth = None
    if frame in data.truth:
        valid = np.asarray(data.atlas.valid, bool)
        height = np.nan_to_num(np.asarray(data.truth[frame]["displacement"], np.float64)) * valid
        truth = normals_from_height(height, data.atlas)
    transfer = (((data.evaluation or {}).get("static") or {}).get("maps") or {}).get(
        "displacement", {}).get("transfer")
    curve = ""
    if transfer:
        curve = ("<p>The recovered displacement against the truth's per octave of spatial "
                 "scale: the gain is the regression slope of the recovered band on the true "
                 "one (1: the relief at that scale is carried; 0: flattened), the correlation "
                 "how much of the band is the truth's rather than noise.</p>"
                 + _image(transfer_png(transfer), "displacement transfer curve"))
    return ("<p>Object-space normals of the base mesh displaced by the recovered H "
            "(eq. 25).</p>" + _image(normals_png(recovered, truth, _static_mask(data, maps)),
                                     "normal maps") + curve)


def dynamic_section(data) -> str:

    dynamic = data.maps.get("dynamic", {})
    if not dynamic:
        return ""
    static_frame = _static_frame(data)
    frames = [static_frame] + shown_frames(list(dynamic))
    band = _display_band(data.bands)
    name = f"rho_sss.{band}"
    recovered, truth = {}, {}
    mask = np.asarray(data.atlas.valid, bool)
    for frame in frames:
        maps = data.maps["static" if frame == static_frame else "dynamic"][frame]
        recovered[frame] = maps[name]
        mask &= np.asarray(maps["confidence"]) > 0
        if frame in data.truth:
            truth[frame] = data.truth[frame][name]
    truth = truth if len(truth) == len(frames) else None
    shown = "" if len(frames) - 1 == len(dynamic) else f" ({len(frames) - 1} shown)"
    return (f"<p>{len(dynamic)} frame(s) fitted from the static maps (eta and roughness "
            f"held){shown}. The change of the subsurface albedo in band {band} against frame "
            f"{static_frame} shows where the skin flushes.</p>"
            + _image(changes_over_frames_png(name, recovered, truth, mask), "albedo changes"))


def _bio_panels(data, frame, maps, truth):
    """``(name, recovered, truth or None, mask, unit, std or None)`` of one frame's biophysical
    figures: the four chromophores (with their posterior std when the file has it), the
    albedo gain if present, the residual. Every panel has the same mask (on the mesh, not
    flagged), so texels without input are grey in all of them."""
    mask = _bio_mask(data, maps)
    panels = []
    for name in BIO_PARAMETERS:
        reference = truth.get(name) if truth is not None else None
        panels.append((name, maps[name], reference, mask, UNITS[name],
                       maps.get(name + STD_SUFFIX)))
    if ALBEDO_GAIN in maps:
        panels.append((ALBEDO_GAIN, maps[ALBEDO_GAIN], None, mask, "1", None))
    panels.append(("residual", maps["residual"], None, mask,
                   f"{UNITS['residual']} (RMS over bands)", None))
    return panels


def bio_notes(data, frame) -> dict:
    """:func:`~polarbssrdf.inverse.evaluation.trust.bio_map_notes` of the bio map file of
    ``frame``: the chromophores held (at their face mean, or at the first frame's map) or
    prior-dominated, on the surface texels."""
    maps = data.maps.get("bio", {})
    if frame not in maps:
        return {}
    channels = dict(maps[frame])
    valid = np.asarray(data.atlas.valid, bool) if data.atlas is not None and \
        getattr(data.atlas, "valid", None) is not None else None
    if valid is not None:  # only the surface counts: off the mesh the std is 0 or the prior's
        channels["flagged"] = np.where(valid, np.asarray(channels.get("flagged", 0.0)), 1.0)
    return bio_map_notes(channels, map_metadata(data, "bio", frame))


def calibration_curves(data, frames):
    """``{chromophore: (fractions, texels)}`` of :func:`coverage_fractions` over ``frames``
    pooled: only chromophores whose maps carry ``<name>_std`` and frames with truth.

    Kept in ``data.computed``: the warning at the top of the page and the calibration
    section ask for the same frames, and a long sequence is read from disk once."""
    key = ("calibration", tuple(frames))
    if key not in data.computed:
        data.computed[key] = _calibration_curves(data, frames)
    return data.computed[key]


def _calibration_curves(data, frames):
    pooled = {}
    for frame in frames:
        if frame not in data.truth:
            continue
        maps, truth = data.maps["bio"][frame], data.truth[frame]
        mask = _bio_mask(data, maps)
        for name in BIO_PARAMETERS:
            std = maps.get(name + STD_SUFFIX)
            if std is None or name not in truth:
                continue
            fractions, texels = coverage_fractions(maps[name], truth[name], std, mask)
            if texels:
                total, count = pooled.get(name, (np.zeros(len(COVERAGE_K)), 0))
                pooled[name] = (total + fractions * texels, count + texels)
    return {name: (total / count, count) for name, (total, count) in pooled.items()}


def coverage_at_two_std(curves) -> dict:
    """``{chromophore: fraction within 2 std}`` of :func:`calibration_curves`' curves."""
    at_two = COVERAGE_K.index(2.0)
    return {name: float(fractions[at_two]) for name, (fractions, _) in curves.items()}


STAGE_MARKERS = {"static": "o", "dynamic": "s", "bio": "^"}
"""The calibration plot's marker of each stage's curves."""


def _pooled(pooled, key, recovered, truth, std, mask):
    """Add one map's coverage fractions to ``pooled[key] = (fractions * texels, texels)``."""
    fractions, texels = coverage_fractions(recovered, truth, std, mask)
    if texels:
        total, count = pooled.get(key, (np.zeros(len(COVERAGE_K)), 0))
        pooled[key] = (total + fractions * texels, count + texels)


def _polarimetric_calibration(data, stage, frames):
    """``{map: (fractions, texels)}`` of ``stage``'s (static or dynamic) maps over ``frames``
    pooled, every ``rho_sss.<band>`` into one ``rho_sss`` curve; only maps with ``_std``."""
    pooled = {}
    for frame in frames:
        if frame not in data.truth:
            continue
        maps, truth = data.maps[stage][frame], data.truth[frame]
        mask = _static_mask(data, maps)
        for name in list(STATIC_MAPS) + [f"rho_sss.{band}" for band in data.bands]:
            std = maps.get(name + STD_SUFFIX)
            if std is None or name not in maps or name not in truth:
                continue
            _pooled(pooled, name.split(".")[0], maps[name], truth[name], std, mask)
    return {name: (total / count, count) for name, (total, count) in pooled.items()}


def stage_calibration_curves(data):
    """``{"<map> (<stage>)": (fractions, texels)}`` for every stage's maps with a posterior
    std and truth: the static frame, the dynamic frames pooled, the bio frames pooled
    (:func:`calibration_curves`); with ``{label: stage}`` for the plot's markers."""
    curves, stages = {}, {}
    static = data.maps.get("static", {})
    frame = _static_frame(data)
    parts = [("static", _polarimetric_calibration(data, "static", [frame] if frame in static else [])),
             ("dynamic", _polarimetric_calibration(data, "dynamic", sorted(data.maps.get("dynamic", {})))),
             ("bio", calibration_curves(data, sorted(data.maps.get("bio", {}))))]
    for stage, found in parts:
        for name, curve in found.items():
            label = f"{name} ({stage})"
            curves[label], stages[label] = curve, stage
    return curves, stages


def calibration_html(data, frames) -> str:
    """The calibration plot of the posterior std (with truth and ``*_std`` channels) of every
    stage's maps, or ""; the 2-std coverage of each beside its ideal, and in the legend what
    :func:`static_map_notes` and :func:`bio_notes` say of a map (held, prior-dominated)."""
    curves, stages = stage_calibration_curves(data)
    if not curves:
        return ""
    notes = {f"{name} (bio)": text for name, text in
             notes_by_map({frame: bio_notes(data, frame) for frame in frames}).items()}
    static = _static_frame(data)
    for name, note in static_map_notes(map_metadata(data, "static", static)).items():
        notes[f"{name} (static)"] = note["label"]
    coverage = ", ".join(f"{name} {value:.3f}"
                         for name, value in coverage_at_two_std(curves).items())
    return ("<p>For each map with a posterior standard deviation, the fraction of its texels "
            "(static and dynamic maps: confident texels on the mesh; biophysical maps: texels "
            "not flagged; frames with truth pooled, the subsurface albedo's bands pooled) whose "
            "error |recovered - truth| is below k times the posterior standard deviation, "
            "against the fraction erf(k / sqrt 2) a Gaussian posterior of that width would give "
            f"(dashed), k = {COVERAGE_K[0]:g} to {COVERAGE_K[-1]:g}. Above the dashed curve "
            "the std is too large, below it too small (overconfident). Markers: circles static, "
            "squares dynamic, triangles biophysical.</p>"
            f'<p class="coverage">Within 2 std: {html.escape(coverage)} '
            f"(ideal {COVERAGE_IDEAL:.3f}).</p>"
            + _image(calibration_png(curves, notes=notes,
                                     markers={label: STAGE_MARKERS[stage]
                                              for label, stage in stages.items()}),
                     "posterior calibration"))


def biophysical_section(data) -> str:

    bio = data.maps.get("bio", {})
    if not bio:
        return ""
    frames = sorted(bio)
    losers = losing_maps(data.evaluation).get("bio", {})
    parts = []
    has_std = False
    for frame in sorted({frames[0], frames[-1]}):
        maps = bio[frame]
        truth = data.truth.get(frame)
        parts.append(f"<h3>Frame {frame}</h3>")
        figures, singles = [], []
        notes = bio_notes(data, frame)
        for name, values, reference, mask, unit, std in _bio_panels(data, frame, maps, truth):
            has_std |= std is not None
            note = notes.get(name)
            image = _image(map_comparison_png(name, values, reference, mask, unit, std=std,
                                              note=f"{name}: {note['label']}" if note else None),
                           f"{name} frame {frame}")
            if note:
                image = (f'<p class="held">{html.escape(name)}, frame {frame}: '
                         f"{html.escape(note['text'])}.</p>" + image)
            why = losers.get(str(frame), {}).get(name)
            if why:
                image = f'<p class="loses">{html.escape(name)}: {why}</p>' + image
            (figures if reference is not None or std is not None else singles).append(image)
        parts.append("\n".join(figures) + _grid(singles))
    summary = data.bio_summary
    truth_summary = None
    if summary is not None:
        if all(f in data.truth for f in frames):
            masks = region_masks(data.capture, data.capture.load_mesh(), data.atlas)
            truth_summary = merged_region_summary(data.truth, frames, masks)
        units = summary.get("units", {})
        if len(frames) > 1:
            parts.append("<h3>Hemoglobin over time</h3>")
            shown = frames if len(frames) <= 2 else [frames[0], frames[-1]]
            notes = notes_by_map({frame: bio_notes(data, frame) for frame in shown})
            parts.append(_image(region_series_png(["C_h_out", "C_h_in"], summary,
                                                  truth_summary, units, notes=notes),
                                "hemoglobin over time"))
        else:
            parts.append(f"<p>One frame ({frames[0]}): hemoglobin over time needs two; the "
                         "table below has its region means.</p>")
        parts.append("<h3>Region summary (the layout of the supplement's Table 2)</h3>")
        parts.append(table2_html(summary, truth_summary, frames))
    std_text = (" Beside each chromophore map: its posterior standard deviation (same unit)."
                if has_std else "")
    return ("<p>Melanin (C_m), eumelanin ratio (beta_m) and hemoglobin of the epidermis "
            "(C_h_out) and dermis (C_h_in), fitted to the subsurface albedo of every "
            "band (eq. 40-47). Flagged texels (no confident input) are grey in every panel."
            f"{std_text}</p>" + "\n".join(parts))


def merged_region_summary(maps, frames, masks):
    """:func:`~polarbssrdf.inverse.biophysical.stage.region_summary` of ``frames``, one frame in
    memory at a time."""

    merged = None
    for frame in frames:
        part = region_summary({frame: maps[frame]}, masks)
        if merged is None:
            merged = part
            continue
        for region, entry in part["regions"].items():
            merged["regions"].setdefault(region, {"texels": entry["texels"], "frames": {}})
            merged["regions"][region]["frames"].update(entry["frames"])
    return merged


TABLE2_PLUSMINUS = ("Each cell is the region's mean &plusmn; the standard deviation of the "
                    "map over the region's texels: how much the parameter varies within the "
                    "region (the supplement's Table 2 reports the same), not an uncertainty "
                    "of the mean (the posterior std is beside each map above). Volume "
                    "fractions; flagged texels are left out.")
"""What the region table's &plusmn; is, said above it."""


def table2_html(summary, truth_summary, frames) -> str:
    """Mean +- the spatial std over each region's texels (rows: region, frame, source;
    columns: parameters), first and last frame, with :data:`TABLE2_PLUSMINUS` above it."""
    shown = sorted({frames[0], frames[-1]})
    header = "".join(f"<th>{html.escape(p)}<br>mean &plusmn; spatial std</th>"
                     for p in BIO_PARAMETERS)
    rows = []
    for region, entry in summary["regions"].items():
        for frame in shown:
            sources = [("recovered", entry["frames"].get(str(frame)))]
            if truth_summary is not None and region in truth_summary["regions"]:
                sources.append(("truth", truth_summary["regions"][region]["frames"]
                                .get(str(frame))))
            for label, values in sources:
                if values is None:
                    continue
                cells = "".join(f"<td>{values[p]['mean']:.4f} &plusmn; {values[p]['std']:.4f}"
                                "</td>" for p in BIO_PARAMETERS)
                rows.append(f"<tr><td>{html.escape(region)}</td>"
                            f"<td>{int(entry.get('texels', 0)):,}</td><td>{frame}</td>"
                            f"<td>{label}</td>{cells}</tr>")
    return (f'<p class="plusminus">{TABLE2_PLUSMINUS}</p>'
            "<table><tr><th>region</th><th>texels</th><th>frame</th><th>source</th>"
            f"{header}</tr>" + "".join(rows) + "</table>")


def rerender_section(data, variant) -> str:

    frame = _static_frame(data)
    maps = data.maps["static"][frame]
    holdout = _holdout(data)
    if holdout:
        camera, why = holdout[0], "held out of the fit"
    else:
        camera = next(r.camera for r in data.capture.manifest.frame(frame).images
                      if r.kind in ("analyser", "raw"))
        why = "one of the fitted views (the run held no camera out)"
    view = render_view(data.capture, maps, camera, frame, spp=RERENDER_SPP,
                       variant=variant)
    observed = captured_view(data.capture, view["record"])
    band = _display_band(data.bands)
    errors = separation_errors(observed[band], view["images"][band], view["mask"])
    return (f"<p>Camera {html.escape(camera)}, {why}, re-rendered through Mitsuba with the "
            f"<code>pbssrdf</code> plugin, the recovered maps and the displaced mesh "
            f"({RERENDER_SPP} spp, band {band}). RMSE over {errors['pixels']:,} pixels: "
            f"I_s {100 * errors['relative_rmse_I_s']:.2f}%, I_sss "
            f"{100 * errors['relative_rmse_I_sss']:.2f}% of the mean captured I_sss.</p>"
            + _image(rerender_png(camera, band, observed[band], view["images"][band],
                                  view["mask"], RADIANCE_UNIT), "re-rendered view"))


def losses_section(data) -> str:

    losses = data.losses
    if not any(losses.get(k) for k in ("static", "dynamic", "bio")):
        return "<p>No loss history in metrics.json.</p>"
    return ("<p>Data terms are mean chi-squares per texel-view (about 1 when the fit "
            "reaches the noise); the total includes the weighted regularizers.</p>"
            + _image(loss_curves_png(losses.get("static"), losses.get("dynamic"),
                                     losses.get("bio")), "loss curves"))


# --------------------------------------------------------------------------- metrics table
def _ratio(constant, value):
    if value is None or constant is None or not value > 0:
        return "-"
    return f"{constant / value:.2f}x"


def _mark(loses) -> str:
    return f' class="loses" title="{LOSES}"' if loses else ""


def _verdict(loses) -> str:
    return f"<td{_mark(loses)}>{LOSES}</td>" if loses else "<td></td>"


def metrics_html(evaluation) -> str:
    """The evaluate figures of every stage as HTML tables; a map that does not beat the best
    constant map is marked (:data:`LOSES`)."""
    parts = []
    static = evaluation.get("static")
    if static:
        maps = static["maps"]
        rows = []
        for name in ("eta", "alpha_s", "alpha_ss", "displacement"):
            entry = maps[name]
            loses = loses_to_constant(entry["mae"], entry["constant_mae"])
            rows.append(f"<tr{_mark(loses)}><td>{name}</td><td>MAE</td>"
                        f"<td>{entry['mae']:.4f}</td>"
                        f"<td>{entry['constant_mae']:.4f}</td>"
                        f"<td>{_ratio(entry['constant_mae'], entry['mae'])}</td>"
                        f"<td>{html.escape(unit_label(entry.get('unit', '1')))}</td>"
                        f"{_verdict(loses)}</tr>")
        relative = [(name, maps[name]) for name in ("rho_s", "rho_ss")]
        relative += [(f"rho_sss.{band}", entry) for band, entry in
                     maps["rho_sss"]["bands"].items()]
        for name, entry in relative:
            value, constant = entry["relative_error"], entry["constant_relative_error"]
            if value is None:
                continue
            loses = loses_to_constant(value, constant)
            rows.append(f"<tr{_mark(loses)}><td>{name}</td><td>relative error</td>"
                        f"<td>{100 * value:.2f}%</td>"
                        f"<td>{100 * constant:.2f}%</td><td>{_ratio(constant, value)}</td>"
                        f"<td>unitless</td>{_verdict(loses)}</tr>")
        normal = maps["normal"]
        loses = loses_to_constant(normal["mean_deg"], normal["base_mesh_mean_deg"])
        rows.append(f"<tr{_mark(loses)}><td>normals</td><td>mean angle</td>"
                    f"<td>{normal['mean_deg']:.2f}</td>"
                    f"<td>{normal['base_mesh_mean_deg']:.2f} (base mesh)</td>"
                    f"<td>{_ratio(normal['base_mesh_mean_deg'], normal['mean_deg'])}</td>"
                    f"<td>degree</td>"
                    + (f'<td class="loses">no better than the base mesh</td>' if loses
                       else "<td></td>") + "</tr>")
        parts.append(f"<h3>Static stage (frame {static['frame']}, "
                     f"{static['texels_scored']:,} texels scored)</h3>"
                     "<table><tr><th>map</th><th>score</th><th>recovered</th>"
                     "<th>best constant map</th><th>constant / recovered</th><th>unit</th>"
                     "<th>verdict</th></tr>" + "".join(rows) + "</table>")
        holdout = static.get("holdout")
        if holdout and holdout.get("cameras"):
            parts.append(holdout_html(holdout))
    dynamic = evaluation.get("dynamic") or {}
    if dynamic:
        rows = []
        for frame, entry in sorted(dynamic.items(), key=lambda kv: int(kv[0])):
            maps = entry["maps"]
            cells = []
            for name in ("eta", "alpha_s"):
                loses = loses_to_constant(maps[name]["mae"], maps[name]["constant_mae"])
                cells.append(f"<td{_mark(loses)}>{maps[name]['mae']:.4f}</td>")
            loses = loses_to_constant(maps["rho_s"]["relative_error"],
                                      maps["rho_s"]["constant_relative_error"])
            cells.append(f"<td{_mark(loses)}>{100 * maps['rho_s']['relative_error']:.2f}%</td>")
            rows.append(f"<tr><td>{frame}</td>{''.join(cells)}"
                        f"<td>{100 * maps['rho_sss']['mean_relative_error']:.2f}%</td>"
                        f"<td>{maps['normal']['mean_deg']:.2f}</td></tr>")
        parts.append("<h3>Dynamic stage, per frame</h3><table><tr><th>frame</th>"
                     "<th>eta MAE</th><th>alpha_s MAE</th><th>rho_s rel. error</th>"
                     "<th>rho_sss rel. error (mean of bands)</th><th>normals (deg)</th></tr>"
                     + "".join(rows) + "</table>")
    bio = evaluation.get("bio") or {}
    if bio:
        header = "".join(f"<th>{p}</th>" for p in BIO_PARAMETERS)
        rows = []
        for frame, entry in sorted(bio.items(), key=lambda kv: int(kv[0])):
            cells = []
            for p in BIO_PARAMETERS:
                scores = entry["maps"][p]
                loses = loses_to_constant(scores["mae_of_range"],
                                          scores["constant_mae_of_range"])
                cells.append(f"<td{_mark(loses)}>{100 * scores['mae_of_range']:.1f}% "
                             f"({100 * scores['constant_mae_of_range']:.1f}%)</td>")
            rows.append(f"<tr><td>{frame}</td>{''.join(cells)}</tr>")
        parts.append("<h3>Biophysical stage: MAE as a fraction of the Table 2 range (best "
                     "constant map in parentheses; red: no better than it)</h3>"
                     f"<table><tr><th>frame</th>{header}</tr>{''.join(rows)}</table>")
        parts.append(coverage_table_html(bio))
    losers = losing_maps(evaluation)
    names = list(losers["static"]) + sorted({n for per in losers["bio"].values() for n in per})
    if names:
        parts.insert(0, f'<p class="loses">{len(names)} map(s) {LOSES} (a map equal to the '
                        f"truth's mean everywhere): {html.escape(', '.join(names))}; they "
                        "are marked in red below and beside their figures.</p>")
    return "\n".join(parts)


def coverage_table_html(bio) -> str:
    """The 2-std coverage of every chromophore per frame beside its ideal
    (:data:`~polarbssrdf.inverse.evaluation.scores.COVERAGE_IDEAL`), or "" when no map
    file has a std."""
    rows = []
    for frame, entry in sorted(bio.items(), key=lambda kv: int(kv[0])):
        values = [(entry["maps"][p] or {}).get("coverage") for p in BIO_PARAMETERS]
        if all(v is None or v != v for v in values):
            continue
        cells = "".join("<td>-</td>" if v is None or v != v else f"<td>{v:.3f}</td>"
                        for v in values)
        rows.append(f"<tr><td>{frame}</td>{cells}<td>{COVERAGE_IDEAL:.3f}</td></tr>")
    if not rows:
        return ""
    header = "".join(f"<th>{p}</th>" for p in BIO_PARAMETERS)
    return ("<h3>Biophysical stage: fraction of texels within 2 posterior std of the truth "
            f"(a calibrated std: {COVERAGE_IDEAL:.3f})</h3>"
            f"<table><tr><th>frame</th>{header}<th>ideal</th></tr>{''.join(rows)}</table>")


def holdout_html(holdout) -> str:
    """The held-out re-render errors (:func:`polarbssrdf.inverse.evaluation.rerender
    .holdout_errors`) as an HTML table."""
    cells = "".join(
        f"<tr><td>{html.escape(name)}</td>"
        f"<td>{100 * entry['mean']['relative_rmse_I_s']:.2f}%</td>"
        f"<td>{100 * entry['mean']['relative_rmse_I_sss']:.2f}%</td>"
        f"<td>{entry['pixels']:,}</td></tr>"
        for name, entry in holdout["cameras"].items())
    return ("<h3>Held-out views, re-rendered (RMSE of the mean captured I_sss, "
            f"{holdout['spp']} spp)</h3><table><tr><th>camera</th><th>I_s</th>"
            f"<th>I_sss</th><th>pixels</th></tr>{cells}</table>")


def confidence_warning(data) -> str:
    """A sentence for the top of the page when most of the surface (more than
    ``1 - LOW_CONFIDENT_FRACTION`` of the texels on the mesh) has confidence 0 (""
    otherwise): the fraction, and what it means for the maps."""
    static = data.maps.get("static")
    frame = _static_frame(data)
    if not static or frame not in static:
        return ""
    valid = np.asarray(data.atlas.valid, bool)
    on_mesh = int(valid.sum())
    if not on_mesh:
        return ""
    zero = float(np.mean(np.asarray(static[frame]["confidence"])[valid] <= 0))
    if 1.0 - zero >= LOW_CONFIDENT_FRACTION:
        return ""
    cameras = {r.camera for r in data.capture.manifest.frame(frame).images
               if r.kind in ("analyser", "raw")} - set(_holdout(data))
    views = f" ({len(cameras)} views fitted)" if cameras else ""
    return (f'<p class="warning">{100 * zero:.0f}% of the surface{views} has confidence 0: '
            "too few views saw it, or its fit is far worse than the median. Those texels are "
            "grey in every map and hold the prior or their neighbours' values, not "
            "measurements; add views that cover them.</p>")


def untrusted_warning(data) -> str:
    """A paragraph for the top of the page when the run's own data says its maps and std
    cannot be trusted (:func:`~polarbssrdf.inverse.evaluation.trust.views_check`: too few
    usable views per confident texel of the static frame); "" otherwise. With truth, the
    measured 2-std coverage of the biophysical maps follows as the evidence."""
    static = data.maps.get("static")
    frame = _static_frame(data)
    if not static or frame not in static or "confidence" not in static[frame]:
        return ""
    check = views_check(static[frame]["confidence"], data.atlas.valid)
    if check is None or check["trusted"]:
        return ""
    bio = data.maps.get("bio") or {}
    has_std = bool(bio) and any(name.endswith(STD_SUFFIX) for name in bio[sorted(bio)[0]])
    evidence = ""
    coverage = coverage_at_two_std(calibration_curves(data, sorted(bio))) if has_std else {}
    if coverage:
        figures = ", ".join(f"{name} {value:.3f}" for name, value in coverage.items())
        evidence = (f" Against the truth, the fraction of texels within 2 std is {figures} "
                    f"(ideal {COVERAGE_IDEAL:.3f}; Posterior calibration below).")
    losers = losing_maps(data.evaluation)
    count = len(losers["static"]) + len({n for per in losers["bio"].values() for n in per})
    if count:
        evidence += f" {count} map(s) are {LOSES} (Metrics below)."
    return ('<p class="warning" id="untrusted"><strong>These maps and their uncertainty '
            f"cannot be trusted.</strong> Static frame {frame}: "
            f"{html.escape(untrusted_text(check, has_std))}.{html.escape(evidence)}</p>")


# --------------------------------------------------------------------------- page
STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 2em auto;
       max-width: 1100px; color: #222; line-height: 1.45; padding: 0 1em; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
img { display: block; max-width: 100%; margin: .6em 0; }
img.broken { outline: 3px solid #c00; min-height: 2em; }
table { border-collapse: collapse; margin: .6em 0 1.2em; font-size: .9em; }
td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
td:first-child, th:first-child { text-align: left; }
nav a { margin-right: 1em; } .meta { color: #555; } code { background: #f3f3f3; }
#image-warning { color: #c00; font-weight: bold; }
.grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(300px, 1fr));
        gap: 0 1em; align-items: start; }
.loses { color: #b00; } tr.loses td, td.loses { background: #fde8e8; }
.warning { border-left: 4px solid #c60; background: #fff4e5; padding: .4em .8em; }
.held { color: #8a4b00; }
"""

IMAGE_CHECK = """
window.addEventListener("load", function () {
  var images = document.images, broken = 0;
  for (var i = 0; i < images.length; i++) {
    if (!images[i].complete || images[i].naturalWidth === 0) {
      broken++; images[i].classList.add("broken");
    }
  }
  document.body.setAttribute("data-images", String(images.length));
  document.body.setAttribute("data-images-broken", String(broken));
  var panels = document.querySelectorAll(".grid img"), rows = {};
  for (var j = 0; j < panels.length; j++) {
    rows[Math.round(panels[j].getBoundingClientRect().top + window.scrollY)] = true;
  }
  document.body.setAttribute("data-grid-images", String(panels.length));
  document.body.setAttribute("data-grid-rows", String(Object.keys(rows).length));
  if (broken) {
    var warning = document.getElementById("image-warning");
    warning.textContent = broken + " image(s) failed to load";
  }
});
"""


def _timings_text(timings) -> str:
    if not timings:
        return ""
    parts = [f"{stage} {seconds:.0f} s" for stage, seconds in timings.items()]
    return "Stage wall times: " + ", ".join(parts) + "."


def build_report_html(data, *, variant=DEFAULT_VARIANT, title=None,
                      extra_metrics=None, progress=None) -> str:
    """The report page of ``data`` (:func:`load_report_data`) as an HTML string.

    ``extra_metrics``: ``{label: value}`` shown in the header (e.g. the demo's timings).
    """
    say = progress or (lambda message: None)
    manifest = data.manifest
    stages = [s for s in ("static", "dynamic", "bio") if s in data.maps]
    frames = sorted({f for per_stage in data.maps.values() for f in per_stage})
    frame_text = (", ".join(map(str, frames)) if len(frames) <= 12
                  else f"{frames[0]}-{frames[-1]} ({len(frames)})")
    sections = []

    def add(anchor, heading, builder):
        say(f"report: {heading.lower()}")
        started = time.perf_counter()
        body = builder()
        if body:
            sections.append((anchor, heading, body))
        say(f"report: {heading.lower()} ({time.perf_counter() - started:.1f} s)")

    if data.evaluation:
        add("metrics", "Metrics", lambda: metrics_html(data.evaluation))
    add("inputs", "Input views", lambda: input_views_section(data))
    if "static" in data.maps:
        add("static", "Static maps" + (" against the truth" if data.truth else ""),
            lambda: static_maps_section(data))
        add("normals", "Normals", lambda: normals_section(data))
    if "dynamic" in data.maps:
        add("dynamic", "Dynamic frames", lambda: dynamic_section(data))
    if "bio" in data.maps:
        add("bio", "Biophysical maps", lambda: biophysical_section(data))
    add("calibration", "Posterior calibration",
        lambda: calibration_html(data, sorted(data.maps.get("bio", {}))))
    if "static" in data.maps:
        add("rerender", "Re-rendered view", lambda: rerender_section(data, variant))
    add("losses", "Loss curves", lambda: losses_section(data))

    created = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    truth_note = ("with ground truth (synthetic capture)" if data.truth else
                  f"without ground truth ({html.escape(data.no_truth_reason or 'none')}): "
                  "maps, losses and re-rendering residuals only")
    warning = untrusted_warning(data) + confidence_warning(data)
    # the capture this page was made with (report --capture), not only the one result.json
    # records: a copy without truth, or one moved since, is what the figures come from
    shown_capture = Path(data.capture.directory).resolve()
    fitted_note = ""
    if Path(str(manifest.capture)).resolve() != shown_capture:
        fitted_note = (f" (the maps were fitted on <code>{html.escape(str(manifest.capture))}"
                       "</code>, as result.json records)")
    extra = "".join(f"<br>{html.escape(str(k))}: {html.escape(str(v))}"
                    for k, v in (extra_metrics or {}).items())
    nav = " ".join(f'<a href="#{a}">{html.escape(h)}</a>' for a, h, _ in sections)
    body = "\n".join(f'<h2 id="{a}">{html.escape(h)}</h2>\n{b}' for a, h, b in sections)
    heading = title or "polarbssrdf reconstruction"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(heading)}</title><style>{STYLE}</style></head>
<body>
<h1>{html.escape(heading)}</h1>
<p class="meta">Result <code>{html.escape(str(data.result_dir.resolve()))}</code> of capture
<code>{html.escape(str(shown_capture))}</code>{fitted_note}, {truth_note}.<br>
{manifest.texture_size} x {manifest.texture_size} texels; stages {', '.join(stages)};
frames {frame_text}; bands {', '.join(data.bands)}.
{_timings_text(data.timings)}{extra}<br>Written {created} by polarbssrdf.report.page.</p>
<p id="image-warning"></p>
{warning}
<nav>{nav}</nav>
{body}
<script>{IMAGE_CHECK}</script>
</body></html>
"""


def write_report(result_dir, out=None, *, capture=None, evaluation=None,
                 variant=DEFAULT_VARIANT, title=None, extra_metrics=None,
                 progress=None) -> Path:
    """Write the report of ``result_dir`` to ``out`` (default ``result_dir/report.html``),
    atomically; returns its path."""

    data = load_report_data(result_dir, capture, evaluation, progress)
    page = build_report_html(data, variant=variant, title=title, extra_metrics=extra_metrics,
                             progress=progress)
    out = Path(out) if out is not None else Path(result_dir) / REPORT_FILE
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, page, overwrite=True)
    return out
