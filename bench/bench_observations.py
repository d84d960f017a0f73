"""Time and peak memory of building texture-space observation stores (issue 9 benchmark).

Synthesizes a sphere capture (default 16 views, 6 bands, 256 x 256 images, 4 spp;
kept in --capture-dir to reuse) and builds its observation store for each
texture size, each build in a child process so its peak resident memory
(Dr.Jit's included) is measured alone.

    .venv/bin/python bench/bench_observations.py [--views 16] [--resolution 256]
        [--textures 256 512] [--capture-dir DIR] [--raw]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def synthesize_capture(directory: Path, views: int, resolution: int, raw: bool) -> float:
    """Render the sphere capture into ``directory`` unless it is there; returns seconds spent."""
    if (directory / "capture.json").is_file():
        return 0.0
    import mitsuba as mi

    import polarbssrdf  # noqa: F401
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    start = time.perf_counter()
    synthesize(directory, SynthesisSettings(object="sphere", views=views, resolution=resolution,
                                            texture=64, spp=4, raw=raw), progress=False)
    return time.perf_counter() - start


def build_once(capture: Path, texture: int, store: Path) -> None:
    """Child process: build one store and print a JSON line of figures."""
    import mitsuba as mi

    import polarbssrdf  # noqa: F401
    from polarbssrdf.inverse.observations.build import build_observations

    mi.set_variant("llvm_ad_mono_polarized")
    baseline_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    start = time.perf_counter()
    result = build_observations(capture, 0, texture, store, progress=False)
    elapsed = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    size = sum(p.stat().st_size for p in store.rglob("*") if p.is_file())
    print(json.dumps({"texture": texture, "seconds": elapsed, "texel_views": len(result),
                      "views": len(result.views), "peak_rss_mb": peak_mb,
                      "rss_before_build_mb": baseline_mb, "store_mb": size / 2**20}))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--textures", type=int, nargs="+", default=[256, 512])
    parser.add_argument("--capture-dir", type=Path, default=None)
    parser.add_argument("--raw", action="store_true", help="raw mosaics (demosaicked on load)")
    parser.add_argument("--child", nargs=3, metavar=("CAPTURE", "TEXTURE", "STORE"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        build_once(Path(args.child[0]), int(args.child[1]), Path(args.child[2]))
        return
    with tempfile.TemporaryDirectory() as scratch:
        capture = args.capture_dir or Path(scratch) / "capture"
        synth_s = synthesize_capture(capture, args.views, args.resolution, args.raw)
        kind = "raw" if args.raw else "analyser"
        print(f"observations: sphere, {args.views} views x 6 bands, {args.resolution}^2 {kind} "
              f"images" + (f" (synthesized in {synth_s:.0f} s)" if synth_s else ""))
        for texture in args.textures:
            store = Path(scratch) / f"observations_{texture}.zarr"
            output = subprocess.run([sys.executable, __file__, "--child", str(capture),
                                     str(texture), str(store)], check=True, capture_output=True,
                                    text=True).stdout
            figures = json.loads(output.strip().splitlines()[-1])
            rate = figures["texel_views"] / figures["seconds"]
            print(f"  T = {texture:5d}: {figures['seconds']:6.1f} s, {figures['texel_views']:9d} "
                  f"texel-views ({rate:9.0f} /s), peak RSS {figures['peak_rss_mb']:6.0f} MiB "
                  f"(before build {figures['rss_before_build_mb']:.0f} MiB), store "
                  f"{figures['store_mb']:.1f} MiB")


if __name__ == "__main__":
    main()
