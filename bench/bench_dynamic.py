"""Per-frame time of the dynamic stage, serial vs a local Dask cluster (issue 11 benchmark).

Synthesizes (once, cached under ``--workdir``) a face sequence with a cheek
flush: 6 views of 256 px, 6 bands, 4 spp, 256^2 truth, ``--frames`` frames
(default 9: the static frame and 8 dynamic ones); runs the static stage with
the default config, then the dynamic stage (default config: 30 epochs per
frame) twice on copies of that result: in-process, one frame after another,
and with ``--workers 2`` (a LocalCluster of two single-threaded worker
processes). Prints per-frame times (target: under 20 s per frame on the
2-core machine), both wall times, and the scheduling overhead
``1 - sum(frame seconds) / (workers x wall)`` (target: under 5% of a
frame's time per frame).

    .venv/bin/python bench/bench_dynamic.py [--workdir /tmp/polarbssrdf-dynamic] [--frames 9]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import time
from pathlib import Path


def cli(*args):
    from polarbssrdf.cli import main

    code = main([str(a) for a in args])
    if code:
        raise SystemExit(f"polarbssrdf {' '.join(map(str, args))} failed with status {code}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/polarbssrdf-dynamic"))
    parser.add_argument("--frames", type=int, default=9)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    capture = args.workdir / f"face_{args.frames}"
    if not (capture / "capture.json").is_file():
        start = time.perf_counter()
        cli("synth", capture, "--object", "face", "--views", 6, "--resolution", 256, "--texture",
            256, "--spp", 4, "--frames", args.frames, "--quiet", "--overwrite")
        print(f"synthesized {capture} in {time.perf_counter() - start:.0f} s", flush=True)
    static = args.workdir / "static"
    if not (static / "static" / "maps_f0000.exr").is_file():
        start = time.perf_counter()
        cli("reconstruct", capture, static, "--stages", "static", "--quiet", "--overwrite")
        print(f"static stage in {time.perf_counter() - start:.0f} s", flush=True)

    from polarbssrdf.variants import select_variant
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.polarimetric.dynamic import run_dynamic_stage
    from polarbssrdf.inverse.frames import scheduling_overhead
    from polarbssrdf.io import load_capture

    select_variant("llvm_ad_mono_polarized")
    loaded = load_capture(capture, check_images=False)
    figures = {}
    for name, workers in (("serial", None), ("workers2", 2)):
        outdir = args.workdir / name
        if outdir.exists():
            shutil.rmtree(outdir)
        shutil.copytree(static, outdir, ignore=shutil.ignore_patterns("observations"))
        start = time.perf_counter()
        report = run_dynamic_stage(loaded, outdir, 256, static_config(), workers=workers,
                                   progress=False)
        wall = time.perf_counter() - start
        seconds = [report["records"][t]["seconds"] for t in report["done"]]
        figures[name] = {"wall_s": round(wall, 1), "frames": len(seconds),
                         "frame_s": [round(s, 1) for s in seconds],
                         "median_frame_s": round(statistics.median(seconds), 1),
                         "texel_views": [report["records"][t]["texel_views"] for t in report["done"]],
                         "overhead": round(scheduling_overhead(report["records"], wall,
                                                               workers or 1), 4),
                         "failed": report["failed"]}
        print(name, json.dumps(figures[name]), flush=True)
    speedup = figures["serial"]["wall_s"] / figures["workers2"]["wall_s"]
    print(f"speed-up with 2 workers: {speedup:.2f}x", flush=True)
    figures["speedup"] = round(speedup, 2)
    if args.out:
        args.out.write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
