"""The error budget of the chromophore chain (issue 20 item 1).

Each row is a synthetic capture variant (``polarbssrdf.synth``) run through
the polarimetric stages and the biophysical stage
(:func:`polarbssrdf.inverse.reconstruct`), scored against its truth with the
project's scorer (:mod:`polarbssrdf.inverse.evaluation.scores`):

* the static stage's (frame 0) and the dynamic stage's (frame 1) subsurface
  albedo on the confident texels (``confidence > 0``, on the mesh, finite
  truth, as ``evaluate`` scores them): the relative error
  ``e_b = (rho_b - t_b) / t_b`` per band and texel, split into its
  **band-common** part ``c = mean_b e_b`` (rms over texels), its **per-band**
  part (rms of ``e_b - c``) and its **bias** (mean of ``e_b``), with the
  scorer's mean relative error beside them;
* the four chromophore MAEs (``C_m, beta_m, C_h_out, C_h_in``) in % of the
  Table 2 range (the scorer's ``mae_of_range``), mean over the frames as the
  demo reports them, beside the best constant map's.

Rows (``--rows``; the default is all of the demo-face rows):

=================  ==========================================================
``raw``            the demo's capture: raw 12-bit mosaics with sensor noise,
                   8 views (the middle one held out, as ``demo`` does)
``noise_free``     noise-free analyser images (same render samples per pixel)
``geometry_held``  the static stage is given the truth geometry: the capture's
                   mesh is the displaced mesh synth rendered, and the
                   displacement map is held at 0 (learning rate 0)
``eta_held``       ``raw``'s static and dynamic maps with eta replaced by the
                   truth's, fed to the biophysical stage
``views_16``,      ``raw`` with 16 / 32 cameras (``views_8`` is ``raw``)
``views_32``
``no_diffusion``   a capture whose subsurface light is not diffused across
                   texels (``SynthesisSettings(subsurface_diffusion=False)``),
                   so the polarimetric stages' per-texel model is exact;
                   ``no_diffusion_noise_free`` the same without sensor noise
                   (against ``noise_free``: the blur's own bias)
``truth_albedo``   the biophysical stage fed the truth subsurface albedo with
                   1% white (multiplicative) noise and truth eta, every
                   surface texel confident; ``truth_albedo_clean`` without the
                   noise
``skin_off``       a capture whose epidermis is thicker (0.28 mm) and blood
                   less oxygenated (0.71) than the fit's start values (0.25,
                   0.75; spreads as synth's defaults), run as a user would:
                   the thickness held at the model's with its std
                   marginalized, the oxygenation estimated
``skin_off_*``     the same capture and polarimetric maps, the biophysical
                   stage given the truth's face mean of ``thickness`` (held
                   at truth), of ``gamma`` (held at truth) or ``skin`` (both)
``skin_off_truth_albedo[_*]``
                   the same four, fed the truth albedo with 1% noise and the
                   truth eta as ``truth_albedo`` (the skin unknowns' share
                   without the polarimetric stages' error)
=================  ==========================================================

``glossy_held`` is not a row: the static stage starts every map from a
constant (``config.initial``) and has no way to take per-texel truth maps of
the glossy parameters, so holding them needs a pipeline hook.

``--sweep`` adds Table 2 rows x regions (forehead/cheek of types I, III, IV;
demo reflectance) with the ``raw`` and ``noise_free`` captures, one frame
(static + biophysical stages), at ``--sweep-texture`` (default 128).

Everything a row makes (capture, result directory, scores) is kept under
``--cache DIR`` under a name with a hash of what defines it, so a rerun (or
another row that shares a capture or a result) reuses it; a step is done once
its ``done.json`` is written.

    nice .venv/bin/python bench/chromophore_budget.py --texture 128 --sweep \\
        --cache /tmp/budget-cache --out budget.json
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
DEMO_ROWS = ("raw", "noise_free", "geometry_held", "eta_held", "views_16", "views_32",
             "no_diffusion", "no_diffusion_noise_free", "truth_albedo", "truth_albedo_clean")
SKIN_OFF_LAYERS = (("thickness_mm", (0.28, 0.025, 0.10, 0.40)), ("gamma", (0.71, 0.03, 0.50, 0.95)))
"""synth's ``skin_layers`` of the ``skin_off`` rows: off the fit's start values (0.25 mm, 0.75)
by what the six off-prior faces of ``bench/bio_off_prior.py`` use, synth's default spreads."""
HELD_AT_TRUTH = {"thickness": ("thickness_mm",), "gamma": ("gamma",), "skin": ("thickness_mm", "gamma")}
"""Row suffix -> the skin unknowns the biophysical stage is given at the truth's face mean."""
SWEEP_SKINS = (("forehead", "I"), ("cheek", "I"), ("forehead", "III"), ("cheek", "III"),
               ("forehead", "IV"), ("cheek", "IV"))
TRUTH_ALBEDO_NOISE = 0.01
DONE = "done.json"


@dataclasses.dataclass(frozen=True)
class CaptureSpec:
    """What a synthetic capture is: synth's settings and the truth's skin row."""

    texture: int
    views: int = 8
    frames: int = 2
    raw: bool = True
    subsurface_diffusion: bool = True
    skin: tuple = ("forehead", "II")
    spp: int = 8
    seed: int = 0
    skin_layers: tuple = ()  # synth's (name, (base, std, low, high)) pairs; () for its defaults

    @property
    def resolution(self):
        """Image size: the demo's 1.5 pixels per texel (384 px at 256^2), even for raw mosaics."""
        return max(64, 2 * round(0.75 * self.texture))

    @property
    def holdout(self):
        return f"cam{self.views // 2:02d}"  # the demo's: the middle camera of the ring


@dataclasses.dataclass(frozen=True)
class Row:
    """A budget row: a capture, how the static stage sees it, what the biophysical stage is fed."""

    name: str
    capture: CaptureSpec
    geometry_held: bool = False
    bio_input: str = "stages"  # "stages", "eta_held", "truth_albedo", "truth_albedo_clean"
    held_at_truth: tuple = ()  # skin unknowns the biophysical stage is given at the truth's mean


def demo_rows(texture, frames):
    raw = CaptureSpec(texture=texture, frames=frames)
    return {
        "raw": Row("raw", raw),
        "noise_free": Row("noise_free", dataclasses.replace(raw, raw=False)),
        "geometry_held": Row("geometry_held", raw, geometry_held=True),
        "eta_held": Row("eta_held", raw, bio_input="eta_held"),
        "views_8": Row("raw", raw),
        "views_16": Row("views_16", dataclasses.replace(raw, views=16)),
        "views_32": Row("views_32", dataclasses.replace(raw, views=32)),
        "no_diffusion": Row("no_diffusion", dataclasses.replace(raw, subsurface_diffusion=False)),
        "no_diffusion_noise_free": Row("no_diffusion_noise_free", dataclasses.replace(
            raw, raw=False, subsurface_diffusion=False)),
        "truth_albedo": Row("truth_albedo", raw, bio_input="truth_albedo"),
        "truth_albedo_clean": Row("truth_albedo_clean", raw, bio_input="truth_albedo_clean"),
        **skin_off_rows(dataclasses.replace(raw, skin_layers=SKIN_OFF_LAYERS)),
    }


def skin_off_rows(capture):
    """The ``skin_off`` rows on ``capture``: estimated, and held at truth per :data:`HELD_AT_TRUTH`,
    from the polarimetric stages' maps and from the truth albedo."""
    rows = {}
    for source, bio_input in (("", "stages"), ("_truth_albedo", "truth_albedo")):
        name = f"skin_off{source}"
        rows[name] = Row(name, capture, bio_input=bio_input)
        for suffix, held in HELD_AT_TRUTH.items():
            rows[f"{name}_{suffix}"] = Row(f"{name}_{suffix}", capture, bio_input=bio_input,
                                           held_at_truth=held)
    return rows


def sweep_rows(texture):
    rows = {}
    for region, kind in SWEEP_SKINS:
        for noise in ("raw", "noise_free"):
            spec = CaptureSpec(texture=texture, frames=1, raw=noise == "raw", skin=(region, kind))
            name = f"{region}_{kind}_{noise}"
            rows[name] = Row(name, spec)
    return rows


def key(value):
    """A short stable hash of a JSON-able value (a cache directory's name)."""
    text = json.dumps(value, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:10]


def is_done(directory):
    return (Path(directory) / DONE).is_file()


def mark_done(directory, record):
    from polarbssrdf.io.atomic import atomic_write_text

    atomic_write_text(Path(directory) / DONE, json.dumps(record, indent=1) + "\n", overwrite=True)


def fresh(directory):
    """An empty ``directory`` (whatever an interrupted earlier attempt left is removed)."""
    directory = Path(directory)
    if directory.exists():
        shutil.rmtree(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    return directory


def truth_settings(spec):
    """The demo's truth (its eta and roughness off the fit's start values) on ``spec.skin``, with
    ``spec.skin_layers`` in place of synth's default thickness and oxygenation."""
    from polarbssrdf.demo import TRUTH_SETTINGS
    from polarbssrdf.synth.truth import DEFAULT_REFLECTANCE, DEFAULT_SKIN_LAYERS, TruthSettings

    reflectance = dict(DEFAULT_REFLECTANCE)
    reflectance.update({k: tuple(v) for k, v in TRUTH_SETTINGS["reflectance"].items()})
    return TruthSettings(reflectance=reflectance, skin=tuple(spec.skin),
                         skin_layers={**DEFAULT_SKIN_LAYERS, **dict(spec.skin_layers)})


def make_capture(spec, cache, say):
    """The synthetic capture of ``spec`` (synthesized once into the cache); its directory."""
    from polarbssrdf.spectral import shipped_default_bands
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    directory = Path(cache) / "captures" / f"T{spec.texture}_v{spec.views}_{key(dataclasses.asdict(spec))}"
    if is_done(directory):
        return directory, json.loads((directory / DONE).read_text())["seconds"]
    say(f"  synth {directory.name} ({spec})")
    started = time.perf_counter()
    settings = SynthesisSettings(object="face", views=spec.views, frames=spec.frames,
                                 resolution=spec.resolution, texture=spec.texture, spp=spec.spp,
                                 seed=spec.seed, raw=spec.raw,
                                 subsurface_diffusion=spec.subsurface_diffusion)
    synthesize(fresh(directory), settings, bands=shipped_default_bands(),
               truth_settings=truth_settings(spec), progress=False)
    seconds = time.perf_counter() - started
    mark_done(directory, {"spec": dataclasses.asdict(spec), "seconds": seconds})
    return directory, seconds


def geometry_held_capture(capture_dir, cache, say):
    """A copy of the capture whose mesh is the displaced mesh synth rendered (frame 0's
    truth displacement on the base mesh); images and truth are hard links."""
    from polarbssrdf.geometry import displace
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.atomic import atomic_write_bytes
    from polarbssrdf.io.capture import _obj_text

    directory = Path(cache) / "captures" / f"{Path(capture_dir).name}_truth_geometry"
    if is_done(directory):
        return directory
    say(f"  truth-geometry copy {directory.name}")
    fresh(directory)
    shutil.copytree(capture_dir, directory, copy_function=os.link, dirs_exist_ok=True)
    (directory / DONE).unlink()
    capture = load_capture(directory, check_images=False)
    mesh = displace(capture.load_mesh(), capture.truth_maps(0)["displacement"])
    mesh_path = capture.mesh_path
    mesh_path.unlink()  # a hard link to the original capture's mesh: never write through it
    atomic_write_bytes(mesh_path, _obj_text(mesh).encode("utf-8"), overwrite=True)
    mark_done(directory, {"from": str(capture_dir), "mesh": "base mesh displaced by the truth"})
    return directory


ITERATIONS = None
"""``--iterations``: epochs of the static stage and of each dynamic frame (None: the config's)."""


def run_stages(capture_dir, spec, cache, say, geometry_held=False):
    """Static (+ dynamic with more than one frame) and biophysical stages on the capture."""
    from polarbssrdf.inverse import reconstruct

    config = {"learning_rates": {"displacement": 0.0}} if geometry_held else None
    if ITERATIONS is not None:
        config = dict(config or {}, iterations=ITERATIONS,
                      dynamic={"iterations": ITERATIONS})
    directory = Path(cache) / "results" / f"{Path(capture_dir).name}_{key(config)}"
    if is_done(directory):
        return directory, json.loads((directory / DONE).read_text())["seconds"]
    stages = ("static", "dynamic", "bio") if spec.frames > 1 else ("static", "bio")
    say(f"  reconstruct {directory.name} ({', '.join(stages)})")
    started = time.perf_counter()
    result = reconstruct(capture_dir, fresh(directory), stages=stages, config=config,
                         holdout=[spec.holdout], progress=False)
    if result.failed:
        raise RuntimeError(f"reconstruct {directory}: frames failed: {result.failed}")
    seconds = {**result.timings, "total": time.perf_counter() - started}
    mark_done(directory, {"capture": str(capture_dir), "config": config, "seconds": seconds})
    return directory, seconds


def held_bio_run(capture_dir, result_dir, kind, cache, say, held_at_truth=()):
    """``result_dir``'s polarimetric maps with truth put in (``kind``; ``"stages"`` leaves them
    as the stages wrote them), fed to the biophysical stage in a copy of the result directory,
    the skin unknowns named in ``held_at_truth`` given at the truth's face mean; returns the
    copy and its bio seconds."""
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.inverse import reconstruct
    from polarbssrdf.inverse.results.directory import read_result, write_result
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.exr import read_exr, write_exr

    name = f"{Path(result_dir).name}_{kind}" + "".join(f"_{n}_truth" for n in held_at_truth)
    directory = Path(cache) / "results" / name
    if is_done(directory):
        return directory, json.loads((directory / DONE).read_text())["seconds"]
    say(f"  biophysical stage on {directory.name}")
    fresh(directory)
    shutil.copytree(result_dir, directory, ignore=shutil.ignore_patterns("bio", DONE),
                    dirs_exist_ok=True)
    manifest = read_result(directory)
    manifest.maps = [r for r in manifest.maps if r["stage"] != "bio"]
    write_result(directory, manifest)
    capture = load_capture(capture_dir, check_images=False)
    bands = [band.name for band in capture.manifest.bands]
    valid = np.asarray(texel_atlas(to_mitsuba(capture.load_mesh()),
                                   manifest.texture_size).valid, bool)
    for record in manifest.maps if kind != "stages" else ():
        path = directory / record["path"]
        channels, metadata = read_exr(path)
        truth = capture.truth_maps(int(record["frame"]))
        channels["eta"] = np.where(valid, truth["eta"], channels["eta"]).astype(np.float32)
        if kind.startswith("truth_albedo"):
            noise = TRUTH_ALBEDO_NOISE if kind == "truth_albedo" else 0.0
            for index, band in enumerate(bands):
                t = np.nan_to_num(np.asarray(truth[f"rho_sss.{band}"], np.float64))
                draw = np.random.default_rng([7, int(record["frame"]), index]).standard_normal(t.shape)
                channels[f"rho_sss.{band}"] = (t * (1.0 + noise * draw)).astype(np.float32)
            channels["confidence"] = valid.astype(np.float32)
        write_exr(path, channels, metadata=metadata, overwrite=True)
    truth = capture.truth_maps(0)
    bio = {n: float(np.mean(np.asarray(truth[n], np.float64)[valid])) for n in held_at_truth}
    if "gamma" in bio:
        bio["oxygenation"] = "held"
    started = time.perf_counter()
    result = reconstruct(capture_dir, directory, stages=("bio",), progress=False,
                         config={"bio": bio} if bio else None)
    if result.failed:
        raise RuntimeError(f"bio on {directory}: frames failed: {result.failed}")
    seconds = {"bio": time.perf_counter() - started}
    mark_done(directory, {"from": str(result_dir), "kind": kind, "held_at_truth": bio,
                          "seconds": seconds})
    return directory, seconds


def albedo_budget(maps, truth, mask, bands):
    """The relative albedo error on ``mask`` split into band-common, per-band and bias parts."""
    e = np.stack([(np.asarray(maps[f"rho_sss.{b}"], np.float64)[mask]
                   - np.asarray(truth[f"rho_sss.{b}"], np.float64)[mask])
                  / np.asarray(truth[f"rho_sss.{b}"], np.float64)[mask] for b in bands])
    common = e.mean(axis=0)
    rest = e - common
    with np.errstate(invalid="ignore", divide="ignore"):  # a band without error: no correlation
        correlation = np.corrcoef(e)
    off = correlation[~np.eye(len(bands), dtype=bool)]
    return {"texels": int(mask.sum()),
            "rms": float(np.sqrt(np.mean(e ** 2))),
            "common_rms": float(np.sqrt(np.mean(common ** 2))),
            "per_band_rms": float(np.sqrt(np.mean(rest ** 2))),
            "bias": float(e.mean()),
            # robust to the few texels far off (rms is dominated by them)
            "common_median_abs": float(np.median(np.abs(common))),
            "per_band_median_abs": float(np.median(np.abs(rest))),
            # var(c) / mean_b var(e_b): 1 when the bands' errors are one common factor
            "common_share_of_variance": float(np.var(common)
                                              / max(np.mean(np.var(e, axis=1)), 1e-30)),
            "mean_band_correlation": float(off.mean()),
            "bands": {b: {"bias": float(e[i].mean()), "rms": float(np.sqrt(np.mean(e[i] ** 2))),
                          "per_band_rms": float(np.sqrt(np.mean(rest[i] ** 2)))}
                      for i, b in enumerate(bands)}}


def score_row(row, capture_dir, result_dir):
    """Scores of a finished row: albedo budgets of its polarimetric maps, chromophore MAEs."""
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.geometry.face import face_region_masks
    from polarbssrdf.inverse.evaluation.scores import (
        biophysical_scores,
        evaluate_maps,
        evaluate_result,
    )
    from polarbssrdf.inverse.results.directory import read_result, read_stage_maps
    from polarbssrdf.io import load_capture

    capture = load_capture(capture_dir, check_images=False)
    manifest = read_result(result_dir)
    bands = list(capture.manifest.band_names)
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), manifest.texture_size)
    regions = face_region_masks(manifest.texture_size)
    face = np.asarray(atlas.valid, bool) & (regions["forehead"] | regions["cheeks"])
    scores = {"albedo": {}, "bio": {}, "eta_mae": {}, "bio_forehead_cheeks": {}}
    for record in sorted(manifest.maps, key=lambda r: r["frame"]):
        stage, frame = record["stage"], int(record["frame"])
        if stage == "bio":
            continue
        maps = read_stage_maps(result_dir, stage, frame)
        truth = capture.truth_maps(frame)
        evaluation, scored = evaluate_maps(maps, truth, atlas, bands, manifest.units)
        entry = albedo_budget(maps, truth, scored, bands)
        entry["forehead_cheeks"] = albedo_budget(maps, truth, scored & face, bands)
        entry["stage"] = stage
        entry["scorer_mean_relative_error"] = evaluation["rho_sss"]["mean_relative_error"]
        entry["scorer_constant_relative_error"] = evaluation["rho_sss"]["mean_constant_relative_error"]
        scores["albedo"][str(frame)] = entry
        scores["eta_mae"][str(frame)] = {"mae": evaluation["eta"]["mae"],
                                         "constant_mae": evaluation["eta"]["constant_mae"]}
    for record in manifest.maps:
        if record["stage"] != "bio":
            continue
        frame = int(record["frame"])
        evaluation = evaluate_result(result_dir, capture, frame, "bio", holdout=False,
                                     atlas=atlas)
        scores["bio"][str(frame)] = {p: {"mae_pct": 100 * evaluation["maps"][p]["mae_of_range"],
                                         "constant_pct":
                                             100 * evaluation["maps"][p]["constant_mae_of_range"]}
                                     for p in PARAMETERS}
        scores["bio"][str(frame)]["texels"] = evaluation["texels_scored"]
        # the same scorer on the forehead and cheeks only (the well-measured part of the face)
        inside, scored = biophysical_scores(read_stage_maps(result_dir, "bio", frame),
                                            capture.truth_maps(frame), face)
        scores["bio_forehead_cheeks"][str(frame)] = {
            p: {"mae_pct": 100 * inside[p]["mae_of_range"],
                "constant_pct": 100 * inside[p]["constant_mae_of_range"]} for p in PARAMETERS}
        scores["bio_forehead_cheeks"][str(frame)]["texels"] = int(scored.sum())
    frames = sorted(scores["bio"], key=int)
    for name in ("bio", "bio_forehead_cheeks"):
        scores[f"{name}_mean"] = {p: {k: float(np.mean([scores[name][f][p][k] for f in frames]))
                                      for k in ("mae_pct", "constant_pct")} for p in PARAMETERS}
    return scores


def run_row(row, cache, say):
    """A row's capture, stages and scores (all cached); its JSON record."""
    record_path = (Path(cache) / "rows"
                   / f"{row.name}_T{row.capture.texture}_{key(dataclasses.asdict(row))}.json")
    if record_path.is_file():
        return json.loads(record_path.read_text())
    say(f"row {row.name} ({row.capture.texture}^2)")
    started = time.perf_counter()
    capture_dir, synth_seconds = make_capture(row.capture, cache, say)
    if row.geometry_held:
        capture_dir = geometry_held_capture(capture_dir, cache, say)
    result_dir, seconds = run_stages(capture_dir, row.capture, cache, say, row.geometry_held)
    if row.bio_input != "stages" or row.held_at_truth:
        result_dir, bio_seconds = held_bio_run(capture_dir, result_dir, row.bio_input, cache, say,
                                               row.held_at_truth)
        seconds = dict(seconds, **{f"bio ({row.bio_input})": bio_seconds["bio"]})
    record = {"row": row.name, "spec": dataclasses.asdict(row), "capture": str(capture_dir),
              "result": str(result_dir), "synth_seconds": synth_seconds, "seconds": seconds,
              "scores": score_row(row, capture_dir, result_dir),
              "wall_seconds_this_call": time.perf_counter() - started}
    from polarbssrdf.io.atomic import atomic_write_text

    record_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(record_path, json.dumps(record, indent=1) + "\n", overwrite=True)
    return record


def table(records):
    """The budget as a Markdown table (albedo of the static frame; chromophores mean over frames)."""
    head = ("| row | T | static rho_sss: rel. err. (scorer) | common rms | per-band rms | bias "
            "| dynamic f1: common / per-band / bias | C_m | beta_m | C_h_out | C_h_in |")
    lines = [head, "|" + "---|" * 11]
    for record in records:
        s = record["scores"]
        a = s["albedo"].get("0")
        d = s["albedo"].get("1")
        cells = [record["row"], str(record["spec"]["capture"]["texture"])]
        if a:
            cells += [f"{100 * a['scorer_mean_relative_error']:.2f}%", f"{100 * a['common_rms']:.2f}%",
                      f"{100 * a['per_band_rms']:.2f}%", f"{100 * a['bias']:+.2f}%"]
        else:
            cells += ["-"] * 4
        cells.append(f"{100 * d['common_rms']:.2f} / {100 * d['per_band_rms']:.2f} / "
                     f"{100 * d['bias']:+.2f}%" if d else "-")
        for p in PARAMETERS:
            b = s["bio_mean"][p]
            cells.append(f"{b['mae_pct']:.1f}% ({b['constant_pct']:.1f}%)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def region_table(records):
    """The static albedo budget and chromophore MAEs (mean over frames) on forehead + cheeks."""
    lines = ["| row | T | texels | common rms | per-band rms | bias | C_m | beta_m | C_h_out "
             "| C_h_in |", "|" + "---|" * 10]
    for record in records:
        s = record["scores"]
        a = s["albedo"]["0"]["forehead_cheeks"]
        cells = [record["row"], str(record["spec"]["capture"]["texture"]), str(a["texels"]),
                 f"{100 * a['common_rms']:.2f}%", f"{100 * a['per_band_rms']:.2f}%",
                 f"{100 * a['bias']:+.2f}%"]
        for p in PARAMETERS:
            b = s["bio_forehead_cheeks_mean"][p]
            cells.append(f"{b['mae_pct']:.1f}% ({b['constant_pct']:.1f}%)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", default=",".join(DEMO_ROWS),
                        help=f"demo-face rows, from {', '.join(DEMO_ROWS)} and views_8 "
                             "(default: all; '' for none)")
    parser.add_argument("--texture", type=int, default=256,
                        help="texture size of the demo-face rows (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=2,
                        help="frames of the demo-face captures: frame 0 static, the rest dynamic "
                             "(default: %(default)s)")
    parser.add_argument("--sweep", action="store_true",
                        help="also the Table 2 sweep (3 skin types x forehead/cheek, raw and "
                             "noise-free)")
    parser.add_argument("--sweep-texture", type=int, default=128,
                        help="texture size of the sweep rows (default: %(default)s)")
    parser.add_argument("--cache", type=Path, default=Path("budget-cache"),
                        help="directory of captures, results and row scores, reused by reruns")
    parser.add_argument("--iterations", type=int, default=None,
                        help="epochs of the static stage and of each dynamic frame (default: "
                             "the config's 150 and 30; fewer only to try the script out)")
    parser.add_argument("--out", type=Path, default=None, help="write the budget as JSON")
    args = parser.parse_args(argv)
    global ITERATIONS
    ITERATIONS = args.iterations

    import mitsuba as mi

    import polarbssrdf

    mi.set_variant("llvm_ad_mono_polarized")
    polarbssrdf.register_plugins()

    def say(message):
        print(f"[{datetime.datetime.now():%H:%M:%S}] {message}", file=sys.stderr, flush=True)

    available = demo_rows(args.texture, args.frames)
    names = [n for n in args.rows.split(",") if n]
    unknown = [n for n in names if n not in available]
    if unknown:
        parser.error(f"unknown rows {', '.join(unknown)}; known: {', '.join(available)}")
    rows = [available[n] for n in names]
    if args.sweep:
        rows += list(sweep_rows(args.sweep_texture).values())
    records = []
    for row in rows:
        records.append(run_row(row, args.cache, say))
        say(f"  done: {row.name}")
    print(table(records))
    print("\nOn the forehead and cheeks only (static albedo and chromophores):\n")
    print(region_table(records))
    if args.out:
        from polarbssrdf.io.atomic import atomic_write_text

        document = {"schema": "polarbssrdf.bench.chromophore_budget", "schema_version": 1,
                    "created_utc": datetime.datetime.now(datetime.timezone.utc)
                    .isoformat(timespec="seconds"),
                    "machine": {"cores": os.cpu_count(), "processor": platform.processor()},
                    "arguments": {k: str(v) for k, v in vars(args).items()},
                    "rows": records}
        atomic_write_text(args.out, json.dumps(document, indent=1) + "\n", overwrite=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
