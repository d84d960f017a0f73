"""The dynamic stage: per-frame maps with the static stage's index and roughness (supplement sec. 5.2).

For every frame ``t`` of a sequence but the static one, eq. 36: ``rho_s^t``,
``rho_ss^t``, ``rho_sss^t`` per band and ``H^t`` from that frame's images,
with ``eta``, ``alpha_s`` and ``alpha_ss`` held at the static maps, by the
static stage's own observations, model, losses and optimizer
(:func:`polarbssrdf.inverse.polarimetric.fit.run_polarimetric_fit`): ``L_sss``, ``L_s`` and ``L_phi`` with
weights 1, 1, 0.2 (no ``L_psi``: the index is fixed), ``H^t`` regularized as
in eq. 33-34 with 0.001 and 500, and the albedos pulled toward the static
maps (eq. 38-39; weights and the subsurface pull's robust weighting in
:data:`~polarbssrdf.inverse.polarimetric.config.DYNAMIC_WEIGHTS` and
:func:`~polarbssrdf.inverse.polarimetric.optimize._temporal_albedo_term`); the
epochs per frame are ``dynamic.iterations`` (default
:data:`~polarbssrdf.inverse.polarimetric.config.DEFAULT_DYNAMIC_ITERATIONS`).
Each frame starts from the static maps (displacement included). A map the static stage
held at the face's level (its views could not tell it per texel,
:mod:`~polarbssrdf.inverse.polarimetric.face_level`) is written at that level with its
std in every frame, as the static stage writes it: a frame has the same views, and its
per-texel ``rho_s`` was 1.08x the constant map's error on the demo with a std that covered
half its errors (2-std coverage 0.53). The frame still fits it per texel, as the static
stage does before it holds a map: the geometry fitted with ``rho_s`` held from the start
took up its variation (normals 0.76 deg against 0.65 on the demo's frames).

A frame is :func:`fit_frame`, a pure function of (the static result on disk,
that frame's images) that writes ``dynamic/maps_f####.exr`` atomically and
returns its record; the caller registers it in ``result.json``
(:mod:`polarbssrdf.inverse.frames` runs frames serially or on Dask).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import drjit as dr
import numpy as np

from polarbssrdf._threads import one_blas_thread
from polarbssrdf.errors import option
from polarbssrdf.geometry import texel_atlas, to_mitsuba
from polarbssrdf.inverse.frames import run_frames
from polarbssrdf.inverse.observations.build import load_or_build_observations
from polarbssrdf.inverse.polarimetric.config import merged_config, parse_dynamic
from polarbssrdf.inverse.polarimetric.fit import initial_parameters, run_polarimetric_fit
from polarbssrdf.inverse.polarimetric.optimize import MapParameters
from polarbssrdf.inverse.polarimetric.static import with_capture_blur
from polarbssrdf.inverse.results.directory import (
    OBSERVATIONS_DIR,
    RESULT_FILE,
    read_result,
    read_stage_maps,
    register_map,
    stage_map_path,
    write_confidence,
    write_metrics,
)
from polarbssrdf.io import load_capture
from polarbssrdf.io.exr import read_exr, write_exr
from polarbssrdf.variants import select_variant

STAGE = "dynamic"
OPTIMIZED = ("rho_s", "rho_ss", "displacement")
"""The maps a frame's gradient steps move (``rho_sss`` is solved in closed form)."""

HELD = ("eta", "alpha_s", "alpha_ss")
"""The maps a frame takes from the static result."""


def dynamic_settings(config):
    """``(StaticConfig for a frame, weights)``: the config with its ``dynamic`` overrides."""
    iterations, weights = parse_dynamic(config.dynamic, config.iterations)
    # the regularization scale and the amplitude variables act on the static stage only
    frame_config = dataclasses.replace(config, iterations=iterations, regularization_scale=1.0,
                                       glossy_amplitudes=False)
    return frame_config, weights


def static_frame_of(outdir) -> int:
    """The frame the static stage fitted in ``outdir`` (``reconstruct --frame``; a result holds
    one static frame); a clear error when there are no static maps."""
    if not (Path(outdir) / RESULT_FILE).is_file():
        raise FileNotFoundError(f"{outdir} holds no {RESULT_FILE}: the dynamic stage starts from "
                                "the static stage's maps; run it first "
                                f"({option('stages', 'static,dynamic')})")
    frames = sorted(int(r["frame"]) for r in read_result(outdir).maps if r["stage"] == "static")
    if not frames:
        raise FileNotFoundError(f"{outdir}/{RESULT_FILE} lists no static maps: run the static stage "
                                f"first ({option('stages', 'static,dynamic')})")
    return frames[0]


def static_maps(outdir):
    """The static stage's maps in ``outdir`` (of the frame it fitted); a clear error when there
    are none."""
    return read_stage_maps(outdir, "static", static_frame_of(outdir))


def static_held_maps(outdir):
    """The static maps held at the face's level (``held_at_face_mean`` of their file)."""
    frame = static_frame_of(outdir)
    record = read_result(outdir).record("static", frame)
    _, metadata = read_exr(Path(outdir) / record["path"])
    return dict((metadata or {}).get("held_at_face_mean", {}))


@one_blas_thread()
def fit_frame(capture_dir, outdir, frame, texture_size, config_json, holdout=(), *,
              variant="llvm_ad_mono_polarized", threads=None, progress=False):
    """Fit one frame and write ``dynamic/maps_f####.exr`` (not registered); returns its record.

    Pure: reads the capture and ``outdir``'s static maps, writes only that
    frame's files (its observation cache, checkpoint, maps). ``config_json``
    is ``StaticConfig.to_json()`` (plain data, so the call can travel to a
    Dask worker). ``threads``: Dr.Jit's thread count in this process. BLAS runs on
    one thread wherever the frame runs (:func:`~polarbssrdf._threads.one_blas_thread`).
    """
    started = time.perf_counter()
    select_variant(variant)
    if threads is not None:
        dr.set_thread_count(int(threads))
    outdir = Path(outdir)
    config = merged_config(config_json)
    frame_config, weights = dynamic_settings(config)
    static = static_maps(outdir)
    capture = load_capture(capture_dir, check_images=False, frames=[frame])
    if frame not in [f.index for f in capture.manifest.frames]:
        raise ValueError(f"capture {capture_dir} has no frame {frame}")
    store = load_or_build_observations(
        capture, frame, texture_size, outdir / OBSERVATIONS_DIR / f"f{frame:04d}.zarr",
        exclude_cameras=tuple(holdout), progress=progress)
    missing = [f"rho_sss.{band}" for band in store.bands if f"rho_sss.{band}" not in static]
    if missing:
        raise ValueError(f"the static maps lack {', '.join(missing)}: frame {frame}'s bands "
                         "differ from the static frame's")
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), texture_size)
    frame_config = with_capture_blur(frame_config, capture, atlas, frame, holdout)
    face_level = {name: record for name, record in static_held_maps(outdir).items()
                  if name in HELD or name in OPTIMIZED}
    maps, _ = initial_parameters(frame_config, texture_size, len(store.bands), static)
    rho_sss = np.stack([np.asarray(static[f"rho_sss.{band}"], np.float32) for band in store.bands])
    params = MapParameters(maps, rho_sss, frame_config.learning_rates, OPTIMIZED,
                           frame_config.optimizer)
    params.set_reference(static, rho_sss, weights)
    stage_dir = outdir / STAGE
    stage_dir.mkdir(parents=True, exist_ok=True)
    result = run_polarimetric_fit(store, atlas, frame_config, checkpoint=stage_dir /
                                  f"checkpoint_f{frame:04d}.npz", progress=progress,
                                  weights=weights, optimized=OPTIMIZED,
                                  description=f"frame {frame}", params=params)
    # held, and fitted but held at the face level by the static stage: exactly the static
    # values (the fill leaves them alone)
    for name in dict.fromkeys((*HELD, *face_level)):
        for channel in (name, f"{name}_std"):
            if channel in static:
                result.maps[channel] = np.asarray(static[channel], np.float32)
        result.held.pop(name, None)
    result.held.update(face_level)
    path = outdir / stage_map_path(STAGE, frame)
    metadata = {"stage": STAGE, "frame": int(frame), "config": config.to_json(),
                "weights": weights, "texel_views": len(store), "history": result.history,
                "confidence": result.confidence, "held_at_face_mean": result.held,
                "capture_blur_mm": frame_config.capture_blur_mm,
                "seconds": round(time.perf_counter() - started, 3)}
    write_exr(path, result.maps, metadata=metadata, overwrite=True)
    dr.flush_malloc_cache()
    return {"frame": int(frame), "path": str(path), "channels": sorted(result.maps),
            "seconds": round(time.perf_counter() - started, 3), "texel_views": len(store),
            "history": result.history}


class FrameTask:
    """``fit_frame`` with everything but the frame bound: picklable, for Dask workers."""

    def __init__(self, capture_dir, outdir, texture_size, config_json, holdout, variant, threads):
        self.arguments = (str(capture_dir), str(outdir), int(texture_size), config_json,
                          tuple(holdout))
        self.variant, self.threads = variant, threads

    def __call__(self, frame):
        capture_dir, outdir, texture, config_json, holdout = self.arguments
        return fit_frame(capture_dir, outdir, frame, texture, config_json, holdout,
                         variant=self.variant, threads=self.threads)


def run_dynamic_stage(capture, outdir, texture_size, config, *, holdout=(), static_frame=None,
                      frames=None, workers=None, scheduler=None, resume=False, progress=True,
                      variant="llvm_ad_mono_polarized", label=STAGE):
    """Fit every frame but ``static_frame`` (or ``frames``) and register the finished ones.

    ``static_frame`` is the frame of the static maps in ``outdir`` (None: whichever it is);
    every frame starts from those maps.

    Frames whose map file exists are skipped when ``resume``; ``label`` names the stage
    on the progress bar. Returns
    ``{"done": [frames], "skipped": [frames], "failed": {frame: reason}, "seconds",
    "confidence": {frame: confidence summary}}``.
    """
    started = time.perf_counter()
    outdir = Path(outdir)
    fitted = static_frame_of(outdir)  # the clear error before any work
    if static_frame is None:
        static_frame = fitted
    elif int(static_frame) != fitted:
        raise ValueError(f"{outdir}/{RESULT_FILE} holds the static maps of frame {fitted}, not "
                         f"{static_frame}: the dynamic stage starts from the static frame's maps")
    dynamic_settings(config)  # and a bad config's
    if frames is None:
        frames = [f.index for f in capture.manifest.frames if f.index != static_frame]
    skipped = [t for t in frames if resume and (outdir / stage_map_path(STAGE, t)).is_file()]
    todo = [t for t in frames if t not in skipped]
    # one Dr.Jit thread per worker process; in-process frames use this process's cores
    threads = 1 if (workers or scheduler) else None
    task = FrameTask(capture.directory, outdir, texture_size, config.to_json(), holdout, variant,
                     threads)
    records, failures = run_frames(task, todo, workers=workers, scheduler=scheduler,
                                   progress=progress, description=label)
    metrics, confidence = {}, {}
    for frame in sorted(records) + skipped:
        channels, metadata = read_exr(outdir / stage_map_path(STAGE, frame))
        register_map(outdir, STAGE, frame, channels)
        metrics[str(frame)] = (metadata or {}).get("history", [])
        if (metadata or {}).get("confidence"):
            confidence[frame] = metadata["confidence"]
    write_metrics(outdir, STAGE, metrics)
    write_confidence(outdir, STAGE, confidence)
    return {"done": sorted(records), "skipped": skipped, "failed": failures,
            "seconds": round(time.perf_counter() - started, 3), "records": records,
            "confidence": confidence}
