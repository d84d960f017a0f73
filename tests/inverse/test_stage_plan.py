"""Issue 32: which frames the stages fit (``--frame``), and every requested stage's needs
checked before the first one starts.

Tiny spheres (4 views, 48 x 48 px, T = 16), 1 epoch per stage.
"""

from __future__ import annotations

import json

import pytest

import mitsuba as mi

from helpers import run_cli
from polarbssrdf.errors import EXIT_USER_ERROR

T = 16
SETTINGS = dict(object="sphere", views=4, resolution=48, texture=T, spp=2)
"""The three-band sphere's settings: those of the session's two-frame sphere
(``two_frame_sphere_dir``, tests/inverse/conftest.py), one frame."""
CONFIG = {"patch_size": 16, "min_steps_per_epoch": 1}


@pytest.fixture(scope="module")
def two_frame_capture(two_frame_sphere_dir):
    """The session's two-frame sphere (tests/inverse/conftest.py); never written to."""
    return two_frame_sphere_dir


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "small.json"
    path.write_text(json.dumps(CONFIG))
    return path


def fit(capture, outdir, config_file, *extra):
    return run_cli("reconstruct", capture, outdir, "--iterations", "1", "--config", config_file,
                   "--quiet", *extra)


def registered(outdir):
    maps = json.loads((outdir / "result.json").read_text())["maps"]
    return sorted((record["stage"], record["frame"]) for record in maps)


# --------------------------------------------------------------------------- item 2
def test_frame_is_the_static_frame_and_dynamic_fits_the_others(two_frame_capture, config_file,
                                                               tmp_path):
    outdir = tmp_path / "rf1"
    status, stdout, stderr = fit(two_frame_capture, outdir, config_file,
                                 "--stages", "static,dynamic", "--frame", "1")
    assert status == 0, stderr
    assert registered(outdir) == [("dynamic", 0), ("static", 1)]
    assert "static frame 1" in stdout


def test_a_later_dynamic_stage_starts_from_the_runs_static_frame(two_frame_capture,
                                                                 config_file, tmp_path):
    outdir = tmp_path / "rf1"
    status, _, stderr = fit(two_frame_capture, outdir, config_file, "--stages", "static",
                            "--frame", "1")
    assert status == 0, stderr
    # another static frame than the run's: refused before any work, naming both
    status, _, stderr = fit(two_frame_capture, outdir, config_file, "--stages", "dynamic",
                            "--frame", "0")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1, stderr
    assert "static frame 1" in stderr and "--frame 0" in stderr
    assert registered(outdir) == [("static", 1)]
    # without --frame: the run's static frame
    status, _, stderr = fit(two_frame_capture, outdir, config_file, "--stages", "dynamic")
    assert status == 0, stderr
    assert registered(outdir) == [("dynamic", 0), ("static", 1)]


# --------------------------------------------------------------------------- item 9
@pytest.fixture(scope="module")
def three_band_capture(tmp_path_factory):
    from polarbssrdf.spectral import shipped_default_bands

    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    directory = tmp_path_factory.mktemp("three_bands") / "capture"
    synthesize(directory, SynthesisSettings(**SETTINGS), bands=shipped_default_bands()[:3],
               progress=False)
    return directory


def test_a_stage_the_capture_cannot_feed_is_refused_before_the_first_starts(
        three_band_capture, config_file, tmp_path):
    outdir = tmp_path / "out"
    status, _, stderr = fit(three_band_capture, outdir, config_file)  # every stage
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1, stderr
    assert "3 bands" in stderr and "at least 4" in stderr and "'bio'" in stderr
    assert "--stages static,dynamic" in stderr
    assert not outdir.exists()  # nothing ran, nothing was written
    # the stages it can feed run
    status, _, stderr = fit(three_band_capture, outdir, config_file, "--stages", "static")
    assert status == 0, stderr
    # and a later bio stage on that result is refused the same way, the result untouched
    before = (outdir / "result.json").read_text()
    status, _, stderr = fit(three_band_capture, outdir, config_file, "--stages", "bio")
    assert status == EXIT_USER_ERROR and "at least 4" in stderr
    assert (outdir / "result.json").read_text() == before and not (outdir / "bio").exists()


# --------------------------------------------------------------------------- item 13
def test_resume_with_more_iterations_continues_every_fit(two_frame_capture, config_file,
                                                        tmp_path):
    outdir = tmp_path / "R"
    stages = ("--stages", "static,dynamic")
    status, _, stderr = fit(two_frame_capture, outdir, config_file, *stages)
    assert status == 0, stderr
    status, _, stderr = run_cli("reconstruct", two_frame_capture, outdir, *stages,
                                "--iterations", "3", "--config", config_file, "--quiet",
                                "--resume")
    assert status == 0, stderr
    metrics = json.loads((outdir / "metrics.json").read_text())
    assert [epoch["epoch"] for epoch in metrics["static"]] == [1, 2, 3]
    assert [epoch["epoch"] for epoch in metrics["dynamic"]["1"]] == [1, 2, 3]
    settings = json.loads((outdir / "result.json").read_text())["settings"]
    assert settings["config"]["iterations"] == 3
    assert settings["config"]["dynamic"]["iterations"] == 3
    # fewer epochs than the run holds: refused, and said why
    status, _, stderr = fit(two_frame_capture, outdir, config_file, *stages, "--resume")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1, stderr
    assert "config.iterations (--iterations): 3 (first run) vs 1 (now)" in stderr
    assert "can add epochs, not remove them" in stderr
