"""Time and peak memory of the static stage on synthetic spheres (issue 9 benchmark).

Synthesizes sphere captures with ``polarbssrdf.synth`` (analyser images, 3 of
the 6 shipped bands, 4 spp, image side = texture side so each texel is seen by
about one pixel; cached under ``--workdir``) and runs the static stage on
them, each phase in its own child process so that its peak resident memory
(Dr.Jit's included, ``getrusage`` of the child) is measured alone:

* ``observe``: ``build_observations`` (the store ``run_static_stage`` builds,
  same block size and cosine threshold);
* ``optimize``: ``run_polarimetric_fit`` on that store with the default
  ``StaticConfig`` (checkpoint after every epoch, as the stage does; maps are
  not written). Every optimizer step is timed, so the first epoch (kernel
  tracing, patch preparation) is reported apart from the steady epochs.

Cases (``--cases``, comma-separated; default all):

* ``target``: the issue's case: 256 x 256 texels, 16 views, 3 bands, 150
  epochs (target: observations + fit under 60 s on the 2-core machine), on
  every core (the default) and, as the in-process reference, on one Dr.Jit
  thread; the two runs' maps must be bit-identical (a step's gradient does
  not depend on the thread count);
* ``scaling``: textures 128, 256, 512 at 16 views and views 8, 16, 32 at 256
  texels, 10 epochs: the per-epoch time per texel-view shows whether the cost
  is linear in texels x views;
* ``memory``: 1024 x 1024 texels, 32 views, 3 epochs (target: peak RSS of
  each phase under 4 GB).

``texel-view steps`` counts the texel-views every optimizer step evaluated
(an epoch of a texture no larger than a patch repeats its one patch
``min_steps_per_epoch`` = 4 times, so at 128 and 256 texels an epoch
evaluates every texel-view 4 times, at 512 once); the rate is per second of
the epochs, and ``ns/tv-step`` is a steady epoch's time per texel-view step,
the figure to compare across sizes.

    .venv/bin/python bench/bench_static.py [--quick] [--cases target,scaling,memory]
        [--workdir /tmp/polarbssrdf-bench] [--out figures.json]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

VARIANT = "llvm_ad_mono_polarized"
SPP = 4
CASES = ("target", "scaling", "memory")
FULL = {
    "target": {"texture": 256, "views": 16, "iterations": 150},
    "scaling": {"textures": (128, 256, 512), "views_at": 16, "views": (8, 16, 32),
                "texture_at": 256, "iterations": 10},
    "memory": {"texture": 1024, "views": 32, "iterations": 3},
}
QUICK = {
    "target": {"texture": 32, "views": 4, "iterations": 4},
    "scaling": {"textures": (32, 64), "views_at": 4, "views": (4, 8), "texture_at": 32,
                "iterations": 3},
    "memory": {"texture": 64, "views": 8, "iterations": 2},
}
TARGET_SECONDS = 60.0
TARGET_RSS_MB = 4096.0


def bench_bands():
    """Three of the shipped bands (every other one: BA, GA, RA)."""
    from polarbssrdf.spectral import shipped_default_bands

    return shipped_default_bands()[::2]


def capture_dir(workdir: Path, views: int, texture: int) -> Path:
    resolution = max(64, texture)
    return workdir / "captures" / f"sphere_v{views}_r{resolution}_t{texture}_spp{SPP}_3bands"


def ensure_capture(workdir: Path, views: int, texture: int) -> tuple[Path, float]:
    """The cached sphere capture (rendered when missing); returns ``(directory, seconds)``.

    Rendered in a child process too: Linux keeps a process's peak RSS across
    ``exec``, so a parent that had rendered would pass its peak on to every
    child it starts and spoil their memory figures.
    """
    directory = capture_dir(workdir, views, texture)
    if (directory / "capture.json").is_file():
        return directory, 0.0
    start = time.perf_counter()
    run_child({"phase": "synthesize", "capture": str(directory), "views": views,
               "texture": texture})
    return directory, time.perf_counter() - start


def child_synthesize(job: dict) -> dict:
    """Render the sphere capture of ``job`` (analyser images, 3 bands, 4 spp)."""
    import mitsuba as mi

    import polarbssrdf  # noqa: F401  (registers the plugins)
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant(VARIANT)
    directory, texture = Path(job["capture"]), job["texture"]
    settings = SynthesisSettings(object="sphere", views=job["views"],
                                 resolution=max(64, texture), texture=texture, spp=SPP, seed=0)
    # a half-written directory of an interrupted run is started over
    synthesize(directory, settings, bands=bench_bands(), overwrite=directory.exists(),
               progress=False)
    return {"capture": str(directory)}


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child_observe(job: dict) -> dict:
    """Build the observation store of ``job['capture']`` at ``job['store']``."""
    import mitsuba as mi

    import polarbssrdf  # noqa: F401
    from polarbssrdf.inverse.observations.build import build_observations

    mi.set_variant(VARIANT)
    before = _peak_rss_mb()
    start = time.perf_counter()
    store = build_observations(job["capture"], 0, job["texture"], job["store"], progress=False)
    seconds = time.perf_counter() - start
    size = sum(p.stat().st_size for p in Path(job["store"]).rglob("*") if p.is_file())
    return {"seconds": seconds, "texel_views": len(store), "views": len(store.views),
            "peak_rss_mb": _peak_rss_mb(), "rss_before_mb": before, "store_mb": size / 2**20}


def child_optimize(job: dict) -> dict:
    """``run_polarimetric_fit`` on the store, every optimizer step timed."""
    import drjit as dr
    import mitsuba as mi

    import polarbssrdf  # noqa: F401
    import polarbssrdf.inverse.polarimetric.static as static
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.observations.store import ObservationStore
    from polarbssrdf.inverse.polarimetric.patches import patch_order, texture_patches
    from polarbssrdf.io import load_capture

    mi.set_variant(VARIANT)
    capture = load_capture(job["capture"], check_images=False)
    store = ObservationStore.open(job["store"])
    atlas = texel_atlas(to_mitsuba(capture.load_mesh()), job["texture"])
    if job.get("threads"):
        dr.set_thread_count(int(job["threads"]))
    config = static_config(iterations=job["iterations"])
    checkpoint = Path(job["checkpoint"])
    checkpoint.unlink(missing_ok=True)  # a checkpoint would resume instead of timing
    steps = []
    step = static.optimizer_step

    def timed_step(params, prepared, config, weights):
        record = step(params, prepared, config, weights)
        steps.append((time.perf_counter(), len(prepared)))
        return record

    static.optimizer_step = timed_step  # optimize_maps looks it up at every call
    before = _peak_rss_mb()
    start = time.perf_counter()
    result = static.run_polarimetric_fit(store, atlas, config, checkpoint=checkpoint,
                                         progress=False)
    seconds = time.perf_counter() - start
    patches = texture_patches(job["texture"], config.patch_size, store.block_size)
    per_epoch = [len(patch_order(patches, epoch, config.seed, config.min_steps_per_epoch))
                 for epoch in range(config.iterations)]
    ends, done = [], 0
    for count in per_epoch:
        done += count
        ends.append(steps[done - 1][0])
    epochs = [ends[0] - start] + [b - a for a, b in zip(ends, ends[1:])]
    steady = epochs[1:] or epochs
    epochs_s = ends[-1] - start
    texel_view_steps = sum(n for _, n in steps)
    return {"seconds": seconds, "epochs_s": epochs_s, "first_epoch_s": epochs[0],
            "steady_epoch_s": statistics.median(steady), "finish_s": seconds - epochs_s,
            "epochs": config.iterations, "steps": len(steps), "patches": len(patches),
            "texel_views": len(store), "texel_view_steps": texel_view_steps,
            "rate": texel_view_steps / epochs_s, "peak_rss_mb": _peak_rss_mb(),
            "rss_before_mb": before, "final_loss": result.history[-1].get("total"),
            "threads": dr.thread_count(), "maps_md5": _maps_digest(result.maps)}


def _maps_digest(maps):
    """MD5 of every map's float32 bytes, in name order (equal digests: bit-identical maps)."""
    import hashlib

    import numpy as np

    digest = hashlib.md5()
    for name in sorted(maps):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(maps[name], np.float32).tobytes())
    return digest.hexdigest()


def run_child(job: dict) -> dict:
    """Run one phase in a fresh interpreter; returns its JSON figures."""
    process = subprocess.run([sys.executable, __file__, "--child", json.dumps(job)],
                             capture_output=True, text=True)
    if process.returncode != 0:
        sys.stderr.write(process.stderr)
        raise SystemExit(f"bench_static: child {job['phase']} failed (exit {process.returncode})")
    return json.loads(process.stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------- the cases
HEADER = (f"{'case':<22} {'T':>5} {'views':>5} {'texel-views':>11} {'obs s':>7} "
          f"{'obs MiB':>8} {'epochs':>6} {'fit s':>7} {'1st ep s':>8} {'epoch s':>8} "
          f"{'ns/tv-step':>10} {'tv-steps/s':>10} {'fit MiB':>8}")


def step_cost_ns(optimize) -> float:
    """Steady epoch time per texel-view step (an epoch's steps times their texel-views), ns."""
    per_epoch = optimize["texel_view_steps"] / optimize["epochs"]
    return 1e9 * optimize["steady_epoch_s"] / max(per_epoch, 1)


def row(label, texture, views, observe, optimize) -> str:
    per_tv = step_cost_ns(optimize)
    return (f"{label:<22} {texture:>5} {views:>5} {observe['texel_views']:>11,} "
            f"{observe['seconds']:>7.1f} {observe['peak_rss_mb']:>8.0f} {optimize['epochs']:>6} "
            f"{optimize['seconds']:>7.1f} {optimize['first_epoch_s']:>8.2f} "
            f"{optimize['steady_epoch_s']:>8.3f} {per_tv:>10.0f} {optimize['rate']:>10.3g} "
            f"{optimize['peak_rss_mb']:>8.0f}")


def run_case(workdir, runs, label, views, texture, iterations, threads=(None,)):
    """Observations once, then one optimization per thread count (None: every core); prints rows."""
    capture, synth_s = ensure_capture(workdir, views, texture)
    if synth_s:
        print(f"  (synthesized {capture.name} in {synth_s:.0f} s)", flush=True)
    run = runs / label
    shutil.rmtree(run, ignore_errors=True)
    run.mkdir(parents=True)
    store = run / "observations.zarr"
    observe = run_child({"phase": "observe", "capture": str(capture), "texture": texture,
                         "store": str(store)})
    results = []
    for count in threads:
        optimize = run_child({"phase": "optimize", "capture": str(capture), "texture": texture,
                              "store": str(store), "iterations": iterations,
                              "threads": count, "checkpoint": str(run / "checkpoint.npz")})
        name = label if len(threads) == 1 else f"{label} {optimize['threads']} thr"
        print(row(name, texture, views, observe, optimize), flush=True)
        results.append({"label": name, "texture": texture, "views": views,
                        "observe": observe, "optimize": optimize})
    shutil.rmtree(run, ignore_errors=True)  # stores of the big cases take GBs
    return results


def case_target(workdir, runs, sizes):
    s = sizes["target"]
    results = run_case(workdir, runs, "target", s["views"], s["texture"], s["iterations"],
                       threads=(None, 1))
    for result in results:
        total = result["observe"]["seconds"] + result["optimize"]["seconds"]
        verdict = "met" if total < TARGET_SECONDS else "NOT met"
        print(f"summary target ({result['label']}): {result['texture']}^2 texels, "
              f"{result['views']} views, {result['optimize']['epochs']} epochs: observations "
              f"{result['observe']['seconds']:.1f} s + fit {result['optimize']['seconds']:.1f} s "
              f"= {total:.1f} s (target < {TARGET_SECONDS:.0f} s: {verdict}); "
              f"{result['observe']['texel_views']:,} texel-views, "
              f"{result['optimize']['texel_view_steps']:,} texel-view steps, "
              f"{result['optimize']['rate']:.3g} /s; peak RSS "
              f"{max(result['observe']['peak_rss_mb'], result['optimize']['peak_rss_mb']):.0f}"
              " MiB", flush=True)
    if len(results) == 2:
        every, one = (result["optimize"] for result in results)
        same = "bit-identical" if every["maps_md5"] == one["maps_md5"] else "DIFFERENT"
        print(f"summary target: {every['threads']} threads vs 1: fit x"
              f"{every['seconds'] / one['seconds']:.2f} of the one-thread time; maps {same}",
              flush=True)
    return results


def case_scaling(workdir, runs, sizes):
    s = sizes["scaling"]
    results = []
    for texture in s["textures"]:
        results += run_case(workdir, runs, f"scaling T={texture}", s["views_at"], texture,
                            s["iterations"])
    for views in s["views"]:
        if views == s["views_at"] and s["texture_at"] in s["textures"]:
            continue  # the same run as above
        results += run_case(workdir, runs, f"scaling views={views}", views, s["texture_at"],
                            s["iterations"])
    per_tv = [step_cost_ns(r["optimize"]) for r in results]
    print(f"summary scaling: steady epoch time per texel-view step {min(per_tv):.0f}-"
          f"{max(per_tv):.0f} ns over {len(results)} runs (constant = linear in "
          f"texel-views, i.e. texels x views)", flush=True)
    return results


def case_memory(workdir, runs, sizes):
    s = sizes["memory"]
    results = run_case(workdir, runs, "memory", s["views"], s["texture"], s["iterations"])
    r = results[0]
    peaks = (r["observe"]["peak_rss_mb"], r["optimize"]["peak_rss_mb"])
    verdict = "met" if max(peaks) < TARGET_RSS_MB else "NOT met"
    print(f"summary memory: {r['texture']}^2 texels, {r['views']} views, "
          f"{r['observe']['texel_views']:,} texel-views (store {r['observe']['store_mb']:.0f} "
          f"MiB): peak RSS observations {peaks[0]:.0f} MiB, {r['optimize']['epochs']} epochs "
          f"{peaks[1]:.0f} MiB (target < {TARGET_RSS_MB:.0f} MiB: {verdict})", flush=True)
    return results


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, to check it runs")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated subset of {', '.join(CASES)}")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/polarbssrdf-bench"),
                        help="where captures are cached and runs are made")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures as JSON")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        job = json.loads(args.child)
        phase = {"observe": child_observe, "optimize": child_optimize,
                 "synthesize": child_synthesize}[job["phase"]]
        print(json.dumps(phase(job)))
        return 0
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        parser.error(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(CASES)}")
    sizes = QUICK if args.quick else FULL
    runs = args.workdir / ("runs-quick" if args.quick else "runs")
    print(f"static stage: sphere, 3 bands, analyser images at {SPP} spp, image side = texture "
          f"side; {VARIANT}; captures cached in {args.workdir / 'captures'}", flush=True)
    print(HEADER, flush=True)
    figures = {}
    for case in cases:
        figures[case] = {"target": case_target, "scaling": case_scaling,
                         "memory": case_memory}[case](args.workdir, runs, sizes)
    if args.out:
        args.out.write_text(json.dumps(figures, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
