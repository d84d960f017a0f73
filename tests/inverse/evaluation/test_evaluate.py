"""``evaluate_result`` and ``polarbssrdf evaluate``: scores against the truth, held-out re-renders.

Results here are written by hand with :mod:`polarbssrdf.inverse.results.directory`'s
helpers (the truth maps, changed in known ways), so every expected score is
known exactly; no optimization runs.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import mitsuba as mi

from helpers import run_cli
from polarbssrdf.errors import EXIT_USER_ERROR

T = 32  # the texture size of the shared capture (conftest.TINY)
RESULT_CHANNELS = ("eta", "alpha_s", "alpha_ss", "rho_s", "rho_ss", "displacement")


@pytest.fixture(scope="module")
def capture_dir(sphere_capture_dir):
    """The session's tiny sphere (tests/inverse/conftest.py); tests that change it copy it."""
    return sphere_capture_dir


@pytest.fixture(scope="module")
def capture(capture_dir):
    from polarbssrdf.io import load_capture

    return load_capture(capture_dir, check_images=False)


@pytest.fixture(scope="module")
def atlas(capture):
    from polarbssrdf.geometry import texel_atlas, to_mitsuba

    mi.set_variant("llvm_ad_mono_polarized")
    return texel_atlas(to_mitsuba(capture.load_mesh()), T)


@pytest.fixture(scope="module")
def truth_result_maps(capture, atlas):
    """The truth in the result format: truth channels, normals of the truth H, confidence 1."""
    from polarbssrdf.geometry.height import normals_from_height

    truth = capture.truth_maps(0)
    maps = {name: truth[name] for name in RESULT_CHANNELS}
    maps.update({name: values for name, values in truth.items() if name.startswith("rho_sss.")})
    normal = normals_from_height(truth["displacement"].astype(np.float64) * atlas.valid, atlas)
    for k, axis in enumerate("xyz"):
        maps[f"normal.{axis}"] = normal[..., k].astype(np.float32)
    maps["confidence"] = np.ones((T, T), np.float32)
    return maps


def fake_result(outdir, capture_dir, maps, holdout=(), texture=T):
    from polarbssrdf.inverse.results.directory import prepare_result_directory, write_stage_maps

    prepare_result_directory(outdir, capture_dir, texture, {"holdout": list(holdout)})
    write_stage_maps(outdir, "static", 0, {k: np.asarray(v, np.float32) for k, v in maps.items()})
    return outdir


def test_truth_maps_score_zero_and_constant_mae_is_the_mean_absolute_deviation(
        capture_dir, capture, atlas, truth_result_maps, tmp_path):
    from polarbssrdf.inverse.evaluation.scores import evaluate_result

    outdir = fake_result(tmp_path / "out", capture_dir, truth_result_maps)
    report = evaluate_result(outdir)  # the capture recorded in result.json
    valid = np.asarray(atlas.valid, bool)
    assert report["texels_scored"] == int(valid.sum()) > 0.9 * T * T
    truth = capture.truth_maps(0)
    for name in ("eta", "alpha_s", "alpha_ss", "displacement"):
        assert report["maps"][name]["mae"] < 1e-7, name
        values = truth[name][valid].astype(np.float64)
        deviation = np.abs(values - values.mean()).mean()
        assert report["maps"][name]["constant_mae"] == pytest.approx(deviation, rel=1e-9), name
        assert deviation > 0
    for name in ("rho_s", "rho_ss"):
        assert report["maps"][name]["relative_error"] < 1e-7
    bands = report["maps"]["rho_sss"]["bands"]
    assert set(bands) == set(capture.manifest.band_names)
    assert all(entry["relative_error"] < 1e-7 for entry in bands.values())
    assert report["maps"]["normal"]["mean_deg"] < 1e-3
    assert report["maps"]["normal"]["median_deg"] < 1e-3
    assert report["maps"]["normal"]["base_mesh_mean_deg"] > 0.01  # the truth H tilts normals
    assert report["holdout"] is None
    assert report["maps"]["displacement"]["unit"] == "mm"


def test_known_offset_and_unconfident_texels(capture_dir, truth_result_maps, tmp_path):
    from polarbssrdf.inverse.evaluation.scores import evaluate_result

    maps = dict(truth_result_maps)
    maps["eta"] = maps["eta"] + np.float32(0.01)
    maps["rho_s"] = maps["rho_s"] * np.float32(1.1)
    confidence = np.ones((T, T), np.float32)
    confidence[:, : T // 2] = 0.0  # garbage there must not count
    maps["alpha_s"] = np.where(confidence > 0, maps["alpha_s"], 0.7).astype(np.float32)
    maps["confidence"] = confidence
    report = evaluate_result(fake_result(tmp_path / "out", capture_dir, maps), capture_dir)
    assert report["maps"]["eta"]["mae"] == pytest.approx(0.01, abs=2e-6)
    assert report["maps"]["rho_s"]["relative_error"] == pytest.approx(0.1, abs=1e-5)
    assert report["maps"]["alpha_s"]["mae"] < 1e-7
    assert report["texels_scored"] <= T * T // 2
    assert report["texels_confident"] == T * T // 2


def test_alpha_s_is_also_scored_per_specular_peak_angle(capture_dir, capture, atlas,
                                                       truth_result_maps, tmp_path):
    """Known errors per class: 0.01 below 10 degrees, 0.03 from 30 degrees, none between."""
    from polarbssrdf.inverse.evaluation.scores import evaluate_result

    maps = dict(truth_result_maps)
    assert "by_specular_peak_angle" not in evaluate_result(
        fake_result(tmp_path / "without", capture_dir, maps), capture_dir)["maps"]
    rows = np.arange(T)[:, None] * np.ones((1, T))
    angle = np.where(rows < 8, 5.0, np.where(rows < 16, 15.0, np.where(rows < 24, 25.0, 90.0)))
    offset = np.where(angle < 10, 0.01, np.where(angle >= 30, -0.03, 0.0))
    maps["alpha_s"] = (maps["alpha_s"] + offset).astype(np.float32)
    maps["specular_peak_angle"] = angle.astype(np.float32)
    report = evaluate_result(fake_result(tmp_path / "with", capture_dir, maps), capture_dir)
    classes = report["maps"]["by_specular_peak_angle"]["alpha_s"]
    assert [(c["from_deg"], c["to_deg"]) for c in classes] == [(0, 10), (10, 20), (20, 30),
                                                               (30, 90)]
    for entry, error in zip(classes, (0.01, 0.0, 0.0, 0.03)):
        assert entry["mae"] == pytest.approx(error, abs=2e-6)
    valid = np.asarray(atlas.valid, bool)
    assert sum(c["texels"] for c in classes) == report["texels_scored"] == int(valid.sum())
    assert sum(c["fraction"] for c in classes) == pytest.approx(1.0)
    # one constant for every class: the truth's mean over all scored texels
    truth = capture.truth_maps(0)["alpha_s"].astype(np.float64)
    mean = truth[valid].mean()
    members = valid & (angle >= 30)
    assert classes[3]["constant_mae"] == pytest.approx(np.abs(truth[members] - mean).mean())
    assert report["maps"]["alpha_s"]["mae"] == pytest.approx(
        sum(c["mae"] * c["fraction"] for c in classes), abs=2e-6)


def test_holdout_rerender_of_the_truth_and_of_darker_subsurface(capture_dir, truth_result_maps,
                                                                tmp_path):
    """Local lobe vs the capture's texture-space diffusion: small for the truth, > 2x at 0.7."""
    from polarbssrdf.inverse.evaluation.scores import evaluate_result

    report = evaluate_result(fake_result(tmp_path / "truth", capture_dir, truth_result_maps,
                                         holdout=["cam00"]))
    holdout = report["holdout"]
    camera = holdout["cameras"]["cam00"]
    assert camera["pixels"] > 300 and camera["clamped_texels"] == {}
    assert set(camera["bands"]) == set(report["maps"]["rho_sss"]["bands"])
    truth_error = holdout["mean"]["relative_rmse_I_sss"]
    assert truth_error < 0.05
    assert holdout["mean"]["relative_rmse_I_s"] < 0.05

    darker = dict(truth_result_maps)
    for name in darker:
        if name.startswith("rho_sss."):
            darker[name] = darker[name] * np.float32(0.7)
    report = evaluate_result(fake_result(tmp_path / "darker", capture_dir, darker,
                                         holdout=["cam00"]))
    assert report["holdout"]["mean"]["relative_rmse_I_sss"] > 2 * truth_error
    # the glossy part is not changed by rho_sss
    assert report["holdout"]["mean"]["relative_rmse_I_s"] < 0.05


def test_evaluate_command_prints_and_writes_json(capture_dir, truth_result_maps, tmp_path):
    outdir = fake_result(tmp_path / "out", capture_dir, truth_result_maps)
    report_path = tmp_path / "reports" / "evaluation.json"
    status, stdout, stderr = run_cli("evaluate", outdir, "--truth", capture_dir,
                                     "--out", report_path)
    assert status == 0, stderr
    printed = json.loads(stdout)
    assert json.loads(report_path.read_text()) == printed
    assert printed["schema"] == "polarbssrdf.evaluation" and printed["stage"] == "static"
    assert printed["maps"]["eta"]["mae"] < 1e-7


def _no_truth_copy(capture_dir, target):
    shutil.copytree(capture_dir, target)
    manifest = json.loads((target / "capture.json").read_text())
    manifest["truth"] = None
    (target / "capture.json").write_text(json.dumps(manifest))
    shutil.rmtree(target / "truth")
    return target


@pytest.mark.parametrize("case", ["no_stage", "no_truth", "texture", "no_result", "out_input"])
def test_evaluate_errors_are_one_line(case, capture_dir, truth_result_maps, tmp_path):
    from polarbssrdf.inverse.results.directory import prepare_result_directory

    outdir = tmp_path / "out"
    extra = []
    if case == "no_stage":
        prepare_result_directory(outdir, capture_dir, T, {})
        expected = "no 'static' maps"
    elif case == "no_truth":
        fake_result(outdir, capture_dir, truth_result_maps)
        extra = ["--truth", _no_truth_copy(capture_dir, tmp_path / "bare")]
        expected = "has no ground truth"
    elif case == "texture":
        small = {name: values[::2, ::2] for name, values in truth_result_maps.items()}
        fake_result(outdir, capture_dir, small, texture=T // 2)
        expected = "texture size mismatch"
    elif case == "no_result":
        outdir.mkdir()
        expected = "result.json"
    else:
        fake_result(outdir, capture_dir, truth_result_maps)
        extra = ["--out", outdir / "result.json"]
        expected = "would overwrite"
    status, _, stderr = run_cli("evaluate", outdir, *extra)
    assert status == EXIT_USER_ERROR, stderr
    assert stderr.startswith("polarbssrdf evaluate: error: ") and stderr.count("\n") == 1
    assert expected in stderr


def test_holdout_of_a_raw_capture_is_compared_in_radiance(sphere_raw_capture_dir):
    """Raw mosaics are calibrated and demosaicked: the truth re-renders within sensor noise."""
    from polarbssrdf.io import load_capture
    from polarbssrdf.inverse.evaluation.rerender import holdout_errors

    mi.set_variant("llvm_ad_mono_polarized")
    capture = load_capture(sphere_raw_capture_dir, check_images=False)
    truth = capture.truth_maps(0)
    errors = holdout_errors(capture, truth, ["cam00"])["mean"]
    assert errors["relative_rmse_I_sss"] < 0.06
    darker = {k: (v * np.float32(0.7) if k.startswith("rho_sss.") else v)
              for k, v in truth.items()}
    assert holdout_errors(capture, darker, ["cam00"])["mean"]["relative_rmse_I_sss"] \
        > 2 * errors["relative_rmse_I_sss"]


def test_evaluate_without_truth_prints_the_held_out_re_render_as_json(capture_dir,
                                                                      truth_result_maps,
                                                                      tmp_path):
    """A real capture (no truth) was refused outright: its held-out re-render error existed
    only as text in the report (issue 21, item 13)."""
    outdir = fake_result(tmp_path / "out", capture_dir, truth_result_maps, holdout=["cam00"])
    bare = _no_truth_copy(capture_dir, tmp_path / "bare")
    report_path = tmp_path / "evaluation.json"
    status, stdout, stderr = run_cli("evaluate", outdir, "--truth", bare, "--spp", "4",
                                     "--out", report_path)
    assert status == 0, stderr
    printed = json.loads(stdout)
    assert json.loads(report_path.read_text()) == printed
    assert printed["schema"] == "polarbssrdf.evaluation" and printed["maps"] is None
    assert printed["truth"] is None and printed["stage"] == "static"
    camera = printed["holdout"]["cameras"]["cam00"]
    assert camera["pixels"] > 300
    # the truth maps re-render the capture within the local lobe's few percent
    assert printed["holdout"]["mean"]["relative_rmse_I_sss"] < 0.05

    # the bio maps are not rendered: one line saying what applies
    status, _, stderr = run_cli("evaluate", outdir, "--truth", bare, "--stage", "bio")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "--stage static or dynamic" in stderr
