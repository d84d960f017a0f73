"""Peak memory of each stage of a run against the estimate reconstruct checks first
(issue 21, item 6).

Synthesizes a sphere capture (4 views, 2 frames, 6 bands, 96 x 96 images; kept in
--capture-dir to reuse) and runs ``reconstruct`` on it at each texture size, one stage
after another into the same result directory (``--stages static``, then ``--stages
dynamic``, ...; one epoch), each stage in a child process so its peak resident memory
(Dr.Jit's and the observation build's included) is measured alone, next to
:func:`polarbssrdf.inverse.resources.run_memory_bytes` for that stage.

    .venv/bin/python bench/bench_memory.py [--textures 128 256 512 1024]
        [--stages static dynamic bio] [--capture-dir DIR]
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


def synthesize_capture(directory: Path) -> None:
    if (directory / "capture.json").is_file():
        return
    import mitsuba as mi

    import polarbssrdf  # noqa: F401
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    synthesize(directory, SynthesisSettings(object="sphere", views=4, resolution=96,
                                            texture=64, spp=2, frames=2), progress=False)


def run_once(capture: Path, texture: int, outdir: Path, stage: str) -> None:
    """Child process: one stage of the run; prints a JSON line of figures."""
    from polarbssrdf.inverse.pipeline import reconstruct
    from polarbssrdf.inverse.resources import run_memory_bytes
    from polarbssrdf.io import load_capture

    manifest = load_capture(capture, check_images=False).manifest
    estimate = run_memory_bytes(texture, len(manifest.bands), len(manifest.frame(0).images),
                                (stage,))
    start = time.perf_counter()
    reconstruct(capture, outdir, stages=(stage,), iterations=1, texture=texture,
                config={"bio": {"rounds": 1, "iterations": 2}}, progress=False)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"texture": texture, "stage": stage, "seconds": time.perf_counter() - start,
                      "peak_rss_mb": peak / 2**20, "estimate_mb": estimate / 2**20}))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--textures", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--stages", nargs="+", default=["static", "dynamic", "bio"])
    parser.add_argument("--capture-dir", type=Path, default=None)
    parser.add_argument("--child", nargs=4, metavar=("CAPTURE", "TEXTURE", "OUTDIR", "STAGE"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        capture, texture, outdir, stage = args.child
        run_once(Path(capture), int(texture), Path(outdir), stage)
        return
    with tempfile.TemporaryDirectory() as scratch:
        capture = args.capture_dir or Path(scratch) / "capture"
        synthesize_capture(capture)
        print(f"{'T':>6} {'stage':>8} {'peak RSS MB':>12} {'estimate MB':>12} {'ratio':>6} "
              f"{'s':>7}", flush=True)
        for texture in args.textures:
            outdir = Path(scratch) / f"out{texture}"
            for stage in args.stages:
                line = subprocess.run([sys.executable, __file__, "--child", str(capture),
                                       str(texture), str(outdir), stage],
                                      capture_output=True, text=True, check=True).stdout
                row = json.loads(line.strip().splitlines()[-1])
                print(f"{texture:>6} {stage:>8} {row['peak_rss_mb']:>12.0f} "
                      f"{row['estimate_mb']:>12.0f} "
                      f"{row['estimate_mb'] / row['peak_rss_mb']:>6.2f} {row['seconds']:>7.1f}",
                      flush=True)


if __name__ == "__main__":
    main()
