"""The static stage: per-texel maps from one multi-view frame (supplement sec. 5.1, eq. 26-35).

``run_static_stage`` turns the texture-space observations of a frame
(:mod:`polarbssrdf.inverse.observations`) into maps of ``eta, rho_s, alpha_s,
rho_ss, alpha_ss, rho_sss.<band>`` and the displacement ``H`` (with the
normals it implies), written in the result format
(:mod:`polarbssrdf.inverse.results.directory`) as ``static/maps_f0000.exr``
with PNG previews. The maps start from the config's constants and are fitted
by :func:`polarbssrdf.inverse.polarimetric.fit.run_polarimetric_fit` (epochs of
patch steps with checkpoints, confidence, the specular peak angle).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

from polarbssrdf.geometry import texel_atlas, to_mitsuba
from polarbssrdf.inverse.observations.build import load_or_build_observations
from polarbssrdf.inverse.observations.footprint import capture_blur_variance_mm2
from polarbssrdf.inverse.polarimetric.fit import run_polarimetric_fit
from polarbssrdf.inverse.results.directory import (
    OBSERVATIONS_DIR,
    write_confidence,
    write_metrics,
    write_stage_maps,
)
from polarbssrdf.inverse.results.previews import write_map_previews

STAGE = "static"
CHECKPOINT_FILE = "checkpoint.npz"


def with_capture_blur(config, capture, atlas, frame, holdout=()):
    """``config`` with ``capture_blur_mm`` estimated from the ``frame``'s fitted cameras
    (:func:`~polarbssrdf.inverse.observations.footprint.capture_blur_variance_mm2`) when
    it is ``None``."""
    if config.capture_blur_mm is not None:
        return config
    variance, _ = capture_blur_variance_mm2(capture, atlas, frame, exclude_cameras=tuple(holdout))
    return dataclasses.replace(config, capture_blur_mm=round(float(variance) ** 0.5, 6))


def run_static_stage(capture, outdir, config, texture_size, *, frame=0, holdout=(),
                     progress=True, label=STAGE):
    """The static stage on ``capture`` into the prepared result directory ``outdir``.

    Builds (or reuses) the observation cache under ``outdir/observations``,
    optimizes with checkpoints under ``outdir/static``, writes
    ``static/maps_f####.exr`` and its previews, and registers the maps.
    ``label`` names the stage on its progress bars (e.g. ``[1/3] static``).
    """
    outdir = Path(outdir)
    start = time.perf_counter()
    store = load_or_build_observations(
        capture, frame, texture_size, outdir / OBSERVATIONS_DIR / f"f{frame:04d}.zarr",
        exclude_cameras=tuple(holdout), progress=progress)
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), texture_size)
    config = with_capture_blur(config, capture, atlas, frame, holdout)
    stage_dir = outdir / STAGE
    stage_dir.mkdir(parents=True, exist_ok=True)
    result = run_polarimetric_fit(store, atlas, config, checkpoint=stage_dir / CHECKPOINT_FILE,
                                  progress=progress, description=label)
    metadata = {"config": config.to_json(), "texel_views": len(store),
                "seconds": round(time.perf_counter() - start, 3), "variant": mi.variant(),
                "confidence": result.confidence, "held_at_face_mean": result.held,
                "face_level_start": result.face_levels}
    result.path = write_stage_maps(outdir, STAGE, frame, result.maps, metadata)
    write_map_previews(result.maps, stage_dir / "previews", f"f{frame:04d}")
    write_metrics(outdir, STAGE, result.history)
    write_confidence(outdir, STAGE, {frame: result.confidence})
    dr.flush_malloc_cache()
    return result
