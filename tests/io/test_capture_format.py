"""The capture format: bit-exact round trips, resuming, and clear errors for bad captures."""

import json
import os

import numpy as np
import pytest

from polarbssrdf.geometry.mesh import uv_sphere
from polarbssrdf.io import (
    Camera,
    CaptureFormatError,
    CaptureManifest,
    CaptureWriter,
    GroundTruth,
    Light,
    load_capture,
    plan_frame,
    read_exr,
    write_capture,
    write_exr,
)
from polarbssrdf.io.capture import MANIFEST_NAME, PLAN_NAME, dumps_json
from polarbssrdf.io.mitsuba_camera import camera_from_look_at
from polarbssrdf.spectral.bands import default_bands

BANDS = default_bands()[:2]


def _rotation_about(axis, degrees):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _pose(angle_deg, shift_mm):
    pose = np.eye(4)
    pose[:3, :3] = _rotation_about([0, 1, 0], angle_deg)
    pose[:3, 3] = shift_mm
    return pose


def _manifest(mesh="mesh.obj", truth="truth/truth.json", frames=2):
    """Colour camera with analyser images, mono camera with raw images, 2 lights, 2 frames."""
    cam0 = camera_from_look_at([0, 0, 600], [0, 0, 0], [0, 1, 0], 25.0, (8, 4), name="cam00",
                               sensor="IMX250MYR")
    cam1 = Camera("cam01", [[900.0, 0.0, 2.7], [0.0, 900.0, 3.1], [0.0, 0.0, 1.0]],
                  [0.01, -0.002, 0.0, 0.0, 0.0], _rotation_about([1, 2, 3], 40.0),
                  [1.5, -2.0, 650.0], (6, 4), "IMX250MZR")
    lights = (Light("light00", [30.0, 0.0, 600.0], 2.5e5, cam0.right, cam0.forward),
              Light("light01", [0.0, 40.0, 620.0], 1.0e5, [0.0, 1.0, 0.0]))
    frame_list = []
    for index in range(frames):
        first = plan_frame(index, 0.04 * index, _pose(3.0 * index, [0.0, 1.0 * index, 0.0]),
                           [("cam00", "light00")], kind="analyser")
        second = plan_frame(index, 0.04 * index, first.pose, [("cam01", "light01")], kind="raw")
        frame_list.append(type(first)(index, first.time_s, first.pose,
                                      first.images + second.images))
    return CaptureManifest(bands=tuple(BANDS), cameras=(cam0, cam1), lights=lights,
                           frames=tuple(frame_list), mesh=mesh, synthetic=truth is not None,
                           truth=truth, metadata={"made_by": "test"})


def _images(manifest, rng):
    """Awkward float32 values (denormals, large numbers) for every record."""
    images = {}
    for _, record in manifest.records():
        width, height = manifest.camera(record.camera).image_size
        channels = {}
        for name in manifest.expected_channels(record):
            values = (rng.random((height, width)) * 1e3).astype(np.float32)
            values[0, 0] = np.float32(1.4e-45)
            channels[name] = values
        images[record.path] = channels
    return images


def _truth(manifest, rng, size=5):
    maps = {}
    for frame in manifest.frames:
        maps[frame.index] = {
            "eta": (1.4 + 0.01 * rng.standard_normal((size, size))).astype(np.float32),
            "displacement": (0.1 * rng.standard_normal((size, size))).astype(np.float32),
            **{f"rho_sss.{band.name}": rng.random((size, size)).astype(np.float32)
               for band in manifest.bands},
        }
    return GroundTruth(maps, metadata={"seed": 3})


def _bits(array):
    return np.ascontiguousarray(array, dtype=np.float32).view(np.uint32)


@pytest.fixture
def written(tmp_path, rng):
    """A complete capture on disk: (directory, manifest, images, truth)."""
    manifest = _manifest()
    images, truth = _images(manifest, rng), _truth(manifest, rng)
    directory = tmp_path / "capture"
    write_capture(directory, manifest, images, truth, mesh=uv_sphere(20.0, rings=6, segments=8))
    return directory, manifest, images, truth


# --------------------------------------------------------------------------- round trips
def test_round_trip_is_bit_exact(written):
    directory, manifest, images, truth = written
    capture = load_capture(directory)
    assert capture.manifest == manifest
    assert capture.manifest.to_json() == manifest.to_json()
    for frame, record in manifest.records():
        loaded = capture.images(frame.index, record.camera, record.light)
        assert list(loaded) == list(manifest.expected_channels(record))
        for name, values in images[record.path].items():
            assert loaded[name].dtype == np.float32
            assert np.array_equal(_bits(loaded[name]), _bits(values)), (record.path, name)
    assert capture.truth.texture_size == 5
    assert capture.truth.metadata == {"seed": 3}
    for index, maps in truth.maps.items():
        loaded = capture.truth_maps(index)
        assert set(loaded) == set(maps)
        for name, values in maps.items():
            assert np.array_equal(_bits(loaded[name]), _bits(values))
    mesh = capture.load_mesh()
    reference = uv_sphere(20.0, rings=6, segments=8)
    assert np.array_equal(mesh.vertices, reference.vertices)
    assert np.array_equal(mesh.uvs, reference.uvs)
    assert not (directory / PLAN_NAME).exists()


def test_manifest_json_round_trip_and_stable_text(written):
    directory, manifest, _, _ = written
    text = (directory / MANIFEST_NAME).read_text()
    again = CaptureManifest.from_json(json.loads(text))
    assert again == manifest
    assert dumps_json(again.to_json()) == text
    # matrices stay bit-exact through JSON
    assert np.array_equal(again.cameras[1].R, manifest.cameras[1].R)
    assert np.array_equal(again.frames[1].pose, manifest.frames[1].pose)


def test_raw_and_analyser_channel_names(written):
    directory, manifest, _, _ = written
    capture = load_capture(directory, check_images=False)
    analyser = capture.images(0, "cam00", "light00")
    raw = capture.images(0, "cam01", "light01")
    assert list(analyser) == [f"{b.name}.I{a}" for b in BANDS for a in (0, 45, 90, 135)]
    assert list(raw) == [f"{b.name}.raw" for b in BANDS]
    assert analyser[f"{BANDS[0].name}.I0"].shape == (4, 8)  # H x W for image_size [8, 4]


def test_without_truth_and_mesh(tmp_path, rng):
    manifest = _manifest(mesh=None, truth=None, frames=1)
    write_capture(tmp_path / "c", manifest, _images(manifest, rng))
    capture = load_capture(tmp_path / "c")
    assert capture.truth is None and capture.mesh_path is None
    assert sorted(os.listdir(tmp_path / "c")) == ["capture.json", "images"]


# --------------------------------------------------------------------------- writer
def test_writer_resumes_after_partial_write(tmp_path, rng):
    manifest = _manifest(mesh=None)
    images, truth = _images(manifest, rng), _truth(manifest, rng)
    directory = tmp_path / "partial"
    writer = CaptureWriter(directory, manifest)
    records = manifest.records()
    for frame, record in records[:3]:
        writer.add_image(frame, record.camera, record.light, images[record.path])
    writer.add_truth(0, truth.maps[0])
    with pytest.raises(FileNotFoundError, match=r"1 planned image\(s\) not written"):
        writer.finish()
    with pytest.raises(FileNotFoundError, match="capture.plan.json"):
        load_capture(directory)
    del writer  # the "crash"

    with pytest.raises(FileExistsError, match="not empty"):
        CaptureWriter(directory, manifest)
    resumed = CaptureWriter(directory, manifest, resume=True)
    expected_done = {(f.index, r.camera, r.light) for f, r in records[:3]}
    assert resumed.completed() == expected_done
    last_frame, last = records[3]
    assert resumed.missing() == [(last_frame.index, last.camera, last.light)]
    assert resumed.completed_truth() == {0}
    with pytest.raises(FileExistsError):  # finished images are not rewritten by accident
        frame, record = records[0]
        resumed.add_image(frame, record.camera, record.light, images[record.path])
    resumed.add_image(last_frame, last.camera, last.light, images[last.path])
    resumed.add_truth(1, truth.maps[1])
    resumed.finish()
    capture = load_capture(directory)
    assert capture.manifest == manifest
    assert sorted(r.frame for r in capture.truth.maps) == [0, 1]
    # resuming a finished capture is a no-op
    again = CaptureWriter(directory, manifest, resume=True)
    assert again.missing() == [] and again.finish() == directory / MANIFEST_NAME


def test_resume_refuses_a_different_plan(tmp_path, rng):
    manifest = _manifest(mesh=None, truth=None)
    writer = CaptureWriter(tmp_path / "c", manifest)
    frame, record = manifest.records()[0]
    writer.add_image(frame, record.camera, record.light, _images(manifest, rng)[record.path])
    other = _manifest(mesh=None, truth=None, frames=1)
    with pytest.raises(FileExistsError, match="different capture"):
        CaptureWriter(tmp_path / "c", other, resume=True)


def test_add_image_checks_before_writing(tmp_path, rng):
    manifest = _manifest(mesh=None, truth=None)
    writer = CaptureWriter(tmp_path / "c", manifest)
    frame, record = manifest.records()[0]
    good = _images(manifest, rng)[record.path]
    wrong_set = dict(good)
    wrong_set.pop(f"{BANDS[0].name}.I45")
    with pytest.raises(ValueError, match=r"wrong channel set.*missing \['BA.I45'\]"):
        writer.add_image(frame, "cam00", "light00", wrong_set)
    with pytest.raises(ValueError, match="width x height"):
        writer.add_image(frame, "cam00", "light00", {k: v[:, :4] for k, v in good.items()})
    with pytest.raises(ValueError, match="NaN"):
        writer.add_image(frame, "cam00", "light00", {**good, "BA.I0": np.full((4, 8), np.nan)})
    with pytest.raises(ValueError, match="negative intensity"):
        writer.add_image(frame, "cam00", "light00", {**good, "BA.I0": -np.ones((4, 8))})
    with pytest.raises(KeyError, match="no image for camera 'cam01' and light 'light00'"):
        writer.add_image(frame, "cam01", "light00", good)
    assert writer.completed() == set()


def test_non_empty_directory_is_refused_and_overwrite_keeps_foreign_files(written, rng):
    directory, manifest, images, truth = written
    with pytest.raises(FileExistsError, match="not empty"):
        write_capture(directory, manifest, images, truth, mesh=uv_sphere(20.0, rings=6, segments=8))
    (directory / "notes.txt").write_text("mine")
    new_images = _images(manifest, rng)
    write_capture(directory, manifest, new_images, truth, overwrite=True,
                  mesh=uv_sphere(20.0, rings=6, segments=8))
    assert (directory / "notes.txt").read_text() == "mine"
    superseded = [name for name in os.listdir(directory) if name.startswith("capture.superseded-")]
    assert len(superseded) == 1
    path = manifest.frames[0].images[0].path
    loaded = load_capture(directory).images(0, "cam00", "light00")
    assert np.array_equal(loaded["BA.I0"], new_images[path]["BA.I0"])


def test_overwrite_starts_over_so_a_resume_reuses_nothing_of_the_earlier_capture(written, rng):
    directory, manifest, images, truth = written
    (directory / "notes.txt").write_text("mine")
    fewer = _manifest(frames=1)  # frame 1 of the earlier capture is not in the new plan
    writer = CaptureWriter(directory, fewer, overwrite=True)
    # the earlier files at the new plan's paths are gone, so none passes for a finished one
    assert writer.completed() == set() and writer.completed_truth() == set()
    assert not (directory / "truth" / "truth.json").exists()
    # files the new plan does not name are kept: foreign ones and the earlier frame 1
    assert (directory / "notes.txt").read_text() == "mine"
    assert (directory / manifest.frames[1].images[0].path).is_file()
    frame, record = fewer.records()[0]
    writer.add_image(frame, record.camera, record.light, images[record.path])
    del writer  # interrupted
    resumed = CaptureWriter(directory, fewer, resume=True)
    assert resumed.completed() == {(frame.index, record.camera, record.light)}


def test_resume_refusal_names_the_differences(tmp_path, rng):
    from polarbssrdf.io.capture import PlanMismatchError

    manifest = _manifest(mesh=None, truth=None)
    CaptureWriter(tmp_path / "c", manifest)
    other = CaptureManifest(bands=manifest.bands, cameras=manifest.cameras,
                            lights=manifest.lights, frames=manifest.frames, mesh=None,
                            synthetic=False, truth=None, metadata={"made_by": "another test"})
    with pytest.raises(PlanMismatchError, match="different capture") as error:
        CaptureWriter(tmp_path / "c", other, resume=True)
    assert error.value.differences == [("manifest.metadata.made_by", "test", "another test")]
    assert "manifest.metadata.made_by: 'test' -> 'another test'" in str(error.value)
    assert isinstance(error.value, FileExistsError)


def test_an_interrupted_image_write_leaves_no_file(tmp_path, rng, monkeypatch):
    import polarbssrdf.io.exr as exr

    manifest = _manifest(mesh=None, truth=None)
    writer = CaptureWriter(tmp_path / "c", manifest)
    frame, record = manifest.records()[0]

    def write_half_and_stop(path, header, channels):
        path.write_bytes(b"v/1\x01 half an EXR")
        raise KeyboardInterrupt

    monkeypatch.setattr(exr, "_write_exr_file", write_half_and_stop)
    with pytest.raises(KeyboardInterrupt):
        writer.add_image(frame, record.camera, record.light, _images(manifest, rng)[record.path])
    files = [p.name for p in (tmp_path / "c").rglob("*") if p.is_file()]
    assert files == [PLAN_NAME]  # neither the image nor its temporary file
    assert writer.completed() == set()


# --------------------------------------------------------------------------- bad captures on disk
def test_missing_image_file(written):
    directory, manifest, _, _ = written
    path = manifest.frames[1].images[1].path
    os.remove(directory / path)
    with pytest.raises(FileNotFoundError, match=r"frames\[1\]\.images\[1\]\.path: image file .*"
                                                r"cam01_light01\.exr' does not exist"):
        load_capture(directory, check_images=False)


def _replace_image(directory, path, channels, **options):
    write_exr(directory / path, channels, overwrite=True, **options)


def test_wrong_channel_set(written):
    directory, manifest, images, _ = written
    path = manifest.frames[0].images[0].path
    channels = dict(images[path])
    channels["BA.I45x"] = channels.pop("BA.I45")
    _replace_image(directory, path, channels)
    load_capture(directory, check_images=False)  # contents are only read when asked for
    with pytest.raises(ValueError, match=r"cam00_light00\.exr'.*wrong channel set for an analyser "
                                         r"image: missing \['BA\.I45'\], unexpected \['BA\.I45x'\]"):
        load_capture(directory)


def test_raw_image_with_analyser_channels(written):
    directory, manifest, images, _ = written
    path = manifest.frames[0].images[1].path
    _replace_image(directory, path, {f"{b.name}.I0": np.zeros((4, 6)) for b in BANDS})
    with pytest.raises(ValueError, match=r"wrong channel set for a raw image: missing "
                                         r"\['BA.raw', 'BB.raw'\]"):
        load_capture(directory)


def test_nan_image(written):
    directory, manifest, images, _ = written
    path = manifest.frames[1].images[0].path
    channels = dict(images[path])
    bad = channels["BB.I90"].copy()
    bad[2, 5] = np.nan
    channels["BB.I90"] = bad
    _replace_image(directory, path, channels, allow_nonfinite=True)
    with pytest.raises(ValueError, match=r"f0001/cam00_light00\.exr': channel 'BB\.I90' has 1 NaN "
                                         r"and 0 infinite values \(first at row 2, column 5\)"):
        load_capture(directory)


def test_wrong_image_size_and_negative_analyser(written):
    directory, manifest, images, _ = written
    path = manifest.frames[0].images[0].path
    _replace_image(directory, path, {k: np.ones((4, 4)) for k in images[path]})
    with pytest.raises(ValueError, match="is 4 x 4 .*image_size is 8 x 4"):
        load_capture(directory)
    channels = {k: np.ones((4, 8)) for k in images[path]}
    channels["BA.I135"] = np.full((4, 8), -0.01)
    _replace_image(directory, path, channels)
    with pytest.raises(ValueError, match="channel 'BA.I135' has negative intensity"):
        load_capture(directory)


def test_tiny_negative_analyser_values_are_accepted(written):
    directory, manifest, images, _ = written
    path = manifest.frames[0].images[0].path
    channels = {k: np.full((4, 8), 100.0) for k in images[path]}
    channels["BA.I0"][0, 0] = -5e-5  # -5e-7 of the maximum: rounding of a dark pixel
    _replace_image(directory, path, channels)
    load_capture(directory)


def test_malformed_json_names_line_and_column(written):
    directory = written[0]
    lines = (directory / MANIFEST_NAME).read_text().splitlines()
    lines[2] = lines[2].rstrip(",")  # "schema_version": 1   <- missing comma
    (directory / MANIFEST_NAME).write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"capture\.json' is not valid JSON: Expecting ',' "
                                         r"delimiter at line 4, column 3"):
        load_capture(directory)


def test_missing_capture_json(tmp_path):
    with pytest.raises(FileNotFoundError, match="has no capture.json"):
        load_capture(tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_capture(tmp_path / "nowhere")


def _rotation_scaled(document):
    document["cameras"][1]["R"] = (np.array(document["cameras"][1]["R"]) * 1.001).tolist()


def _reflection(document):
    document["cameras"][0]["R"][0] = [-x for x in document["cameras"][0]["R"][0]]


def _set(path, value):
    def edit(document):
        target = document
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return edit


def _delete(path):
    def edit(document):
        target = document
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]
    return edit


def _duplicate_camera(document):
    document["cameras"][1]["name"] = "cam00"


def _duplicate_band(document):
    document["bands"][1]["name"] = document["bands"][0]["name"]


def _duplicate_image(document):
    document["frames"][0]["images"].append(dict(document["frames"][0]["images"][0],
                                                path="images/other.exr"))


BAD_MANIFESTS = {
    "unknown camera": (_set(["frames", 1, "images", 0, "camera"], "cam9"),
                       r"frames\[1\]\.images\[0\]\.camera: unknown camera 'cam9' "
                       r"\(known: cam00, cam01\)"),
    "unknown light": (_set(["frames", 0, "images", 1, "light"], "lamp"),
                      r"frames\[0\]\.images\[1\]\.light: unknown light 'lamp'"),
    "non-rotation R": (_rotation_scaled, r"cameras\[1\]\.R: is not a rotation: max \|R R\^T - I\|"),
    "reflection R": (_reflection, r"cameras\[0\]\.R: is not a rotation: det = -1"),
    "newer schema_version": (_set(["schema_version"], 2),
                             r"schema_version: 2 is newer than the supported version 1"),
    "other schema": (_set(["schema"], "something.else"), r"schema: expected 'polarbssrdf.capture'"),
    "units": (_set(["units", "length"], "cm"), r"units: must be"),
    "K shape": (_set(["cameras", 0, "K"], [[1.0, 0.0], [0.0, 1.0]]),
                r"cameras\[0\]\.K: must be 3 x 3, got shape \(2, 2\)"),
    "K type": (_set(["cameras", 0, "K"], "eye"), r"cameras\[0\]\.K: must contain only numbers"),
    "K form": (_set(["cameras", 0, "K", 2], [0.0, 0.5, 1.0]), r"cameras\[0\]\.K: must have the form"),
    "t shape": (_set(["cameras", 1, "t"], [1.0, 2.0]), r"cameras\[1\]\.t: must be a 3-vector"),
    "dist length": (_set(["cameras", 1, "dist"], [0.0, 0.0, 0.0, 0.0]),
                    r"cameras\[1\]\.dist: must be a 5-vector"),
    "non-finite": (_set(["cameras", 1, "t", 2], float("nan")), r"cameras\[1\]\.t: must be finite"),
    "missing field": (_delete(["cameras", 0, "R"]), r"cameras\[0\]\.R: missing required field"),
    "extra field": (_set(["lights", 0, "colour"], "red"), r"lights\[0\]\.colour: unexpected field"),
    "bool as number": (_set(["lights", 0, "intensity"], True),
                       r"lights\[0\]\.intensity: must be a number, got bool"),
    "unknown sensor": (_set(["cameras", 0, "sensor"], "IMX999"),
                       r"cameras\[0\]\.sensor: unknown sensor 'IMX999' \(known: IMX250MZR, "
                       r"IMX250MYR, ideal\)"),
    "size vs period": (_set(["cameras", 0, "image_size"], [6, 4]),
                       r"cameras\[0\]\.image_size: 6 x 4 .* not a multiple of the 4 x 4 period "
                       r"of sensor IMX250MYR"),
    "size type": (_set(["cameras", 0, "image_size"], [8.0, 4]),
                  r"cameras\[0\]\.image_size\[0\]: must be an integer"),
    "duplicate camera": (_duplicate_camera, r"cameras\[1\]\.name: duplicate name 'cam00' "
                                            r"\(also cameras\[0\]\)"),
    "duplicate band": (_duplicate_band, r"bands\[1\]\.name: duplicate name 'BA'"),
    "negative intensity": (_set(["lights", 1, "intensity"], -1.0),
                           r"lights\[1\]\.intensity: must be >= 0, got -1"),
    "zero axis": (_set(["lights", 1, "polarization_axis"], [0, 0, 0]),
                  r"lights\[1\]\.polarization_axis: must be a non-zero vector"),
    "parallel polarizer normal": (_set(["lights", 0, "polarizer_normal"], [1.0, 0.0, 0.0]),
                                  r"lights\[0\]\.polarizer_normal: must not be parallel"),
    "bad kind": (_set(["frames", 0, "images", 0, "kind"], "stokes"),
                 r"frames\[0\]\.images\[0\]\.kind: must be one of analyser, raw"),
    "raw on ideal": (_set(["cameras", 1, "sensor"], "ideal"),
                     r"frames\[0\]\.images\[1\]\.kind: camera 'cam01' has an ideal sensor"),
    "absolute path": (_set(["frames", 0, "images", 0, "path"], "/tmp/x.exr"),
                      r"frames\[0\]\.images\[0\]\.path: must be relative"),
    "escaping path": (_set(["frames", 0, "images", 0, "path"], "../x.exr"),
                      r"frames\[0\]\.images\[0\]\.path: must be a plain relative path"),
    "duplicate image": (_duplicate_image, r"frames\[0\]\.images\[2\]: second image for camera "
                                          r"'cam00' and light 'light00'"),
    "duplicate frame index": (_set(["frames", 1, "index"], 0),
                              r"frames\[1\]\.index: duplicate frame index 0"),
    "pose last row": (_set(["frames", 0, "pose", 3], [0, 0, 1, 1]),
                      r"frames\[0\]\.pose: last row must be \[0, 0, 0, 1\]"),
    "pose scaled": (_set(["frames", 0, "pose", 0, 0], 2.0),
                    r"frames\[0\]\.pose\.rotation: is not a rotation"),
    "band weights": (_set(["bands", 0, "weights"], "flat"),
                     r"bands\[0\]\.weights: must contain only numbers"),
    "band negative weight": (_set(["bands", 0, "weights", 3], -1.0),
                             r"bands\[0\]: band 'BA': weights must be finite, >= 0"),
    "truth on real capture": (_set(["synthetic"], False),
                              r"truth: only synthetic captures have ground truth"),
    "no frames": (_set(["frames"], []), r"frames: must not be empty"),
}


@pytest.mark.parametrize("case", sorted(BAD_MANIFESTS))
def test_bad_manifest_names_the_field(written, case):
    directory = written[0]
    edit, message = BAD_MANIFESTS[case]
    document = json.loads((directory / MANIFEST_NAME).read_text())
    edit(document)
    (directory / MANIFEST_NAME).write_text(json.dumps(document))
    with pytest.raises(CaptureFormatError, match=r"capture\.json: " + message):
        load_capture(directory, check_images=False)


def test_bad_truth_manifest_and_maps(written):
    directory, manifest, _, truth = written
    truth_json = directory / "truth" / "truth.json"
    original = truth_json.read_text()
    document = json.loads(original)
    document["maps"][0]["channels"].append("rho_sss.ZZ")
    truth_json.write_text(json.dumps(document))
    with pytest.raises(ValueError, match=r"truth\.json: maps\[0\]\.channels: channel 'rho_sss\.ZZ': "
                                         r"unknown band 'ZZ'"):
        load_capture(directory, check_images=False)
    document = json.loads(original)
    document["schema_version"] = 7
    truth_json.write_text(json.dumps(document))
    with pytest.raises(ValueError, match="schema_version: 7 is newer"):
        load_capture(directory, check_images=False)
    truth_json.write_text(original)
    maps = {name: np.ones((4, 4), dtype=np.float32) for name in truth.maps[1]}
    write_exr(directory / "truth" / "maps_f0001.exr", maps, overwrite=True)
    with pytest.raises(ValueError, match="maps_f0001.exr': map 'eta' is 4 x 4 but the texture "
                                         "size is 5"):
        load_capture(directory)


def test_writer_rejects_unknown_truth_parameter(tmp_path):
    manifest = _manifest(mesh=None)
    writer = CaptureWriter(tmp_path / "c", manifest)
    with pytest.raises(ValueError, match="parameter 'albedo' has no unit"):
        writer.add_truth(0, {"albedo": np.ones((4, 4))})
    with pytest.raises(ValueError, match="square"):
        writer.add_truth(0, {"eta": np.ones((4, 3))})


def test_constructors_validate_python_values():
    with pytest.raises(CaptureFormatError, match="R: is not a rotation"):
        Camera("c", np.eye(3), np.zeros(5), np.diag([1.0, 1.0, 2.0]), np.zeros(3), (4, 4))
    with pytest.raises(CaptureFormatError, match="intensity: must be finite"):
        Light("l", np.zeros(3), float("inf"), [1.0, 0.0, 0.0])
    rotation = _rotation_about([1, 1, 0], 33.0).astype(np.float32)  # float32 rounding is accepted
    Camera("c", np.eye(3), np.zeros(5), rotation, np.zeros(3), (4, 4))


def test_project_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    manifest = _manifest()
    camera = manifest.cameras[1]
    camera = Camera(camera.name, camera.K, [0.05, -0.1, 0.002, -0.001, 0.03], camera.R, camera.t,
                    camera.image_size, camera.sensor)
    rng = np.random.default_rng(4)
    points = camera.center + 600.0 * camera.forward + rng.uniform(-60, 60, size=(20, 3))
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(camera.R)[0], camera.t, camera.K,
                                    camera.dist)
    assert np.allclose(camera.project(points), expected[:, 0], atol=1e-9)


@pytest.mark.parametrize("dist", [[0.0] * 5, [0.05, -0.1, 0.002, -0.001, 0.03]])
def test_normalized_rays_invert_project(dist):
    camera = _manifest().cameras[1]
    camera = Camera(camera.name, camera.K, dist, camera.R, camera.t, camera.image_size,
                    camera.sensor)
    rng = np.random.default_rng(9)
    pixels = rng.uniform(0, 1, size=(2, 7, 5)) * np.reshape(camera.image_size, (2, 1, 1))
    rays = camera.normalized_rays(pixels[0], pixels[1])
    assert rays.shape == (7, 5, 2)
    in_camera = np.concatenate([rays, np.ones((7, 5, 1))], axis=-1) * 600.0
    world = (in_camera - camera.t) @ camera.R  # X_world = R^T (X_cam - t)
    np.testing.assert_allclose(camera.project(world), np.moveaxis(pixels, 0, -1), atol=1e-6)


def test_image_metadata_names_the_record(written):
    directory, manifest, _, _ = written
    _, metadata = read_exr(directory / manifest.frames[1].images[1].path)
    assert metadata == {"frame": 1, "camera": "cam01", "light": "light01", "kind": "raw"}


# --------------------------------------------------------------------------- raw calibration
CALIBRATION = {"radiance_per_dn": {"BA": 2.5e-4, "BB": 1.0 / 3.0}, "black_level_dn": 64.0,
               "saturation_dn": 4095.0}


def _calibrated_manifest():
    """:func:`_manifest` with every raw record (cam01) calibrated."""
    manifest = _manifest()
    frames = [plan_frame(f.index, f.time_s, f.pose, [("cam00", "light00")]) for f in
              manifest.frames]
    frames = [type(f)(f.index, f.time_s, f.pose, f.images + plan_frame(
        f.index, f.time_s, f.pose, [("cam01", "light01")], "raw", {"cam01": CALIBRATION}).images)
        for f in frames]
    return CaptureManifest(bands=manifest.bands, cameras=manifest.cameras,
                           lights=manifest.lights, frames=tuple(frames), mesh=manifest.mesh,
                           synthetic=True, truth=manifest.truth, metadata=manifest.metadata)


def test_raw_calibration_round_trips_and_converts(tmp_path, rng):
    manifest = _calibrated_manifest()
    record = manifest.frames[1].image("cam01", "light01")
    assert record.calibrated and record.radiance_per_dn == CALIBRATION["radiance_per_dn"]
    assert record.to_json() == {"camera": "cam01", "light": "light01", "path": record.path,
                                "kind": "raw", **CALIBRATION}
    directory = tmp_path / "capture"
    write_capture(directory, manifest, _images(manifest, rng), _truth(manifest, rng),
                  mesh=uv_sphere(20.0, rings=6, segments=8))
    text = (directory / MANIFEST_NAME).read_text()
    loaded = load_capture(directory).manifest
    assert loaded == manifest and dumps_json(loaded.to_json()) == text
    again = loaded.frames[1].image("cam01", "light01")
    assert again == record and hash(again) == hash(record)
    # bit-exact floats through JSON
    assert again.radiance_per_dn["BB"] == 1.0 / 3.0
    dn = np.array([[64.0, 1064.0]])
    np.testing.assert_array_equal(again.radiance("BB", dn), [[0.0, 1000.0 / 3.0]])
    # analyser records carry none and write none
    analyser = loaded.frames[0].image("cam00", "light00")
    assert not analyser.calibrated and set(analyser.to_json()) == {"camera", "light", "path",
                                                                   "kind"}
    with pytest.raises(ValueError, match="has no radiance_per_dn"):
        analyser.radiance("BA", dn)
    with pytest.raises(KeyError, match="no radiance_per_dn for band 'RA'"):
        again.radiance("RA", dn)


def test_old_raw_records_without_calibration_still_load(written):
    directory, manifest, _, _ = written
    document = json.loads((directory / MANIFEST_NAME).read_text())
    assert "radiance_per_dn" not in document["frames"][0]["images"][1]
    record = load_capture(directory).manifest.frames[0].image("cam01", "light01")
    assert record.kind == "raw" and not record.calibrated
    assert record.black_level_dn is None and record.saturation_dn is None


def _calibrate(document):
    for frame in document["frames"]:
        frame["images"][1].update(json.loads(json.dumps(CALIBRATION)))


def _then(*edits):
    def edit(document):
        for step in edits:
            step(document)
    return edit


RAW = ["frames", 1, "images", 1]
BAD_CALIBRATIONS = {
    "on analyser": (_set(["frames", 0, "images", 0, "radiance_per_dn"], {"BA": 1.0, "BB": 1.0}),
                    r"frames\[0\]\.images\[0\]\.radiance_per_dn: only raw images carry a "
                    r"radiometric calibration \(analyser images are radiance already\)"),
    "black level on analyser": (_set(["frames", 0, "images", 0, "black_level_dn"], 0.0),
                                r"frames\[0\]\.images\[0\]\.black_level_dn: only raw images"),
    "missing band": (_delete(RAW + ["radiance_per_dn", "BB"]),
                     r"frames\[1\]\.images\[1\]\.radiance_per_dn: missing band\(s\) BB"),
    "unknown band": (_set(RAW + ["radiance_per_dn", "ZZ"], 1.0),
                     r"frames\[1\]\.images\[1\]\.radiance_per_dn\.ZZ: unknown band \(bands: BA, "
                     r"BB\)"),
    "zero scale": (_set(RAW + ["radiance_per_dn", "BA"], 0.0),
                   r"frames\[1\]\.images\[1\]\.radiance_per_dn\.BA: must be > 0, got 0"),
    "negative scale": (_set(RAW + ["radiance_per_dn", "BA"], -1e-3),
                       r"frames\[1\]\.images\[1\]\.radiance_per_dn\.BA: must be > 0"),
    "infinite scale": (_set(RAW + ["radiance_per_dn", "BA"], float("inf")),
                       r"frames\[1\]\.images\[1\]\.radiance_per_dn\.BA: must be finite"),
    "string scale": (_set(RAW + ["radiance_per_dn", "BA"], "1e-3"),
                     r"frames\[1\]\.images\[1\]\.radiance_per_dn\.BA: must be a number, got str"),
    "not an object": (_set(RAW + ["radiance_per_dn"], [1.0, 2.0]),
                      r"frames\[1\]\.images\[1\]\.radiance_per_dn: must be a non-empty JSON "
                      r"object"),
    "empty": (_set(RAW + ["radiance_per_dn"], {}),
              r"frames\[1\]\.images\[1\]\.radiance_per_dn: must be a non-empty"),
    "no black level": (_delete(RAW + ["black_level_dn"]),
                       r"frames\[1\]\.images\[1\]\.black_level_dn: missing: required with "
                       r"radiance_per_dn"),
    "negative black level": (_set(RAW + ["black_level_dn"], -1.0),
                             r"frames\[1\]\.images\[1\]\.black_level_dn: must be >= 0"),
    "black level alone": (_delete(RAW + ["radiance_per_dn"]),
                          r"frames\[1\]\.images\[1\]\.black_level_dn: needs radiance_per_dn"),
    "saturation below black": (_set(RAW + ["saturation_dn"], 10.0),
                               r"frames\[1\]\.images\[1\]\.saturation_dn: must exceed "
                               r"black_level_dn \(64\), got 10"),
    "misspelt field": (_set(RAW + ["radiance_per_DN"], {}),
                       r"frames\[1\]\.images\[1\]\.radiance_per_DN: unexpected field"),
}


@pytest.mark.parametrize("case", sorted(BAD_CALIBRATIONS))
def test_bad_raw_calibration_names_the_field(written, case):
    directory = written[0]
    edit, message = BAD_CALIBRATIONS[case]
    document = json.loads((directory / MANIFEST_NAME).read_text())
    _calibrate(document)
    (directory / MANIFEST_NAME).write_text(json.dumps(document))
    load_capture(directory, check_images=False)  # the calibrated capture itself is fine
    edit(document)
    (directory / MANIFEST_NAME).write_text(json.dumps(document))
    with pytest.raises(CaptureFormatError, match=r"capture\.json: " + message):
        load_capture(directory, check_images=False)


def test_python_records_validate_calibration():
    from polarbssrdf.io.manifest import ImageRecord

    with pytest.raises(CaptureFormatError, match="radiance_per_dn: only raw images"):
        ImageRecord("c", "l", "a.exr", "analyser", {"BA": 1.0}, 0.0)
    with pytest.raises(CaptureFormatError, match=r"^radiance_per_dn\.BA: must be > 0"):
        ImageRecord("c", "l", "a.exr", "raw", {"BA": -1.0}, 0.0)
    record = ImageRecord("c", "l", "a.exr", "raw", {"BA": np.float32(0.5)}, np.int64(3))
    assert type(record.radiance_per_dn["BA"]) is float and record.black_level_dn == 3.0
    assert {record: 1}[ImageRecord("c", "l", "a.exr", "raw", {"BA": 0.5}, 3.0)] == 1
