"""``polarbssrdf demo`` end to end: time and peak memory per step, and how they grow (issue 12).

Runs the demo's steps one child process each, exactly as ``polarbssrdf demo``
runs them in one process: ``synth`` (raw face, hemoglobin flush), then
``reconstruct --stages static``, ``--stages dynamic``, ``--stages bio`` on
the same result directory, ``evaluate`` of the static stage with the
held-out camera re-rendered, and ``report``. Each step's wall time and peak
resident memory (the child's ``ru_maxrss`` from ``os.wait4``) is printed.

The base case is the demo's default size (8 views, 4 frames, 256^2 texels,
384 px images). ``--scaling`` also runs smaller and larger cases, one factor
changed at a time from a base of 8 views, 4 frames, 128^2 texels, 256 px:
views 4 / 16, frames 2 / 8, texture 64 / 256; each row prints its ratio to
that base's time, measured in the same run.

    .venv/bin/python bench/bench_demo.py [--workdir /tmp/polarbssrdf-demo-bench] [--scaling]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

DEMO = dict(views=8, frames=4, texture=256, resolution=384)
SCALING_BASE = dict(views=8, frames=4, texture=128, resolution=256)
SCALING = [("views", 4), ("views", 16), ("frames", 2), ("frames", 8), ("texture", 64),
           ("texture", 256)]


def run_child(arguments):
    """Run ``polarbssrdf ARGUMENTS`` in a child; returns (seconds, peak RSS in MiB)."""
    import tempfile

    with tempfile.TemporaryFile() as errors:
        started = time.perf_counter()
        process = subprocess.Popen([sys.executable, "-m", "polarbssrdf", *map(str, arguments)],
                                   stdout=subprocess.DEVNULL, stderr=errors)
        _, status, usage = os.wait4(process.pid, 0)
        seconds = time.perf_counter() - started
        code = os.waitstatus_to_exitcode(status)
        process.returncode = code  # reaped by wait4
        if code:
            errors.seek(0)
            message = errors.read().decode(errors="replace")[-2000:]
            raise SystemExit(f"polarbssrdf {' '.join(map(str, arguments))} failed ({code}):\n"
                             f"{message}")
    return seconds, usage.ru_maxrss / 1024.0  # Linux reports KiB


def run_case(workdir, views, frames, texture, resolution):
    """Every step of one demo size; returns ``{step: (seconds, MiB)}``."""
    from polarbssrdf.demo import TRUTH_SETTINGS, DemoSettings

    settings = DemoSettings(views=views, frames=frames, texture=texture, resolution=resolution)
    case = workdir / f"v{views}_f{frames}_t{texture}_r{resolution}"
    if case.exists():
        shutil.rmtree(case)
    case.mkdir(parents=True)
    params = case / "truth_settings.json"
    params.write_text(json.dumps(TRUTH_SETTINGS))
    capture, result = case / "capture", case / "result"
    steps = {}
    steps["synth"] = run_child(["synth", capture, "--object", "face", "--views", views,
                                "--frames", frames, "--resolution", resolution, "--texture",
                                texture, "--spp", settings.spp, "--raw", "--params", params,
                                "--quiet"])
    common = [capture, result, "--holdout", settings.holdout, "--quiet"]
    steps["static"] = run_child(["reconstruct", *common, "--stages", "static"])
    steps["dynamic"] = run_child(["reconstruct", *common, "--stages", "dynamic"])
    steps["bio"] = run_child(["reconstruct", *common, "--stages", "bio"])
    steps["evaluate"] = run_child(["evaluate", result, "--out", case / "evaluation.json"])
    steps["report"] = run_child(["report", result, "--quiet"])
    evaluation = json.loads((case / "evaluation.json").read_text())
    return steps, evaluation


def print_case(label, steps, reference=None):
    total = sum(seconds for seconds, _ in steps.values())
    cells = "  ".join(f"{name} {seconds:6.1f} s {mib:5.0f} MiB"
                      for name, (seconds, mib) in steps.items())
    ratio = f"  (x{total / reference:.2f} of the base)" if reference else ""
    print(f"{label:28s} total {total:6.1f} s{ratio}\n    {cells}", flush=True)
    return total


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/polarbssrdf-demo-bench"))
    parser.add_argument("--scaling", action="store_true",
                        help="also the cases that change views, frames or texture")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    rows = {}
    steps, evaluation = run_case(args.workdir, **DEMO)
    rows["demo default"] = steps
    print_case("demo default " + json.dumps(DEMO), steps)
    maps = evaluation["maps"]
    print(f"    static eta MAE {maps['eta']['mae']:.4f} (constant {maps['eta']['constant_mae']:.4f})"
          f", alpha_s {maps['alpha_s']['mae']:.4f} ({maps['alpha_s']['constant_mae']:.4f})",
          flush=True)
    if args.scaling:
        base_steps, _ = run_case(args.workdir, **SCALING_BASE)
        rows["scaling base"] = base_steps
        base = print_case("base " + json.dumps(SCALING_BASE), base_steps)
        for key, value in SCALING:
            size = {**SCALING_BASE, key: value}
            steps, _ = run_case(args.workdir, **size)
            rows[f"{key} {value}"] = steps
            print_case(f"{key} = {value}", steps, base)
    if args.out:
        args.out.write_text(json.dumps({k: {s: list(v) for s, v in r.items()}
                                        for k, r in rows.items()}, indent=1))


if __name__ == "__main__":
    sys.exit(main())
