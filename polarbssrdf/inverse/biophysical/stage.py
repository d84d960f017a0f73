"""The biophysical stage of ``reconstruct``: result maps -> ``bio/maps_f####.exr``, previews, summary.

Reads the subsurface albedo maps an earlier stage registered in
``result.json`` (the per-frame ``dynamic`` maps where they exist, else the
``static`` maps), fits melanin and hemoglobin with
:func:`polarbssrdf.inverse.biophysical.fit.fit_biophysical`, and writes per frame

* ``bio/maps_f####.exr``: ``C_m, beta_m, C_h_out, C_h_in`` (volume fractions)
  and their posterior standard deviations ``<map>_std`` (same units; the face's
  thickness and oxygenation, the index's error marginalized), ``residual`` (RMS
  over bands of rendered minus input albedo) and ``flagged`` (1 where the input
  was invalid and the values come from the prior); the metadata's ``noise.face``
  holds the face's held epidermal thickness (mm) and its estimated oxygenation with
  their variances (``oxygenation``: how the estimate was made);
* ``bio/previews/<map>_f####.png`` with colour bars and units;
* ``bio/summary.json``: mean and standard deviation per region and frame in
  the layout of the supplement's Table 2 (:func:`region_summary`).

Frames: the first frame is fitted from the per-texel start; every later
frame starts from the first frame's maps and, by default, holds ``C_m`` and
``beta_m`` there (melanin does not change within seconds; ``bio.free_melanin``
frees them), with the first frame's std. Each frame is :func:`fit_frame`, a pure function of (the first
frame's biophysical maps, that frame's albedo maps), so frames can run in
parallel; a frame whose file exists is skipped on resume.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import drjit as dr
import numpy as np
from PIL import Image
from tqdm import tqdm

from polarbssrdf._threads import one_blas_thread
from polarbssrdf.geometry import texel_atlas, to_mitsuba
from polarbssrdf.geometry.face import face_mesh, face_region_masks
from polarbssrdf.inverse.biophysical.config import bio_config
from polarbssrdf.inverse.biophysical.fit import fit_biophysical
from polarbssrdf.inverse.biophysical.model import PARAMETERS
from polarbssrdf.inverse.frames import run_frames
from polarbssrdf.inverse.observations.footprint import capture_blur_variance_mm2
from polarbssrdf.inverse.results.directory import (
    read_result,
    read_stage_maps,
    register_map,
    stage_map_path,
    write_metrics,
)
from polarbssrdf.inverse.results.previews import write_map_previews
from polarbssrdf.io import load_capture
from polarbssrdf.io.atomic import atomic_write_text
from polarbssrdf.io.exr import read_exr, write_exr
from polarbssrdf.variants import select_variant

STAGE = "bio"
SUMMARY_FILE = "summary.json"
SOURCE_STAGES = ("dynamic", "static")
"""Where the albedo maps come from, first choice first."""

UNITS = {"C_m": "volume fraction", "beta_m": "fraction of melanin",
         "C_h_out": "volume fraction", "C_h_in": "volume fraction", "residual": "albedo",
         "flagged": "unitless"}
UNITS.update({f"{name}_std": UNITS[name] for name in PARAMETERS})
"""Units of the stage's channels (``C_m``: melanin in the epidermis; ``beta_m``: eumelanin
share of it; ``C_h_out``/``C_h_in``: blood in the epidermis/dermis)."""


def source_frames(outdir):
    """``{frame: stage}`` of the albedo maps the stage reads: a frame's ``dynamic`` maps where
    they exist, else its ``static`` maps; in frame order (the static frame first)."""

    manifest = read_result(outdir)
    sources = {}
    for stage in reversed(SOURCE_STAGES):  # static first, then dynamic overrides
        for record in manifest.maps:
            if record["stage"] == stage:
                sources[record["frame"]] = stage
    if not sources:
        raise FileNotFoundError(
            f"{Path(outdir) / 'result.json'} lists no static or dynamic maps: the biophysical "
            "stage fits their subsurface albedo; run the static stage first "
            "('--stages static,bio')")
    static = sorted(f for f, stage in sources.items() if stage == "static")
    others = sorted(f for f in sources if f not in static)
    return {frame: sources[frame] for frame in static + others}


def albedo_inputs(maps, bands):
    """The channels :func:`fit_biophysical` reads from a result's map file: the albedo per band,
    the index, confidence and the albedo's std per band when the file has them.

    Not ``eta_std``: the static stage's index std is wider than the index's error on the demo
    (its median 0.038 against an error of 0.021 rms, 2-std coverage 0.993), and with it the
    chromophores' coverage rose to 0.99 there; the config's index spread (0.015) is used until
    that std is right (docs/biophysical.md)."""
    wanted = ([f"rho_sss.{band.name}" for band in bands] + ["eta", "confidence"]
              + [f"rho_sss.{band.name}_std" for band in bands])
    missing = [name for name in wanted[:len(bands)] if name not in maps]
    if missing:
        raise ValueError(f"the maps lack {', '.join(missing)} (they have "
                         f"{', '.join(sorted(maps))})")
    return {name: maps[name] for name in wanted if name in maps}


def fit_frame(albedo_maps, bands, atlas, config, reference=None, free_melanin=False, progress=None):
    """One frame's biophysical fit: a pure function of its inputs.

    Parameters
    ----------
    albedo_maps : dict
        ``rho_sss.<band>`` (and optional ``eta``, ``confidence``) of the frame.
    reference : dict, optional
        The first frame's biophysical maps: the start, and (unless
        ``free_melanin``) the held values of ``C_m`` and ``beta_m`` (with their
        ``_std`` channels where it has them).
    progress : callable, optional
        Called with a message per Gauss-Newton step and round.

    Returns
    -------
    BiophysicalResult
    """
    held = held_std = None
    if reference is not None and not free_melanin:
        held = {name: reference[name] for name in ("C_m", "beta_m")}
        held_std = {name: reference[f"{name}_std"] for name in held if f"{name}_std" in reference}
    start = None if reference is None else {name: reference[name] for name in PARAMETERS}
    return fit_biophysical(albedo_maps, bands, atlas, config, start=start, held=held,
                           progress=progress, held_std=held_std)


def region_masks(capture, mesh, atlas):
    """``name -> (T, T) bool`` regions of the summary: ``surface`` always; on the embedded
    face (same landmark UVs) ``forehead``, ``cheek_left``, ``cheek_right``, ``cheeks``; and
    any ``regions/<name>.png`` masks in the capture directory (non-zero = inside, resampled
    to the texture)."""

    T = atlas.resolution
    masks = {"surface": np.asarray(atlas.valid, bool)}
    canonical = face_mesh(0)
    n = len(canonical.uvs)
    if len(mesh.uvs) >= n and np.allclose(mesh.uvs[:n], canonical.uvs, atol=1e-6):
        for name, mask in face_region_masks(T, mesh).items():
            masks[name] = mask & atlas.valid
    directory = Path(capture.directory) / "regions"
    if directory.is_dir():

        for path in sorted(directory.glob("*.png")):
            image = Image.open(path).convert("L").resize((T, T), Image.NEAREST)
            # an image of the UV layout has OBJ v = 1 in its top row, which is row 0 of the
            # package's maps (Mitsuba v = 1 - OBJ v): no flip
            mask = np.asarray(image) > 0
            masks[path.stem] = mask & atlas.valid
    return masks


def region_summary(maps_per_frame, masks):
    """Mean and standard deviation per region and frame, Table 2's layout.

    Returns ``{"parameters": [...], "regions": {region: {"texels": n, "frames":
    {frame: {parameter: {"mean", "std"}}}}}}``; texels flagged as invalid input
    are left out.
    """
    regions = {}
    for name, mask in masks.items():
        frames = {}
        texels = 0
        for frame, maps in sorted(maps_per_frame.items()):
            inside = mask & (np.asarray(maps.get("flagged", 0.0)) == 0)
            texels = int(inside.sum())
            if texels == 0:
                continue
            frames[str(frame)] = {p: {"mean": float(np.mean(maps[p][inside])),
                                      "std": float(np.std(maps[p][inside]))} for p in PARAMETERS}
        if frames:
            regions[name] = {"texels": texels, "frames": frames}
    return {"parameters": list(PARAMETERS), "units": {p: UNITS[p] for p in PARAMETERS},
            "regions": regions}


def write_bio_previews(channels, directory, frame):
    """Previews of the four maps and the residual (colour bars, units)."""

    shown = {name: channels[name] for name in (*PARAMETERS, *(f"{n}_std" for n in PARAMETERS), "residual")
             if name in channels}
    return write_map_previews(shown, directory, f"f{frame:04d}", units=UNITS)


_ATLASES = {}


def _atlas(capture, texture_size):
    """The texel atlas of the capture's mesh (kept per process: frames share it)."""

    key = (str(capture.directory), int(texture_size))
    if key not in _ATLASES:
        _ATLASES.clear()
        _ATLASES[key] = texel_atlas(to_mitsuba(capture.load_mesh()), texture_size)
    return _ATLASES[key]


@one_blas_thread()
def write_frame(capture, outdir, frame, source, texture_size, settings, reference=None, progress=None):
    """Fit one frame and write its map file (not registered) and previews; returns its channels.

    A pure function of (the capture's bands and mesh, ``outdir``'s ``source``
    maps of ``frame``, ``reference``: the first frame's biophysical maps or
    None), so later frames can run on Dask workers; its BLAS runs on one thread
    wherever it runs (:func:`~polarbssrdf._threads.one_blas_thread`).
    """

    config, free_melanin = bio_config(settings)
    bands = list(capture.manifest.bands)
    inputs = albedo_inputs(read_stage_maps(outdir, source, frame), bands)
    atlas = _atlas(capture, texture_size)
    if config.capture_blur_mm is None:
        # every polarization camera of the frame, a held-out one too: the median footprint
        # over the face barely moves with one camera more
        variance, _ = capture_blur_variance_mm2(capture, atlas, frame)
        config = dataclasses.replace(config, capture_blur_mm=float(np.sqrt(variance)))
    try:
        result = fit_frame(inputs, bands, atlas, config, reference, free_melanin, progress)
    except ValueError as error:
        raise ValueError(f"bio, frame {frame} ({source} maps): {error}") from None
    channels = result.channels()
    path = Path(outdir) / stage_map_path(STAGE, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, channels, overwrite=True,
              metadata={"stage": STAGE, "frame": int(frame), "source_stage": source,
                        "history": result.history, "seconds": round(result.seconds, 3),
                        "noise": result.noise, "capture_blur_mm": round(config.capture_blur_mm, 4),
                        "held": [] if reference is None or free_melanin else ["C_m", "beta_m"]})
    write_bio_previews(channels, Path(outdir) / STAGE / "previews", frame)
    return channels


def reference_maps(first):
    """What a later frame takes from the first frame's map file: the four maps and their std."""
    wanted = (*PARAMETERS, *(f"{n}_std" for n in PARAMETERS))
    return {name: first[name] for name in wanted if name in first}


class FitProgress:
    """The fit's messages on a tqdm bar: a step advances it, a round's summary is its postfix."""

    def __init__(self, bar):
        self.bar = bar

    def __call__(self, message):
        if ", step " in message:
            self.bar.update(1)
        self.bar.set_postfix_str(message.removeprefix("bio "), refresh=True)


class BioFrameTask:
    """:func:`write_frame` for a later frame with everything but the frame bound (picklable)."""

    def __init__(self, capture_dir, outdir, texture_size, settings, sources, variant, threads):
        self.capture_dir, self.outdir = str(capture_dir), str(outdir)
        self.texture_size, self.settings, self.sources = int(texture_size), settings, sources
        self.variant, self.threads = variant, threads

    def __call__(self, frame):


        started = time.perf_counter()
        select_variant(self.variant)
        if self.threads is not None:
            dr.set_thread_count(int(self.threads))
        capture = load_capture(self.capture_dir, check_images=False, frames=[])
        first = read_stage_maps(self.outdir, STAGE, next(iter(self.sources)))
        write_frame(capture, self.outdir, frame, self.sources[frame], self.texture_size,
                    self.settings, reference_maps(first))
        return {"frame": int(frame), "seconds": round(time.perf_counter() - started, 3)}


def run_bio_stage(capture, outdir, texture_size, settings=None, *, resume=False, progress=True,
                  workers=None, scheduler=None, variant="llvm_ad_mono_polarized", label=STAGE):
    """Fit every source frame of ``outdir``, register the maps, write the summary.

    The first frame (the static one) runs here; the others start from it and
    run serially, or on Dask with ``workers`` / ``scheduler``
    (:mod:`polarbssrdf.inverse.frames`). Frames whose file exists are skipped
    when ``resume``; ``label`` names the stage on the progress bar. The loss history
    of every frame goes to ``OUTDIR/metrics.json`` under ``bio``. Returns the summary
    dict, with ``failed``: ``{frame: reason}``.
    """

    outdir = Path(outdir)
    bio_config(settings)  # a bad config's error before any work
    sources = source_frames(outdir)
    frames = list(sources)
    started = time.perf_counter()
    first = frames[0]
    path = outdir / stage_map_path(STAGE, first)
    if not (resume and path.is_file()):
        config, _ = bio_config(settings)
        # the first frame runs for minutes at 256^2 and up: a bar over its Gauss-Newton steps
        with tqdm(total=config.rounds * config.iterations, desc=f"{label} frame {first}", unit="step",
                  disable=not progress) as bar:
            write_frame(capture, outdir, first, sources[first], texture_size, settings,
                        progress=FitProgress(bar))
    register_map(outdir, STAGE, first, read_exr(path)[0])
    later = [t for t in frames[1:]
             if not (resume and (outdir / stage_map_path(STAGE, t)).is_file())]
    task = BioFrameTask(capture.directory, outdir, texture_size, settings, sources, variant,
                        1 if (workers or scheduler) else None)
    _, failures = run_frames(task, later, workers=workers, scheduler=scheduler,
                             progress=progress, description=label)
    fitted, histories = {}, {}
    for frame in frames:
        path = outdir / stage_map_path(STAGE, frame)
        if frame in failures or not path.is_file():
            continue
        fitted[frame], metadata = read_exr(path)
        register_map(outdir, STAGE, frame, fitted[frame])
        histories[str(frame)] = (metadata or {}).get("history", [])
    write_metrics(outdir, STAGE, histories)
    atlas = _atlas(capture, texture_size)
    summary = region_summary(fitted, region_masks(capture, capture.load_mesh(), atlas))
    summary.update(source_stages={str(f): sources[f] for f in fitted}, frames=sorted(fitted),
                   seconds=round(time.perf_counter() - started, 3))
    atomic_write_text(outdir / STAGE / SUMMARY_FILE, json.dumps(summary, indent=1) + "\n",
                      overwrite=True)
    summary["failed"] = failures
    return summary
