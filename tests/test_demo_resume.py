"""Issue 32, item 11: ``demo --resume`` on a finished demo keeps the times of the run that
did the work, and says what it reused.

A demo of its own (a resume rewrites metrics.json, which test_demo.py's shared demo must
not see): 4 views, 2 frames, 32^2 texels, 1 epoch; about 50 s with the resume.
"""

from __future__ import annotations

import json

from helpers import run_cli

TINY = ["--views", "4", "--frames", "2", "--texture", "32", "--resolution", "96", "--spp",
        "2", "--iterations", "1"]


def test_resuming_a_finished_demo_keeps_the_times_of_the_run_that_did_the_work(tmp_path):
    outdir = tmp_path / "demo"
    status, _, stderr = run_cli("demo", outdir, *TINY, "--quiet")
    assert status == 0, stderr
    first = json.loads((outdir / "metrics.json").read_text())["seconds"]
    timings = json.loads((outdir / "result" / "timings.json").read_text())

    status, stdout, stderr = run_cli("demo", outdir, *TINY, "--resume")
    assert status == 0, stderr
    again = json.loads((outdir / "metrics.json").read_text())["seconds"]
    assert again["stages"] == first["stages"] == timings
    assert json.loads((outdir / "result" / "timings.json").read_text()) == timings
    assert again["synth"] == first["synth"] and again["reconstruct"] == first["reconstruct"]
    assert again["reused"] == ["synth", "reconstruct"]
    assert "reused from the earlier run: synth, reconstruct" in stdout
    assert "reused the finished synth and reconstruct" in stderr
    # reconstruct's own summary says which stages it found done
    assert stdout.count("reused the earlier run's fit") == 3
