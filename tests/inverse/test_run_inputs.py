"""What ``reconstruct``, ``evaluate`` and ``report`` check before they trust their inputs
(issue 21, items 2-8 and 10): image values as read, content fingerprints of the cache, the
capture's identity, the confident share of the surface, the memory a run needs, the
scheduler, damaged EXRs and meshes.

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


# --------------------------------------------------------------------------- item 4
@pytest.fixture(scope="module")
def fitted(sphere_capture_dir, tmp_path_factory):
    """A one-epoch static result of the analyser sphere (T = 32, its truth's size)."""
    root = tmp_path_factory.mktemp("fitted")
    config = root / "small.json"
    config.write_text(json.dumps(SMALL))
    status, _, stderr = _reconstruct(sphere_capture_dir, root / "result", config)
    assert status == 0, stderr
    return root / "result"


def test_result_json_records_the_captures_identity(fitted, sphere_capture_dir):
    import hashlib

    identity = json.loads((fitted / "result.json").read_text())["capture_identity"]
    images = sorted((sphere_capture_dir / "images" / "f0000").glob("*.exr"))
    assert identity["frame"] == 0 and identity["hash"] == "blake2b-128"
    assert identity["images"] == {
        str(path.relative_to(sphere_capture_dir)):
            hashlib.blake2b(path.read_bytes(), digest_size=16).hexdigest() for path in images}
    manifest = json.loads((sphere_capture_dir / "capture.json").read_text())
    mesh = sphere_capture_dir / manifest["mesh"]
    assert identity["mesh"] == hashlib.blake2b(mesh.read_bytes(), digest_size=16).hexdigest()


def test_evaluate_refuses_another_captures_truth_unless_forced(fitted, sphere_capture_dir,
                                                               sphere_raw_capture_dir):
    """The raw sphere has truth of the same size: it scored 'plausibly' with exit 0."""
    status, stdout, stderr = run_cli("evaluate", fitted, "--truth", sphere_raw_capture_dir)
    assert status == EXIT_USER_ERROR and stdout == ""
    assert stderr.count("\n") == 1
    assert f"--truth '{sphere_raw_capture_dir}' is not the capture" in stderr
    assert f"'{sphere_capture_dir.resolve()}'" in stderr  # the result's own capture
    assert "capture.json differs" in stderr and "--force" in stderr

    status, stdout, stderr = run_cli("evaluate", fitted, "--truth", sphere_raw_capture_dir,
                                     "--force")
    assert status == 0, stderr
    assert json.loads(stdout)["maps"]["eta"]["mae"] >= 0
    assert stderr.startswith("polarbssrdf evaluate: warning: ") and stderr.count("\n") == 1

    status, stdout, stderr = run_cli("evaluate", fitted)  # the recorded capture: its own
    assert status == 0 and stderr == "", stderr


def test_a_capture_with_other_image_contents_is_not_the_results(fitted, sphere_capture_dir,
                                                                tmp_path):
    """Same capture.json, one image changed: named; a copy without its truth is the same
    capture (the identity is what was measured)."""
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.identity import capture_identity

    changed = _copy(sphere_capture_dir, tmp_path / "changed")
    _rewrite(_image(changed, "cam02"), lambda c: {n: 0.9 * v for n, v in c.items()})
    status, _, stderr = run_cli("evaluate", fitted, "--truth", changed)
    assert status == EXIT_USER_ERROR
    assert "1 of 4 images of frame 0 have other contents (e.g. images/f0000/cam02" in stderr
    assert "capture.json differs" not in stderr

    moved = _copy(sphere_capture_dir, tmp_path / "moved")  # another path, same capture
    without_truth = _copy(sphere_capture_dir, tmp_path / "real")
    manifest = json.loads((without_truth / "capture.json").read_text())
    manifest.update(synthetic=False, truth=None)
    (without_truth / "capture.json").write_text(json.dumps(manifest, indent=4))
    shutil.rmtree(without_truth / "truth")
    original = capture_identity(load_capture(sphere_capture_dir, check_images=False), 0)
    for copy in (moved, without_truth):
        assert capture_identity(load_capture(copy, check_images=False), 0) == original


def test_report_refuses_another_capture_unless_forced(fitted, sphere_raw_capture_dir, tmp_path,
                                                     monkeypatch):
    from polarbssrdf.report import page

    written = []

    def fake_report(result_dir, out, **keywords):  # the check is the point, not the page
        written.append(keywords["capture"])
        out.write_text("<html></html>")
        return out

    monkeypatch.setattr(page, "write_report", fake_report)
    out = tmp_path / "report.html"
    status, _, stderr = run_cli("report", fitted, "--capture", sphere_raw_capture_dir,
                                "--out", out, "--quiet")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert f"--capture '{sphere_raw_capture_dir}' is not the capture" in stderr
    assert not written and not out.exists()
    status, _, stderr = run_cli("report", fitted, "--capture", sphere_raw_capture_dir,
                                "--out", out, "--quiet", "--force")
    assert status == 0 and written == [sphere_raw_capture_dir], stderr
    assert "warning" in stderr


def test_resume_and_later_stages_refuse_a_capture_whose_contents_changed(sphere_capture_dir,
                                                                         config_file, tmp_path):
    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    outdir = tmp_path / "out"
    status, _, stderr = _reconstruct(capture, outdir, config_file)
    assert status == 0, stderr
    _rewrite(_image(capture, "cam00"), lambda c: {n: 0.9 * v for n, v in c.items()})
    before = (outdir / "result.json").read_text()
    status, _, stderr = _reconstruct(capture, outdir, config_file, "--resume")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "capture contents: 1 of 4 images of frame 0 have other contents" in stderr
    status, _, stderr = run_cli("reconstruct", capture, outdir, "--stages", "bio", "--quiet")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "is not the capture the result" in stderr and "images/f0000/cam00" in stderr
    assert (outdir / "result.json").read_text() == before


# --------------------------------------------------------------------------- item 5
def _surface(capture_dir):
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.io import load_capture
    from polarbssrdf.variants import ensure_jit_variant

    ensure_jit_variant()
    return texel_atlas(to_mitsuba(load_capture(capture_dir, check_images=False).load_mesh()),
                       32).valid


def test_the_confident_share_of_the_surface_is_in_metrics_json(fitted, sphere_capture_dir):
    from polarbssrdf.io.exr import read_exr

    confidence, _ = read_exr(fitted / "static" / "maps_f0000.exr")
    valid = _surface(sphere_capture_dir)
    recorded = json.loads((fitted / "metrics.json").read_text())["confidence"]["static"]["0"]
    assert recorded["surface_texels"] == int(valid.sum())
    assert recorded["confident_texels"] == int(((confidence["confidence"] > 0) & valid).sum())
    assert recorded["confident_fraction"] == pytest.approx(
        recorded["confident_texels"] / recorded["surface_texels"], abs=1e-4)
    assert 0 < recorded["confident_fraction"] < 1  # 4 ring views never see the poles


def test_a_low_confident_share_is_said_and_warned(sphere_capture_dir, tmp_path):
    """min_views 3 of 4 ring cameras: few texels are seen by 3 of them."""
    config = tmp_path / "strict.json"
    config.write_text(json.dumps({**SMALL, "min_views": 3}))
    outdir = tmp_path / "out"
    status, _, stderr = run_cli("reconstruct", sphere_capture_dir, outdir, "--stages", "static",
                                "--iterations", "1", "--config", config)
    assert status == 0, stderr
    share = json.loads((outdir / "metrics.json").read_text())["confidence"]["static"]["0"]
    assert share["confident_fraction"] < 0.5
    percent = f"{100 * share['confident_fraction']:.1f}%"
    lines = [line for line in stderr.splitlines() if line.startswith("polarbssrdf reconstruct: ")]
    assert f"polarbssrdf reconstruct: static: {percent} of the surface is confident " \
           "(metrics.json: confidence)" in lines
    # (the other warning: too few views per confident texel, issue 32 item 5)
    warnings = [line for line in lines if "warning" in line and "of the surface" in line]
    assert len(warnings) == 1 and f"only {percent} of the surface" in warnings[0]
    assert "below 50%" in warnings[0]


def test_a_fit_with_no_confident_texel_fails(sphere_capture_dir, config_file, tmp_path):
    """One camera: every texel has at most one usable view, so confidence 0 everywhere."""
    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    manifest = json.loads((capture / "capture.json").read_text())
    frame = manifest["frames"][0]
    frame["images"] = [record for record in frame["images"] if record["camera"] == "cam00"]
    (capture / "capture.json").write_text(json.dumps(manifest))
    outdir = tmp_path / "out"
    status, _, stderr = _reconstruct(capture, outdir, config_file)
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert "no texel of the surface is confident" in stderr
    assert "no texel has the 2 usable texel-views min_views asks for (at most 1)" in stderr
    assert json.loads((outdir / "result.json").read_text())["maps"] == []


# --------------------------------------------------------------------------- item 8
def test_a_truncated_image_is_named_in_one_line(sphere_capture_dir, config_file, tmp_path,
                                                capfd):
    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    image = _image(capture)
    image.write_bytes(image.read_bytes()[:image.stat().st_size // 2])
    capfd.readouterr()
    status, stdout, stderr = _reconstruct(capture, tmp_path / "out", config_file)
    assert status == EXIT_USER_ERROR and stdout == ""
    assert stderr.startswith(f"polarbssrdf reconstruct: error: '{image}' is not a readable "
                             "OpenEXR file (truncated or damaged: ")
    assert stderr.count("\n") == 1
    assert capfd.readouterr() == ("", "")  # nothing of OpenEXR's own on the descriptors


# --------------------------------------------------------------------------- item 10
@pytest.mark.parametrize("content", [b"", b"\x00\x01 not a mesh\nat all\n"])
def test_an_empty_or_garbage_mesh_is_not_read_as_one(content, sphere_capture_dir, config_file,
                                                     tmp_path):
    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    mesh = capture / json.loads((capture / "capture.json").read_text())["mesh"]
    mesh.write_bytes(content)
    status, _, stderr = _reconstruct(capture, tmp_path / "out", config_file)
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1
    assert f"{mesh}: could not be read as a mesh" in stderr
    assert "texture coordinates" not in stderr


def test_a_camera_whose_images_are_all_nan_is_one_line_of_ours(sphere_capture_dir, config_file,
                                                               tmp_path, capfd):
    capture = _copy(sphere_capture_dir, tmp_path / "capture")
    _rewrite(_image(capture), lambda c: {n: np.full_like(v, np.nan) for n, v in c.items()})
    capfd.readouterr()
    status, _, stderr = _reconstruct(capture, tmp_path / "out", config_file)
    assert status == 0, stderr
    lines = stderr.splitlines()
    assert lines[0] == ("polarbssrdf: warning: camera 'cam01' (light 'light01') sees no texel "
                        "of frame 0: the remaining texels sample non-finite (NaN) pixels; "
                        "skipping it")
    # three ring cameras leave most of the sphere unconfident: the second line says so, the
    # third that the confident texels have too few views (issue 32, item 5)
    assert len(lines) == 3 and lines[1].startswith("polarbssrdf reconstruct: warning: static")
    assert "usable views per confident texel" in lines[2]
    assert capfd.readouterr() == ("", "")  # no UserWarning with its source line


# --------------------------------------------------------------------------- item 7
def test_an_unreachable_scheduler_is_refused_before_any_stage(sphere_capture_dir, config_file,
                                                              tmp_path, monkeypatch):
    """Nothing listens on port 9: a 62-line traceback after the static stage before."""
    from polarbssrdf.inverse import frames

    monkeypatch.setattr(frames, "SCHEDULER_TIMEOUT_S", 1.0)
    outdir = tmp_path / "out"
    status, _, stderr = run_cli("reconstruct", sphere_capture_dir, outdir, "--iterations", "1",
                                "--config", config_file, "--scheduler", "tcp://127.0.0.1:9",
                                "--quiet")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1, stderr
    assert "no Dask scheduler answers at tcp://127.0.0.1:9" in stderr
    assert not outdir.exists()
    status, _, stderr = run_cli("reconstruct", sphere_capture_dir, outdir, "--scheduler",
                                "nohost", "--quiet")
    assert status == EXIT_USER_ERROR and "'nohost' is not a Dask scheduler address" in stderr
    demo = tmp_path / "demo"
    status, _, stderr = run_cli("demo", demo, "--scheduler", "tcp://127.0.0.1:9", "--quiet")
    assert status == EXIT_USER_ERROR and "tcp://127.0.0.1:9" in stderr and not demo.exists()


def test_a_running_scheduler_passes_the_check():
    from dask.distributed import LocalCluster

    from polarbssrdf.inverse.frames import check_scheduler

    with LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as cluster:
        check_scheduler(cluster.scheduler_address, timeout=5)


# --------------------------------------------------------------------------- item 6
def test_a_texture_too_large_for_the_machine_is_refused_before_anything_is_written(
        sphere_capture_dir, tmp_path):
    """--texture 100000: a NumPy _ArrayMemoryError traceback, with result.json left behind."""
    from polarbssrdf.inverse.resources import machine_memory

    outdir = tmp_path / "out"
    status, _, stderr = run_cli("reconstruct", sphere_capture_dir, outdir, "--texture", "100000",
                                "--quiet")
    assert status == EXIT_USER_ERROR and stderr.count("\n") == 1, stderr
    total, _ = machine_memory()
    assert "100000 x 100000 texels, 6 bands, 4 views" in stderr
    assert f"more than this machine's {total / 2**30:,.1f} GB" in stderr
    assert "use a smaller --texture" in stderr
    assert not outdir.exists()
    demo = tmp_path / "demo"
    status, _, stderr = run_cli("demo", demo, "--texture", "100000", "--quiet")
    assert status == EXIT_USER_ERROR and "the demo would need about" in stderr
    assert not demo.exists()


def test_the_memory_estimate_grows_with_the_texels_and_the_largest_texture_fits():
    from polarbssrdf.inverse import resources

    stages = ("static", "dynamic", "bio")
    base = resources.run_memory_bytes(0, 6, 8, stages)
    small, large = (resources.run_memory_bytes(t, 6, 8, stages) - base for t in (256, 1024))
    assert large == 16 * small > 0  # T^2
    assert resources.run_memory_bytes(256, 12, 8, stages) > resources.run_memory_bytes(
        256, 6, 8, stages)
    assert resources.run_memory_bytes(256, 6, 8, ("static",)) <= resources.run_memory_bytes(
        256, 6, 8, stages)
    for memory in (2**30, 24 * 2**30, 256 * 2**30):
        largest = resources.largest_texture(memory, 6, 8, stages)
        assert resources.run_memory_bytes(largest, 6, 8, stages) <= memory
        assert resources.run_memory_bytes(largest + 1, 6, 8, stages) > memory


def test_the_check_compares_with_the_machines_memory(monkeypatch, capsys):
    from polarbssrdf.errors import CommandError
    from polarbssrdf.inverse import resources

    stages = ("static",)
    needed = resources.run_memory_bytes(512, 6, 4, stages)
    monkeypatch.setattr(resources, "machine_memory", lambda: (needed - 1, needed - 1))
    with pytest.raises(CommandError, match="use a smaller --texture"):
        resources.check_memory(512, 6, 4, stages)
    monkeypatch.setattr(resources, "machine_memory", lambda: (needed, needed // 2))
    assert resources.check_memory(512, 6, 4, stages) == needed
    assert "warning" in capsys.readouterr().err  # fits the machine, not what is free now


def test_a_dask_worker_drops_only_the_heartbeat_failure_after_the_scheduler_left():
    """After Ctrl-C the cluster closes under a worker's heartbeat: that one message is not
    printed; the worker's other errors are."""
    import logging
    import signal

    from polarbssrdf.inverse import frames

    logger = logging.getLogger("distributed.worker")
    before = list(logger.filters)
    handler = signal.getsignal(signal.SIGINT)  # dask_setup ignores Ctrl-C, as in a worker
    try:
        frames.dask_setup(None)
        heartbeat = logger.makeRecord("distributed.worker", logging.ERROR, __file__, 1,
                                      "Failed to communicate with scheduler during heartbeat.", (), None)
        other = logger.makeRecord("distributed.worker", logging.ERROR, __file__, 1,
                                  "Compute Failed", (), None)
        assert not logger.filter(heartbeat)
        assert logger.filter(other)
    finally:
        logger.filters[:] = before
        signal.signal(signal.SIGINT, handler)
