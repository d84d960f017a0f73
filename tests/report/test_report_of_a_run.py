"""The report and ``reconstruct``'s warnings on a real (tiny) run (issue 32, items 5 and 6).

One tiny synthetic sphere (4 views, 48 x 48 px, T = 32) and one static run of 2 epochs
with camera cam03 held out, made once for the module (well under a minute): three fitted
cameras of a ring see a texel of the sphere with a median of 2 usable views.
"""

from __future__ import annotations

import json
import shutil

import pytest

import mitsuba as mi

from helpers import run_cli

T = 32
SETTINGS = dict(object="sphere", views=4, resolution=48, texture=T, spp=4)


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    directory = tmp_path_factory.mktemp("report_run") / "capture"
    synthesize(directory, SynthesisSettings(**SETTINGS), progress=False)
    return directory


@pytest.fixture(scope="module")
def run(capture_dir, tmp_path_factory):
    """``reconstruct CAPTURE OUT --stages static --holdout cam03`` (2 epochs): its output."""
    config = tmp_path_factory.mktemp("config") / "small.json"
    config.write_text(json.dumps({"patch_size": 16, "min_steps_per_epoch": 2}))
    outdir = tmp_path_factory.mktemp("report_runs") / "out"
    status, stdout, stderr = run_cli("reconstruct", capture_dir, outdir, "--stages", "static",
                                     "--iterations", "2", "--config", config, "--holdout",
                                     "cam03", "--quiet")
    assert status == 0, stderr
    return {"outdir": outdir, "stdout": stdout, "stderr": stderr}


@pytest.fixture(scope="module")
def own_report(run, tmp_path_factory):
    """``report OUT`` with the capture result.json records: the page's text."""
    page_path = tmp_path_factory.mktemp("own_report") / "report.html"
    status, _, stderr = run_cli("report", run["outdir"], "--out", page_path, "--quiet")
    assert status == 0, stderr
    return page_path.read_text()


def _copy_without_truth(capture_dir, target):
    """A copy of the capture without ``truth/``, its manifest as a real capture's."""
    shutil.copytree(capture_dir, target, ignore=shutil.ignore_patterns("truth"))
    manifest = json.loads((target / "capture.json").read_text())
    manifest.update(synthetic=False, truth=None)
    (target / "capture.json").write_text(json.dumps(manifest))
    return target


# --------------------------------------------------------------------------- item 6
def test_the_header_names_the_capture_passed_with_capture(run, own_report, capture_dir,
                                                          tmp_path):
    """``report RES --capture NOTRUTH`` said "of capture <the one result.json records>"."""
    notruth = _copy_without_truth(capture_dir, tmp_path / "notruth")
    page_path = tmp_path / "report.html"
    status, _, stderr = run_cli("report", run["outdir"], "--capture", notruth, "--out",
                                page_path, "--quiet")
    assert status == 0, stderr
    page = page_path.read_text()
    header = page.split('<p class="meta">', 1)[1].split("</p>", 1)[0]
    assert f"of capture\n<code>{notruth.resolve()}</code>" in header
    assert f"the maps were fitted on <code>{capture_dir.resolve()}</code>" in header
    assert "without ground truth (the capture has no ground truth)" in header

    # with the capture result.json records, the header names it and nothing else
    header = own_report.split('<p class="meta">', 1)[1].split("</p>", 1)[0]
    assert f"of capture\n<code>{capture_dir.resolve()}</code>" in header
    assert "fitted on" not in header


# --------------------------------------------------------------------------- item 5
def test_too_few_views_per_texel_is_warned_by_reconstruct_and_atop_the_report(run, own_report):
    """Three fitted cameras of a ring: six static maps lost to a constant and the bio std
    covered a third of the errors, exit 0, without a word."""
    warnings = [line for line in run["stderr"].splitlines()
                if line.startswith("polarbssrdf reconstruct: warning: static frame 0: ")]
    assert len(warnings) == 1, run["stderr"]
    assert ("a median of 2 usable views per confident texel, fewer than the 4 the glossy "
            "lobes need") in warnings[0]
    assert "biophysical posterior std" not in warnings[0]  # no bio stage in this run
    views = json.loads((run["outdir"] / "metrics.json").read_text())["views"]
    assert views["frame"] == 0 and views["median_views"] == 2 and views["views_needed"] == 4
    assert views["trusted"] is False and views["confident_texels"] > 0

    top = own_report.split("<nav>", 1)[0]  # above the first section
    assert '<p class="warning" id="untrusted">' in top
    assert "These maps and their uncertainty cannot be trusted" in top
    assert "a median of 2 usable views per confident texel" in top


def test_the_views_criterion_reads_the_views_from_the_confidence_map():
    import numpy as np

    from polarbssrdf.inverse.evaluation.trust import VIEWS_NEEDED, usable_views, views_check

    assert VIEWS_NEEDED == 4  # rho_s, alpha_s, rho_ss, alpha_ss
    views = np.array([[0, 2, 3, 4], [5, 8, 9, 12]])
    confidence = np.minimum(1.0, views / 8.0)  # the static stage's min(1, n / 8)
    np.testing.assert_array_equal(usable_views(confidence), np.minimum(views, 8))

    def check(counts, valid=None):
        return views_check(np.minimum(1.0, np.asarray(counts, float) / 8.0), valid)

    assert check([[2, 2, 3, 0]])["median_views"] == 2 and not check([[2, 2, 3, 0]])["trusted"]
    assert check([[3, 4, 5, 0]])["trusted"]  # median 4: enough
    assert check([[12, 9, 3, 0]])["trusted"]  # full confidence counts as 8
    on_mesh = np.array([[True, True, False, True]])
    assert check([[2, 5, 2, 9]], on_mesh)["median_views"] == 5  # off the mesh: not counted
    assert check([[0, 0, 0, 0]]) is None  # nothing confident: nothing to judge
