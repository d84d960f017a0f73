"""``polarbssrdf reconstruct``: outputs, refusals, resume and overwrite, one-line errors.

The session's tiny synthetic sphere (4 views, 64 x 64 px, T = 32; shared with the other
inverse tests) and 2 epochs per run: the whole module takes well under a minute.
"""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest

from helpers import run_cli
from polarbssrdf.errors import EXIT_INTERRUPTED, EXIT_USER_ERROR

T = 32  # the texture size of the shared capture (conftest.TINY)


def tree_hashes(directory):
    """Relative path -> sha256 of every file under ``directory`` (and the set of directories)."""
    hashes = {}
    for path in sorted(directory.rglob("*")):
        key = str(path.relative_to(directory))
        hashes[key] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "dir"
    return hashes


@pytest.fixture(scope="module")
def capture_dir(sphere_capture_dir):
    """The session's tiny sphere (tests/inverse/conftest.py); tests that change it copy it."""
    return sphere_capture_dir


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "small.json"
    path.write_text(json.dumps({"patch_size": 16, "min_steps_per_epoch": 2}))
    return path


def reconstruct_args(capture_dir, outdir, config_file, *extra):
    # the static stage's command line (the biophysical stage's: test_bio_stage.py)
    return ("reconstruct", capture_dir, outdir, "--stages", "static", "--iterations", "2",
            "--config", config_file, "--quiet", *extra)


@pytest.fixture(scope="module")
def run(capture_dir, config_file, tmp_path_factory):
    """One complete run holding out cam03, with the capture's hashes before and after."""
    outdir = tmp_path_factory.mktemp("runs") / "out"
    before = tree_hashes(capture_dir)
    status, stdout, stderr = run_cli(*reconstruct_args(capture_dir, outdir, config_file,
                                                       "--holdout", "cam03"))
    after = tree_hashes(capture_dir)
    assert status == 0, stderr
    return {"outdir": outdir, "stdout": stdout, "before": before, "after": after}


def expected_channels(capture_dir):
    from polarbssrdf.io import load_capture

    bands = load_capture(capture_dir, check_images=False).manifest.band_names
    maps = ["eta", "alpha_s", "alpha_ss", "rho_s", "rho_ss", "displacement",
            *(f"rho_sss.{band}" for band in bands)]
    return {*maps, *(f"{name}_std" for name in maps), "normal.x", "normal.y", "normal.z",
            "confidence", "specular_peak_angle"}


# --------------------------------------------------------------------------- outputs
def test_result_json(run, capture_dir):
    from polarbssrdf.io.truth import TEXTURE_CONVENTION

    data = json.loads((run["outdir"] / "result.json").read_text())
    assert data["schema"] == "polarbssrdf.result" and data["schema_version"] == 1
    assert data["texture_size"] == T  # the truth's size: no --texture given
    assert data["texture_convention"] == TEXTURE_CONVENTION
    assert data["units"]["displacement"] == "mm" and data["units"]["eta"] == "1"
    assert data["capture"] == str(capture_dir.resolve())
    assert data["maps"] == [{"frame": 0, "stage": "static", "path": "static/maps_f0000.exr",
                             "channels": data["maps"][0]["channels"]}]
    assert set(data["maps"][0]["channels"]) == expected_channels(capture_dir)
    settings = data["settings"]
    assert settings["stages"] == ["static"] and settings["frame"] == 0
    assert settings["holdout"] == ["cam03"]
    assert settings["config"]["iterations"] == 2 and settings["config"]["patch_size"] == 16


def test_maps_have_exactly_the_documented_channels_and_no_nan(run, capture_dir):
    from polarbssrdf.io.exr import read_exr

    channels, metadata = read_exr(run["outdir"] / "static" / "maps_f0000.exr")
    assert set(channels) == expected_channels(capture_dir)
    for name, values in channels.items():
        assert values.dtype == np.float32 and values.shape == (T, T), name
        assert np.all(np.isfinite(values)), name
    assert metadata["texel_views"] > 0
    assert 0 <= channels["confidence"].min() and channels["confidence"].max() <= 1
    angle = channels["specular_peak_angle"]
    assert 0 <= angle.min() and angle.max() <= 90


def test_previews_decode_as_png(run):
    from PIL import Image

    previews = sorted((run["outdir"] / "static" / "previews").glob("*.png"))
    names = {p.name for p in previews}
    assert {"eta_f0000.png", "normal_f0000.png", "confidence_f0000.png"} <= names
    for path in previews:
        with Image.open(path) as image:
            assert image.format == "PNG"
            image.load()


def test_metrics_json(run):
    metrics = json.loads((run["outdir"] / "metrics.json").read_text())
    assert [epoch["epoch"] for epoch in metrics["static"]] == [1, 2]
    assert all(np.isfinite(epoch["total"]) for epoch in metrics["static"])


def test_summary(run):
    text = run["stdout"]
    assert "texel-views" in text and "static/maps_f0000.exr" in text
    assert " s)" in text and "held out cam03" in text
    # a synthetic capture with truth at the run's size: the closing line says how to score it
    assert text.rstrip().splitlines()[-1].endswith(
        f"score it with 'polarbssrdf evaluate {run['outdir']}', see it with "
        f"'polarbssrdf report {run['outdir']}'")


def test_the_documented_example_output_matches_a_run(run, capture_dir):
    """docs/reconstruct.md's example said 16 channels where a run writes 17 (issue 21,
    item 15): its channel count and closing line are those of a run."""
    import pathlib
    import re
    from types import SimpleNamespace

    from polarbssrdf.inverse.commands import closing_line

    doc = (pathlib.Path(__file__).resolve().parents[2] / "docs" / "reconstruct.md").read_text()
    documented = re.search(r"\((\d+) channels, 20 epochs", doc)
    printed = re.search(r"\((\d+) channels, 2 epochs", run["stdout"])
    assert documented and printed
    assert int(documented.group(1)) == int(printed.group(1)) == len(expected_channels(
        capture_dir))
    truth = SimpleNamespace(texture_size=64, maps=[SimpleNamespace(frame=0)])
    assert closing_line("result", 0, ["cam03"], 64, SimpleNamespace(truth=truth)) in doc


def test_capture_is_never_modified(run):
    assert run["after"] == run["before"]


# --------------------------------------------------------------------------- OUTDIR rules
def test_refuses_a_non_empty_outdir(run, capture_dir, config_file):
    before = tree_hashes(run["outdir"])
    status, _, stderr = run_cli(*reconstruct_args(capture_dir, run["outdir"], config_file,
                                                  "--holdout", "cam03"))
    assert status == EXIT_USER_ERROR
    assert "not empty" in stderr and "--resume" in stderr and "--overwrite" in stderr
    assert stderr.count("\n") == 1
    assert tree_hashes(run["outdir"]) == before


def test_refuses_an_outdir_inside_the_capture(capture_dir, config_file):
    before = tree_hashes(capture_dir)
    status, _, stderr = run_cli(*reconstruct_args(capture_dir, capture_dir / "result",
                                                  config_file))
    assert status == EXIT_USER_ERROR and "inside the capture" in stderr
    assert stderr.count("\n") == 1
    assert tree_hashes(capture_dir) == before


def test_resume_with_other_settings_names_them(run, capture_dir, config_file):
    status, _, stderr = run_cli("reconstruct", capture_dir, run["outdir"], "--iterations", "3",
                                "--config", config_file, "--holdout", "cam02", "--resume",
                                "--quiet")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "--holdout" in stderr and '["cam03"]' in stderr and '["cam02"]' in stderr
    assert "config.iterations" in stderr and "--overwrite" in stderr
    status, _, stderr = run_cli(*reconstruct_args(capture_dir, run["outdir"], config_file,
                                                  "--holdout", "cam03", "--texture", "16",
                                                  "--resume"))
    assert status == EXIT_USER_ERROR and "--texture: 32 (first run) vs 16 (now)" in stderr


def test_interrupted_run_resumes_to_the_same_maps(run, capture_dir, config_file, tmp_path,
                                                  monkeypatch):
    """Ctrl-C after epoch 1 exits 130; --resume ends like an uninterrupted run."""
    from polarbssrdf.inverse.polarimetric import fit
    from polarbssrdf.io.exr import read_exr

    original = fit.save_checkpoint

    def interrupt_after_first_epoch(path, params, epoch, history, *args):
        original(path, params, epoch, history, *args)
        if epoch == 1:
            raise KeyboardInterrupt

    outdir = tmp_path / "out"
    args = reconstruct_args(capture_dir, outdir, config_file, "--holdout", "cam03")
    monkeypatch.setattr(fit, "save_checkpoint", interrupt_after_first_epoch)
    status, _, stderr = run_cli(*args)
    assert status == EXIT_INTERRUPTED and "--resume" in stderr
    assert not (outdir / "static" / "maps_f0000.exr").exists()
    monkeypatch.setattr(fit, "save_checkpoint", original)

    status, _, stderr = run_cli(*args, "--resume")
    assert status == 0, stderr
    resumed, _ = read_exr(outdir / "static" / "maps_f0000.exr")
    uninterrupted, _ = read_exr(run["outdir"] / "static" / "maps_f0000.exr")
    for name, values in uninterrupted.items():
        np.testing.assert_allclose(resumed[name], values, atol=1e-5, err_msg=name)
    metrics = json.loads((outdir / "metrics.json").read_text())
    assert [epoch["epoch"] for epoch in metrics["static"]] == [1, 2]

    # --overwrite starts over with new settings
    status, _, stderr = run_cli("reconstruct", capture_dir, outdir, "--stages", "static", "--iterations", "1",
                                "--config", config_file, "--overwrite", "--quiet")
    assert status == 0, stderr
    data = json.loads((outdir / "result.json").read_text())
    assert data["settings"]["config"]["iterations"] == 1 and data["settings"]["holdout"] == []
    metrics = json.loads((outdir / "metrics.json").read_text())
    assert [epoch["epoch"] for epoch in metrics["static"]] == [1]


# --------------------------------------------------------------------------- user errors
def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("case", ["stage", "holdout", "config_key", "config_range",
                                  "config_nested", "missing_capture", "not_a_capture",
                                  "variant"])
def test_user_errors_are_one_line_with_status_2(case, capture_dir, config_file, tmp_path):
    outdir = tmp_path / "out"
    capture, extra, config = capture_dir, [], config_file
    expected = []
    if case == "stage":
        extra = ["--stages", "static,colour"]
        expected = ["unknown stage 'colour'", "known stages: static, dynamic, bio"]
    elif case == "holdout":
        extra = ["--holdout", "cam01,cam99"]
        expected = ["cam99", "cam00, cam01, cam02, cam03"]
    elif case == "config_key":
        config = _write(tmp_path / "c.json", json.dumps({"patch_sise": 16}))
        expected = ["patch_sise", str(config)]
    elif case == "config_range":
        config = _write(tmp_path / "c.json", json.dumps({"min_cosine": 1.5}))
        expected = ["min_cosine", "<= 1"]
    elif case == "config_nested":
        config = _write(tmp_path / "c.json", json.dumps({"bounds": {"eta": [1.5, 1.4]}}))
        expected = ["bounds.eta"]
    elif case == "missing_capture":
        capture = tmp_path / "no_such_capture"
        expected = ["does not exist"]
    elif case == "not_a_capture":
        capture = tmp_path / "empty"
        capture.mkdir()
        expected = ["capture.json"]
    elif case == "variant":
        extra = ["--variant", "scalar_mono_polarized"]
        expected = ["llvm_ad_mono_polarized"]
    status, _, stderr = run_cli("reconstruct", capture, outdir, "--iterations", "2",
                                "--config", config, "--quiet", *extra)
    assert status == EXIT_USER_ERROR, stderr
    assert stderr.startswith("polarbssrdf reconstruct: error: ") and stderr.count("\n") == 1
    for text in expected:
        assert text in stderr
    assert not outdir.exists()  # refused before anything was written


def test_capture_without_mesh(capture_dir, config_file, tmp_path):
    copy = tmp_path / "capture"
    shutil.copytree(capture_dir, copy)
    manifest = json.loads((copy / "capture.json").read_text())
    manifest["mesh"] = None
    (copy / "capture.json").write_text(json.dumps(manifest))
    status, _, stderr = run_cli(*reconstruct_args(copy, tmp_path / "out", config_file))
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "no mesh" in stderr
