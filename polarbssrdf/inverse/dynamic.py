"""The dynamic stage: per-frame maps with the static stage's index and roughness (supplement sec. 5.2).

For every frame ``t`` of a sequence but the static one, eq. 36: ``rho_s^t``,
``rho_ss^t``, ``rho_sss^t`` per band and ``H^t`` from that frame's images,
with ``eta``, ``alpha_s`` and ``alpha_ss`` held at the static maps, by the
static stage's own observations, model, losses and optimizer
(:mod:`polarbssrdf.inverse.static`): ``L_sss``, ``L_s`` and ``L_phi`` with
weights 1, 1, 0.2 (no ``L_psi``: the index is fixed), ``H^t`` regularized as
in eq. 33-34 with 0.001 and 500, and the albedos pulled toward the static
maps (eq. 38-39; weights and the subsurface pull's robust weighting in
:data:`DYNAMIC_WEIGHTS` and :func:`polarbssrdf.inverse.optimize._temporal_albedo_term`).
Each frame starts from the static maps (displacement included).

A frame is :func:`fit_frame`, a pure function of (the static result on disk,
that frame's images) that writes ``dynamic/maps_f####.exr`` atomically and
returns its record; the caller registers it in ``result.json``
(:mod:`polarbssrdf.inverse.frames` runs frames serially or on Dask).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

STAGE = "dynamic"
OPTIMIZED = ("rho_s", "rho_ss", "displacement")
"""The maps a frame's gradient steps move (``rho_sss`` is solved in closed form)."""

HELD = ("eta", "alpha_s", "alpha_ss")
"""The maps a frame takes from the static result."""

DYNAMIC_WEIGHTS = {"sss": 1.0, "s": 1.0, "phi": 0.2, "psi": 0.0,
                   "H_magnitude": 0.001, "H_laplacian": 500.0,
                   "alpha_s_smoothness": 0.0, "alpha_ss_smoothness": 0.0, "eta_smoothness": 0.0,
                   "rho_s_temporal": 100.0, "rho_ss_temporal": 100.0, "rho_sss_temporal": 1e5}
"""Weights of eq. 36-39: the paper's, except the pulls toward the static albedos.

The paper's 0.01 weigh plain sums of squared image residuals; here the data
terms are chi-squares per texel-view (``losses``), against which 0.01 does
nothing: on a raw 5-frame face (64^2, 6 views) the frame-to-frame spread of
``rho_s`` in a region without flush was 1.86% with 0.01 and 1.86% with 0;
100 gives 0.25% (1000: 0.04%), with the cheek flush tracked alike (change
-0.01071 for a truth of -0.01055 at every weight). ``rho_sss_temporal``
acts through a robust weight instead of eq. 39's (see
:func:`polarbssrdf.inverse.optimize._temporal_albedo_term`): on the same face
the spread of ``rho_sss`` without flush was 0.132% with no pull, 0.119% with
1e4 and 0.052% with 1e5, the cheeks' change -0.01068 and -0.01040 for the
truth's -0.01055. With eq. 39's own weight, 1e6 held back 14% of the flush
and left the spread at 0.132%."""


DEFAULT_ITERATIONS = 30
"""Epochs per frame. A frame starts from the static maps, which are close: 30 epochs track a
raw face's cheek flush within 2% of its change with normals within 2 degrees
(tests/inverse/test_dynamic.py). At 256^2 with 6 views and 6 bands a frame took 22.7 s with 50
epochs (bench/RESULTS.md); the static stage's 150 would be 60 s."""


def parse_dynamic(overrides, default_iterations=None):
    """``(iterations, weights)`` from a config's ``dynamic`` object; errors name the key.

    ``overrides`` may set ``iterations`` (default :data:`DEFAULT_ITERATIONS`)
    and ``weights`` (keys of :data:`DYNAMIC_WEIGHTS`).
    """
    overrides = dict(overrides or {})
    weights = dict(DYNAMIC_WEIGHTS)
    extra = overrides.pop("weights", {}) or {}
    if not isinstance(extra, dict):
        raise ValueError(f"config: dynamic.weights must be an object, got {extra!r}")
    unknown = sorted(set(extra) - set(DYNAMIC_WEIGHTS))
    if unknown:
        raise ValueError(f"config: unknown dynamic.weights key(s) {unknown}; known: "
                         f"{sorted(DYNAMIC_WEIGHTS)}")
    for name, value in extra.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
            raise ValueError(f"config: dynamic.weights.{name} must be a number >= 0, got {value!r}")
        weights[name] = float(value)
    iterations = overrides.pop("iterations", DEFAULT_ITERATIONS)
    if overrides:
        raise ValueError(f"config: unknown dynamic key(s) {sorted(overrides)}; known: "
                         "['iterations', 'weights']")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
        raise ValueError(f"config: dynamic.iterations must be an integer >= 0, got {iterations!r}")
    return iterations, weights


def dynamic_settings(config):
    """``(StaticConfig for a frame, weights)``: the config with its ``dynamic`` overrides."""
    iterations, weights = parse_dynamic(config.dynamic, config.iterations)
    # the regularization scale and the amplitude variables act on the static stage only
    frame_config = dataclasses.replace(config, iterations=iterations, regularization_scale=1.0,
                                       glossy_amplitudes=False)
    return frame_config, weights


def static_maps(outdir):
    """The static stage's maps in ``outdir``; a clear error when there are none."""
    from polarbssrdf.inverse.result import RESULT_FILE, read_stage_maps

    if not (Path(outdir) / RESULT_FILE).is_file():
        raise FileNotFoundError(f"{outdir} holds no {RESULT_FILE}: the dynamic stage starts from "
                                "the static stage's maps; run it first ('--stages static,dynamic')")
    try:
        return read_stage_maps(outdir, "static", 0)
    except FileNotFoundError:
        raise FileNotFoundError(f"{outdir}/{RESULT_FILE} lists no static maps: run the static stage "
                                "first ('--stages static,dynamic')") from None


def fit_frame(capture_dir, outdir, frame, texture_size, config_json, holdout=(), *,
              variant="llvm_ad_mono_polarized", threads=None, progress=False):
    """Fit one frame and write ``dynamic/maps_f####.exr`` (not registered); returns its record.

    Pure: reads the capture and ``outdir``'s static maps, writes only that
    frame's files (its observation cache, checkpoint, maps). ``config_json``
    is ``StaticConfig.to_json()`` (plain data, so the call can travel to a
    Dask worker). ``threads``: Dr.Jit's thread count in this process.
    """
    import drjit as dr

    from polarbssrdf.inverse.commands import select_variant
    from polarbssrdf.inverse.config import static_config

    started = time.perf_counter()
    select_variant(variant)
    if threads is not None:
        dr.set_thread_count(int(threads))
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.inverse.observations import load_or_build_observations
    from polarbssrdf.inverse.optimize import MapParameters
    from polarbssrdf.inverse.result import stage_map_path
    from polarbssrdf.inverse.static import initial_parameters, run_polarimetric_fit
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.exr import write_exr

    outdir = Path(outdir)
    config = static_config(config_json)
    frame_config, weights = dynamic_settings(config)
    static = static_maps(outdir)
    capture = load_capture(capture_dir, check_images=False, frames=[frame])
    if frame not in [f.index for f in capture.manifest.frames]:
        raise ValueError(f"capture {capture_dir} has no frame {frame}")
    store = load_or_build_observations(
        capture, frame, texture_size, outdir / "observations" / f"f{frame:04d}.zarr",
        exclude_cameras=tuple(holdout), progress=progress)
    missing = [f"rho_sss.{band}" for band in store.bands if f"rho_sss.{band}" not in static]
    if missing:
        raise ValueError(f"the static maps lack {', '.join(missing)}: frame {frame}'s bands "
                         "differ from the static frame's")
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), texture_size)
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
    for name in HELD:  # held: exactly the static values (the fill leaves them alone)
        result.maps[name] = np.asarray(static[name], np.float32)
    path = outdir / stage_map_path(STAGE, frame)
    metadata = {"stage": STAGE, "frame": int(frame), "config": config.to_json(),
                "weights": weights, "texel_views": len(store), "history": result.history,
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


def run_dynamic_stage(capture, outdir, texture_size, config, *, holdout=(), static_frame=0,
                      frames=None, workers=None, scheduler=None, resume=False, progress=True,
                      variant="llvm_ad_mono_polarized", label=STAGE):
    """Fit every frame but ``static_frame`` (or ``frames``) and register the finished ones.

    Frames whose map file exists are skipped when ``resume``; ``label`` names the stage
    on the progress bar. Returns
    ``{"done": [frames], "skipped": [frames], "failed": {frame: reason}, "seconds"}``.
    """
    from polarbssrdf.inverse.frames import run_frames
    from polarbssrdf.inverse.result import register_map, stage_map_path
    from polarbssrdf.inverse.static import write_metrics

    started = time.perf_counter()
    outdir = Path(outdir)
    static_maps(outdir)  # the clear error before any work
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
    from polarbssrdf.io.exr import read_exr

    metrics = {}
    for frame in sorted(records) + skipped:
        channels, metadata = read_exr(outdir / stage_map_path(STAGE, frame))
        register_map(outdir, STAGE, frame, channels)
        metrics[str(frame)] = (metadata or {}).get("history", [])
    write_metrics(outdir, STAGE, metrics)
    return {"done": sorted(records), "skipped": skipped, "failed": failures,
            "seconds": round(time.perf_counter() - started, 3), "records": records}
