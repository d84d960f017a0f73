"""The ``polarbssrdf calibrate`` commands on synthetic inputs written to disk."""

import argparse
import json
import sys

import cv2
import numpy as np
import pytest

from polarbssrdf import cli
from polarbssrdf.calibration import checker_reference, read_cameras, relative_pose_error
from polarbssrdf.calibration import commands
from polarbssrdf.calibration.synthetic import random_board_poses, render_board_view
from polarbssrdf.errors import CommandError
from polarbssrdf.spectral import default_light, gaussian_curve, read_bands, sample_curve


def run(argv):
    """Run ``polarbssrdf <argv>`` as the console script does (exit code 2 on user errors)."""
    if "polarbssrdf.calibration.commands" in cli.COMMAND_MODULES:
        return cli.main(argv)
    parser = argparse.ArgumentParser(prog="polarbssrdf")
    subparsers = parser.add_subparsers(dest="command", required=True)
    commands.register(subparsers)
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (CommandError, FileNotFoundError, ValueError) as error:
        print(f"polarbssrdf {args.command}: error: {error}", file=sys.stderr)
        return 2


@pytest.fixture(scope="module")
def board_file(tmp_path_factory, board):
    path = tmp_path_factory.mktemp("board") / "BOARD.json"
    path.write_text(json.dumps({"squares_x": board.squares_x, "squares_y": board.squares_y,
                                "square_mm": board.square_mm, "marker_mm": board.marker_mm,
                                "dictionary": board.dictionary}))
    return path


@pytest.fixture(scope="module")
def image_tree(tmp_path_factory, board, rig_truth):
    """DIR/cam0, DIR/cam1: 9 simultaneous shots as PNG, plus one shot without a board."""
    root = tmp_path_factory.mktemp("views")
    poses = random_board_poses(board, 9, 41, distance_mm=(450.0, 540.0), tilt_deg=28.0)
    rng = np.random.default_rng(42)
    for camera in rig_truth[:2]:
        folder = root / camera.name
        folder.mkdir()
        for i, pose in enumerate(poses):
            image = render_board_view(board, camera, pose, blur_sigma_px=0.6, noise_dn=2.0, rng=rng)
            cv2.imwrite(str(folder / f"shot{i:02d}.png"), image)
        cv2.imwrite(str(folder / "empty.png"), np.full((480, 640), 90, np.uint8))
    return root


def test_geometry_command_writes_the_cameras_block(tmp_path, image_tree, board_file, rig_truth, capsys):
    out = tmp_path / "CAMERAS.json"
    assert run(["calibrate", "geometry", str(image_tree), "--board", str(board_file),
                "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "shot03:" in printed and "empty: no board detected" in printed
    document = json.loads(out.read_text())
    assert document["schema"] == "polarbssrdf.calibration.cameras" and document["schema_version"] == 1
    entries = {entry["name"]: entry for entry in document["cameras"]}
    assert list(entries) == ["cam0", "cam1"] and document["reference_camera"] == "cam0"
    for entry in entries.values():
        assert entry["rms_px"] < 0.5 and len(entry["views"]) == 9 and entry["no_board"] == ["empty"]
        assert np.array(entry["K"]).shape == (3, 3) and len(entry["dist"]) == 5
        assert entry["image_size"] == [640, 480]
    cameras = read_cameras(out)
    assert np.allclose(cameras[0].R, np.eye(3)) and np.allclose(cameras[0].t, 0.0)
    for estimate, truth in zip(cameras, rig_truth):
        assert abs(estimate.K[0, 0] / truth.K[0, 0] - 1) < 0.01
    angle_deg, offset_mm = relative_pose_error(cameras[0], cameras[1], rig_truth[0], rig_truth[1])
    assert angle_deg < 0.3 and offset_mm < 3.0
    # a second run refuses to replace the result, --overwrite replaces it
    before = out.read_text()
    assert run(["calibrate", "geometry", str(image_tree), "--board", str(board_file),
                "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err and out.read_text() == before
    assert run(["calibrate", "geometry", str(image_tree), "--board", str(board_file), "--out", str(out),
                "--overwrite", "--model", "pinhole"]) == 0
    assert json.loads(out.read_text())["model"] == "pinhole"
    assert read_cameras(out)[1].dist.tolist() == [0.0] * 5


def _copy_tree(source, target, cameras=("cam0", "cam1"), shots=None):
    for camera in cameras:
        (target / camera).mkdir(parents=True)
        for path in sorted((source / camera).glob("*.png")):
            if shots is None or path.stem in shots:
                (target / camera / path.name).write_bytes(path.read_bytes())


def test_geometry_bad_inputs_are_clear_errors(tmp_path, image_tree, board_file, capsys):
    out = str(tmp_path / "CAMERAS.json")

    def error_of(directory, board=board_file):
        assert run(["calibrate", "geometry", str(directory), "--board", str(board), "--out", out]) == 2
        return capsys.readouterr().err

    # a camera whose images show no board
    blank = tmp_path / "blank"
    _copy_tree(image_tree, blank)
    (blank / "cam2").mkdir()
    for i in range(3):
        cv2.imwrite(str(blank / "cam2" / f"shot{i:02d}.png"), np.full((480, 640), 90, np.uint8))
    assert "camera cam2: no ChArUco board" in error_of(blank)
    # too few views
    few = tmp_path / "few"
    _copy_tree(image_tree, few, shots={"shot00", "shot01", "shot02", "empty"})
    assert "camera cam0: too few views with a detected board: 3 (need at least 4" in error_of(few)
    # inconsistent image sizes within a camera
    sizes = tmp_path / "sizes"
    _copy_tree(image_tree, sizes)
    image = cv2.imread(str(sizes / "cam1" / "shot04.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(sizes / "cam1" / "shot04.png"), cv2.resize(image, (800, 600)))
    message = error_of(sizes)
    assert "camera cam1: images have inconsistent sizes" in message and "800 x 600: shot04.png" in message
    # malformed BOARD.json, unknown dictionary, missing directory
    bad_board = tmp_path / "bad.json"
    bad_board.write_text('{"squares_x": 11, "squares_y": 8, "square_mm": 30}')
    assert "missing field(s) marker_mm, dictionary" in error_of(image_tree, bad_board)
    bad_board.write_text(json.dumps({"squares_x": 11, "squares_y": 8, "square_mm": 30,
                                     "marker_mm": 22, "dictionary": "DICT_4X4_42"}))
    assert "unknown ArUco dictionary 'DICT_4X4_42'" in error_of(image_tree, bad_board)
    assert "image directory not found" in error_of(tmp_path / "nowhere")
    # a board of the wrong dictionary is simply not found
    bad_board.write_text(json.dumps({"squares_x": 11, "squares_y": 8, "square_mm": 30,
                                     "marker_mm": 22, "dictionary": "DICT_6X6_250"}))
    assert "no ChArUco board (11 x 8 squares, DICT_6X6_250) found" in error_of(image_tree, bad_board)
    assert not (tmp_path / "CAMERAS.json").exists()


def test_colour_command(tmp_path, capsys):
    names, reference = checker_reference()
    matrix = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.05, -0.55, 1.5]])
    camera = reference @ np.linalg.inv(matrix).T
    patches = tmp_path / "patches.csv"
    patches.write_text("patch,R,G,B\n" + "".join(f"{n},{r:.8f},{g:.8f},{b:.8f}\n"
                                                  for n, (r, g, b) in zip(names, camera)))
    out = tmp_path / "colour.json"
    assert run(["calibrate", "colour", str(patches), "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    np.testing.assert_allclose(document["matrix"], matrix, atol=1e-5)
    assert document["schema"] == "polarbssrdf.calibration.colour" and len(document["patches"]) == 24
    # unnamed patches must be complete and in chart order
    patches.write_text("patch,R,G,B\n1,0.1,0.2,0.3\n2,0.3,0.2,0.1\n")
    assert run(["calibrate", "colour", str(patches), "--out", str(tmp_path / "c2.json")]) == 2
    assert "give all 24 patches" in capsys.readouterr().err
    assert run(["calibrate", "colour", str(patches), "--out", str(patches), "--overwrite"]) == 2
    assert "is one of the inputs" in capsys.readouterr().err


def test_spectral_command(tmp_path):
    wl = np.arange(400.0, 701.0, 5.0)
    centres = np.arange(420.0, 671.0, 10.0)
    led = sample_curve(default_light(), wl)
    lights = np.array([100.0 * gaussian_curve(c, 12.0)(wl) * led for c in centres])
    response = {"G": gaussian_curve(535.0, 80.0)(wl), "R": gaussian_curve(605.0, 70.0, 0.9)(wl)}
    values = np.array([[np.trapezoid(light * 0.99 * r, wl) for r in response.values()] for light in lights])
    names = [f"lctf{int(c)}" for c in centres]
    (tmp_path / "lights.csv").write_text(
        "# LCTF x LED, spectrometer, W/(m^2 nm)\nwavelength_nm," + ",".join(names) + "\n"
        + "".join(f"{w:g}," + ",".join(f"{v:.10g}" for v in lights[:, i]) + "\n" for i, w in enumerate(wl)))
    (tmp_path / "spectralon.csv").write_text("wavelength_nm,reflectance\n380,0.99\n720,0.99\n550,0.99\n")
    (tmp_path / "measurements.csv").write_text(
        "band,G,R\n" + "".join(f"{n},{g:.10g},{r:.10g}\n" for n, (g, r) in zip(names, values)))
    transmittance = 0.05 + 0.9 * gaussian_curve(560.0, 60.0)(wl)
    (tmp_path / "filterA.csv").write_text(
        "wavelength_nm,incident,transmitted\n"
        + "".join(f"{w:g},{1000.0:g},{1000.0 * t:.10g}\n" for w, t in zip(wl, transmittance)))
    out, bands_out = tmp_path / "spectral.json", tmp_path / "bands.json"
    argv = ["calibrate", "spectral", "--lights", str(tmp_path / "lights.csv"),
            "--reference", str(tmp_path / "spectralon.csv"),
            "--measurements", str(tmp_path / "measurements.csv"),
            "--filter", f"A={tmp_path / 'filterA.csv'}", "--out", str(out), "--bands-out", str(bands_out)]
    # the reference must be sorted by wavelength: a clear error first
    assert run(argv) == 2
    (tmp_path / "spectralon.csv").write_text("wavelength_nm,reflectance\n380,0.99\n550,0.99\n720,0.99\n")
    assert run(argv) == 0
    document = json.loads(out.read_text())
    covered = (wl >= 420) & (wl <= 670)
    for channel, truth in response.items():
        estimate = np.array(document["responses"][channel])
        error = np.sqrt(np.mean((estimate - truth)[covered] ** 2)) / np.sqrt(np.mean(truth[covered] ** 2))
        assert error < 0.02
    np.testing.assert_allclose(document["filters"]["A"]["transmittance"], transmittance, rtol=1e-6)
    bands = read_bands(bands_out)
    assert [b.name for b in bands] == ["GA", "RA"]


SPHERES = [("cam0", 1.0, (160, 120, 60)), ("cam1", 1.25, (140, 110, 80))]
"""Two cameras seeing the white sphere: name, true gain, (centre x, centre y, radius) in px."""


def sphere_radiance(gain, cx, cy, radius):
    """Linear radiance of a coaxially lit Lambertian sphere (240 x 320), peak 0.7 x gain."""
    rows, columns = np.mgrid[0:240, 0:320].astype(float)
    return 0.7 * gain * np.sqrt(np.clip(1 - ((columns - cx) ** 2 + (rows - cy) ** 2) / radius ** 2,
                                        0, None))


def srgb_encode(linear):
    """The sRGB transfer curve (IEC 61966-2-1) of values in [0, 1]."""
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def test_sphere_command(tmp_path):
    """Linear 16-bit TIFF images give the true gains."""
    for name, gain, layout in SPHERES:
        image = np.round(65535 * sphere_radiance(gain, *layout)).astype(np.uint16)
        cv2.imwrite(str(tmp_path / f"{name}.tiff"), image)
    out = tmp_path / "gains.json"
    assert run(["calibrate", "sphere", str(tmp_path), "--out", str(out)]) == 0
    gains = json.loads(out.read_text())["gains"]
    np.testing.assert_allclose(gains["cam1"], 1.25, rtol=0.01)
    np.testing.assert_allclose(gains["cam0"], 1.0)


@pytest.mark.parametrize("suffix,dtype", [(".png", np.uint8), (".jpg", np.uint8),
                                          (".png", np.uint16), (".tiff", np.uint8)])
def test_sphere_command_refuses_display_encoded_images(tmp_path, capsys, suffix, dtype):
    """sRGB previews are not radiance (they gave a gain of 1.097 for 1.25): a clear error."""
    scale = np.iinfo(dtype).max
    for name, gain, layout in SPHERES:
        encoded = np.round(scale * srgb_encode(sphere_radiance(gain, *layout))).astype(dtype)
        cv2.imwrite(str(tmp_path / f"{name}{suffix}"), encoded)
    out = tmp_path / "gains.json"
    assert run(["calibrate", "sphere", str(tmp_path), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert f"cam0{suffix}" in error and "sRGB" in error and "linear" in error
    assert "--decode-srgb" in error
    assert not out.exists()


@pytest.mark.parametrize("suffix,dtype", [(".png", np.uint8), (".png", np.uint16),
                                          (".jpg", np.uint8)])
def test_sphere_command_decodes_srgb_images_on_request(tmp_path, suffix, dtype):
    scale = np.iinfo(dtype).max
    for name, gain, layout in SPHERES:
        encoded = np.round(scale * srgb_encode(sphere_radiance(gain, *layout))).astype(dtype)
        cv2.imwrite(str(tmp_path / f"{name}{suffix}"), encoded)
    out = tmp_path / "gains.json"
    assert run(["calibrate", "sphere", str(tmp_path), "--out", str(out), "--decode-srgb"]) == 0
    gains = json.loads(out.read_text())["gains"]
    np.testing.assert_allclose(gains["cam1"], 1.25, rtol=0.01)
    np.testing.assert_allclose(gains["cam0"], 1.0)


def test_sphere_command_takes_exr_images_as_linear_even_with_decode_srgb(tmp_path):
    from polarbssrdf.io.exr import write_exr

    for name, gain, layout in SPHERES:
        write_exr(tmp_path / f"{name}.exr", {"Y": sphere_radiance(gain, *layout).astype(np.float32)})
    out = tmp_path / "gains.json"
    assert run(["calibrate", "sphere", str(tmp_path), "--out", str(out), "--decode-srgb"]) == 0
    np.testing.assert_allclose(json.loads(out.read_text())["gains"]["cam1"], 1.25, rtol=1e-3)


def calibrate_subcommands():
    """The ``calibrate`` sub-parsers of the real command line, by name."""
    parser = cli.build_parser()
    commands_action = next(a for a in parser._subparsers._group_actions)
    calibrate = commands_action.choices["calibrate"]
    what = next(a for a in calibrate._subparsers._group_actions)
    return what.choices


def test_every_calibrate_option_has_help_with_its_default():
    subcommands = calibrate_subcommands()
    assert set(subcommands) == {"geometry", "colour", "spectral", "sphere"}
    for name, subparser in subcommands.items():
        for action in subparser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            label = f"calibrate {name} {'/'.join(action.option_strings) or action.dest}"
            assert action.help and action.help.strip(), f"{label} has no help"
            optional = action.option_strings and not action.required
            if optional and action.nargs != 0:  # options taking a value: say what happens without
                assert "default" in action.help, f"{label}: help does not give the default"
        # argparse formats every help text (a stray '%' would fail here)
        assert subparser.format_help()
