"""Time and peak memory of synthesizing a face capture (issue 4 benchmark).

Face, 8 views, 6 bands, 512 x 512 images, 512 x 512 texture, 16 spp, one
frame, run as `polarbssrdf synth` in a child process (so its peak resident
memory is measured, Dr.Jit's included). Target: under 2 minutes on 2 cores.

    .venv/bin/python bench/bench_synth.py [--views 8] [--resolution 512] [--texture 512] [--spp 16]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 120.0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--texture", type=int, default=512)
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    executable = Path(sys.executable).with_name("polarbssrdf")
    with tempfile.TemporaryDirectory() as scratch:
        command = [str(executable), "synth", str(Path(scratch) / "capture"), "--object", "face",
                   "--views", str(args.views), "--resolution", str(args.resolution),
                   "--texture", str(args.texture), "--spp", str(args.spp), "--quiet"]
        start = time.perf_counter()
        subprocess.run(command, check=True, env=os.environ.copy())
        elapsed = time.perf_counter() - start
        size = sum(p.stat().st_size for p in Path(scratch).rglob("*") if p.is_file())
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    images = args.views * 6
    print(f"synth face: {args.views} views x 6 bands, {args.resolution}^2 images, "
          f"{args.texture}^2 texture, {args.spp} spp")
    print(f"  wall time          {elapsed:7.1f} s   (target {TARGET_S:.0f} s, ratio "
          f"{elapsed / TARGET_S:.2f})")
    print(f"  per band image     {elapsed / images:7.2f} s")
    print(f"  peak memory (RSS)  {peak_mb:7.0f} MiB")
    print(f"  capture on disk    {size / 2**20:7.1f} MiB")


if __name__ == "__main__":
    main()
