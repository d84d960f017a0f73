"""Issue 32: what ``reconstruct`` writes is safe from ``--out``, from truncated checkpoints,
from SIGTERM, and from the Python API's string arguments.

The session's two-frame tiny sphere (4 views, 48 x 48 px, T = 16; frame 0 is fitted) and
one 2-epoch static run per module; the refusals are checked before any work, so the module
takes seconds past its fixtures.
"""

from __future__ import annotations

import hashlib
import json

import pytest

from helpers import run_cli
from polarbssrdf.errors import EXIT_USER_ERROR

CONFIG = {"patch_size": 16, "min_steps_per_epoch": 1}


@pytest.fixture(scope="module")
def capture_dir(two_frame_sphere_dir):
    """The session's two-frame sphere (tests/inverse/conftest.py; the static stage fits frame
    0), shared with test_stage_plan.py; never written to."""
    return two_frame_sphere_dir


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "small.json"
    path.write_text(json.dumps(CONFIG))
    return path


def static_args(capture_dir, outdir, config_file, *extra):
    return ("reconstruct", capture_dir, outdir, "--stages", "static", "--iterations", "2",
            "--config", config_file, "--quiet", *extra)


@pytest.fixture(scope="module")
def result_dir(capture_dir, config_file, tmp_path_factory):
    outdir = tmp_path_factory.mktemp("protected_run") / "R"
    status, _, stderr = run_cli(*static_args(capture_dir, outdir, config_file))
    assert status == 0, stderr
    return outdir


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- item 1
@pytest.mark.parametrize("command, name", [
    ("evaluate", "metrics.json"), ("report", "metrics.json"),
    ("evaluate", "static/checkpoint.npz"), ("evaluate", "timings.json"),
    ("report", "static/previews/eta_f0000.png"), ("evaluate", "report.html"),
])
def test_out_never_replaces_a_file_of_the_result(result_dir, command, name):
    target = result_dir / name
    if name == "report.html":
        target.write_text("<html>an earlier report</html>")
    before = digest(target)
    status, _, stderr = run_cli(command, result_dir, "--out", target)
    assert status == EXIT_USER_ERROR, stderr
    assert stderr.count("\n") == 1 and "would overwrite a file of the result" in stderr
    assert str(target) in stderr
    assert digest(target) == before


def test_out_may_not_write_inside_a_stage_directory(result_dir):
    target = result_dir / "static" / "evaluation.json"
    status, _, stderr = run_cli("evaluate", result_dir, "--out", target)
    assert status == EXIT_USER_ERROR and "inside the result's static/ directory" in stderr
    assert not target.exists()


# --------------------------------------------------------------------------- item 7
@pytest.mark.parametrize("damage", ["truncated", "replaced"])
def test_a_damaged_checkpoint_on_resume_is_one_line_naming_it(result_dir, capture_dir,
                                                              config_file, tmp_path, damage):
    import shutil

    outdir = tmp_path / "R"
    shutil.copytree(result_dir, outdir)
    checkpoint = outdir / "static" / "checkpoint.npz"
    data = checkpoint.read_bytes()
    checkpoint.write_bytes(data[:len(data) // 2] if damage == "truncated" else b'{"a": 1}\n')
    status, _, stderr = run_cli(*static_args(capture_dir, outdir, config_file, "--resume"))
    assert status == EXIT_USER_ERROR, stderr
    assert stderr.count("\n") == 1 and str(checkpoint) in stderr and "unreadable" in stderr


# --------------------------------------------------------------------------- item 12
def test_python_api_takes_a_string_or_a_sequence_of_names(capture_dir, tmp_path):
    from polarbssrdf.inverse import reconstruct

    result = reconstruct(capture_dir, tmp_path / "R", stages="static", holdout="cam03",
                         config=dict(CONFIG, iterations=1), progress=False)
    settings = json.loads((tmp_path / "R" / "result.json").read_text())["settings"]
    assert settings["stages"] == ["static"] and settings["holdout"] == ["cam03"]
    assert result.holdout == ["cam03"] and result.stages == ["static"]


@pytest.mark.parametrize("keywords, named, not_named", [
    (dict(stages="static,colour"), "in stages;", "--stages"),
    (dict(holdout=("cam01", "cam99")), "holdout names unknown camera cam99", "--holdout"),
    (dict(texture=32.5), "texture must be an integer >= 8, got 32.5", "--texture"),
    (dict(iterations=-1), "iterations must be an integer >= 0", "--iterations"),
    (dict(frame="1"), "frame must be an integer >= 0", "--frame"),
    (dict(stages=3), "stages must be a string", "--stages"),
])
def test_python_api_refuses_before_writing_and_names_parameters(capture_dir, tmp_path,
                                                                keywords, named, not_named):
    from polarbssrdf.errors import CommandError
    from polarbssrdf.inverse import reconstruct

    outdir = tmp_path / "R"
    with pytest.raises(CommandError) as error:
        reconstruct(capture_dir, outdir, **{"stages": "static", **keywords},
                    config=dict(CONFIG, iterations=1), progress=False)
    assert named in str(error.value) and not_named not in str(error.value)
    assert not outdir.exists()


def test_python_api_messages_name_parameters_where_the_cli_names_options(result_dir,
                                                                         capture_dir,
                                                                         config_file):
    from polarbssrdf.inverse import reconstruct

    with pytest.raises(FileExistsError) as error:
        reconstruct(capture_dir, result_dir, stages="static", progress=False)
    assert "resume=True" in str(error.value) and "overwrite=True" in str(error.value)
    assert "--resume" not in str(error.value)
    status, _, stderr = run_cli(*static_args(capture_dir, result_dir, config_file))
    assert status == EXIT_USER_ERROR and "--resume" in stderr and "resume=True" not in stderr
