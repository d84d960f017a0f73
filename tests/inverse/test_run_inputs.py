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


# --------------------------------------------------------------------------- item 3
def _write_uncompressed(path, channels):
    """An uncompressed EXR: its size depends only on the image size, not the values."""
    import OpenEXR

    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {n: np.ascontiguousarray(v) for n, v in channels.items()}).write(
        str(path))


def _replace_keeping_size_and_time(path, scale):
    """Re-export ``path`` (uncompressed) with values times ``scale``, restoring its mtime:
    what ``cp -p`` / ``rsync -a`` of a re-rendered image does."""
    import os

    from polarbssrdf.io.exr import read_exr

    before = os.stat(path)
    channels, _ = read_exr(path)
    _write_uncompressed(path, {name: values * np.float32(scale)
                               for name, values in channels.items()})
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    after = os.stat(path)
    assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)


def _view_samples(store, camera):
    """``texel -> analyser samples`` of one camera's texel-views in a store."""
    view = [v["camera"] for v in store.views].index(camera)
    rows = store.read_rows(0, len(store))
    keep = rows.view == view
    order = np.argsort(rows.texel[keep])
    return rows.texel[keep][order], rows.analyser[keep][order]


@pytest.fixture
def uncompressed_capture(sphere_capture_dir, tmp_path):
    """A copy of the capture whose cam01 image is stored uncompressed (same values)."""
    from polarbssrdf.io.exr import read_exr

    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    channels, _ = read_exr(_image(capture))
    _write_uncompressed(_image(capture), channels)
    return capture


def test_the_cache_fingerprint_is_the_images_content(uncompressed_capture, tmp_path):
    """An image replaced by one of the same size and time: the store is rebuilt from it."""
    import hashlib

    from polarbssrdf.inverse.observations.build import load_or_build_observations

    path = tmp_path / "observations.zarr"
    first = load_or_build_observations(uncompressed_capture, 0, 32, path, block_size=8,
                                       progress=False)
    texels, samples = _view_samples(first, "cam01")
    recorded = dict(first.attrs["fingerprint_inputs"]["images"])
    image = _image(uncompressed_capture)
    expected = hashlib.blake2b(image.read_bytes(), digest_size=16).hexdigest()
    assert recorded[str(image.relative_to(uncompressed_capture))] == expected

    _replace_keeping_size_and_time(image, 0.5)
    second = load_or_build_observations(uncompressed_capture, 0, 32, path, block_size=8,
                                        progress=False)
    assert second.fingerprint != first.fingerprint
    texels_again, samples_again = _view_samples(second, "cam01")
    np.testing.assert_array_equal(texels_again, texels)
    np.testing.assert_allclose(samples_again, 0.5 * samples, rtol=1e-6)


def test_overwrite_rebuilds_the_observation_cache(sphere_capture_dir, config_file, tmp_path):
    """--overwrite starts over from the images on disk, the cache included: a cache whose
    fingerprint matches but whose samples are not the images' (here doubled by hand) is
    not reused."""
    import zarr

    from polarbssrdf.inverse.observations.store import ObservationStore

    outdir = tmp_path / "out"
    status, _, stderr = _reconstruct(sphere_capture_dir, outdir, config_file)
    assert status == 0, stderr
    store = outdir / "observations" / "f0000.zarr"
    texels, samples = _view_samples(ObservationStore.open(store), "cam01")
    analyser = zarr.open_group(str(store), mode="r+")["analyser"]
    analyser[:] = 2 * analyser[:]
    status, _, stderr = _reconstruct(sphere_capture_dir, outdir, config_file, "--overwrite")
    assert status == 0, stderr
    texels_again, samples_again = _view_samples(ObservationStore.open(store), "cam01")
    np.testing.assert_array_equal(texels_again, texels)
    np.testing.assert_array_equal(samples_again, samples)
