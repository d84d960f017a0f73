"""What ``reconstruct`` reads is what it checks (issue 21): image values, cache fingerprints.

Each test copies the tiny session capture (tests/inverse/conftest.py), changes it the way
a user's file goes wrong, and runs the command in this process for one epoch.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from helpers import run_cli
from polarbssrdf.errors import EXIT_USER_ERROR

SMALL = {"patch_size": 16, "min_steps_per_epoch": 1}


@pytest.fixture
def config_file(tmp_path):
    path = tmp_path / "small.json"
    path.write_text(json.dumps(SMALL))
    return path


def _copy(source, target):
    shutil.copytree(source, target)
    return target


def _image(capture_dir, camera="cam01"):
    return capture_dir / "images" / "f0000" / f"{camera}_light{camera[3:]}.exr"


def _rewrite(path, change):
    from polarbssrdf.io.exr import read_exr, write_exr

    channels, metadata = read_exr(path)
    write_exr(path, change(channels), metadata=metadata, overwrite=True, allow_nonfinite=True)


def _loader_message(capture_dir):
    from polarbssrdf.io import load_capture

    with pytest.raises(ValueError) as caught:
        load_capture(capture_dir, check_images=True)
    return str(caught.value)


def _reconstruct(capture_dir, outdir, config_file, *extra):
    return run_cli("reconstruct", capture_dir, outdir, "--stages", "static", "--iterations", "1",
                   "--config", config_file, "--quiet", *extra)


# --------------------------------------------------------------------------- item 2
@pytest.mark.parametrize("damage", ["negated", "infinite"])
def test_images_are_checked_as_read_with_the_loaders_message(damage, sphere_capture_dir,
                                                             config_file, tmp_path):
    """A negated image (or one infinite pixel) fitted with exit 0 before; now the loader's
    own message, one line, status 2."""
    capture = _copy(sphere_capture_dir, tmp_path / "capture")

    def change(channels):
        if damage == "negated":
            return {name: -values for name, values in channels.items()}
        channels["GA.I90"][20, 11] = np.inf
        return channels

    _rewrite(_image(capture), change)
    expected = _loader_message(capture)
    assert ("negative intensity" if damage == "negated" else "1 infinite") in expected
    status, _, stderr = _reconstruct(capture, tmp_path / "out", config_file)
    assert status == EXIT_USER_ERROR
    assert stderr == f"polarbssrdf reconstruct: error: {expected}\n"


def test_nan_pixels_still_pass_as_missing_data(sphere_capture_dir, config_file, tmp_path):
    """The loader refuses NaN; the builder keeps it as missing data (dropped texel-views)."""
    capture = _copy(sphere_capture_dir, tmp_path / "capture")

    def change(channels):
        channels["GA.I90"][20:24, 10:14] = np.nan
        return channels

    _rewrite(_image(capture), change)
    assert "NaN" in _loader_message(capture)
    status, _, stderr = _reconstruct(capture, tmp_path / "out", config_file)
    assert status == 0, stderr
