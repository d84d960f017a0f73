"""``polarbssrdf render`` end to end on scenes/sphere.xml, and its user errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from polarbssrdf.cli import main
from polarbssrdf.io import read_exr
from polarbssrdf.render.stokes_images import (
    CONTACT_SHEET_FILE,
    PREVIEW_FILES,
    polarization_channels,
    preview_images,
    preview_settings,
)

REPO = Path(__file__).resolve().parents[2]
SPHERE = REPO / "scenes" / "sphere.xml"
SMALL = ["-D", "resolution=32", "-D", "spp=4"]
MONO_CHANNELS = ["I0", "I45", "I90", "I135", "S0", "S1", "S2", "S3"]


def run_cli(capsys, *args):
    """Run the ``polarbssrdf`` command in this process: (exit status, stdout, stderr)."""
    status = main([str(a) for a in args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def lit_pixels(S0):
    return S0 > 1e-6 * S0.max()


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    """One small render of the default sphere (mono polarized)."""
    outdir = tmp_path_factory.mktemp("render") / "out"
    assert main(["render", str(SPHERE), str(outdir), *SMALL, "--seed", "3"]) == 0
    return outdir


def test_writes_exr_json_and_previews(sphere_run):
    channels, exr_meta = read_exr(sphere_run / "polarization.exr")
    assert list(channels) == MONO_CHANNELS
    assert all(c.shape == (32, 32) and c.dtype == np.float32 for c in channels.values())
    record = json.loads((sphere_run / "render.json").read_text())
    assert record["schema_version"] == 1
    assert record["variant"] == "llvm_ad_mono_polarized"
    assert record["spp"] == 4 and record["seed"] == 3
    assert record["defines"] == {"resolution": "32", "spp": "4"}
    assert record["resolution"] == {"width": 32, "height": 32}
    assert record["channels"] == MONO_CHANNELS
    assert Path(record["scene"]) == SPHERE
    assert record["versions"]["polarbssrdf"] and record["timing_s"]["render"] > 0
    assert exr_meta["scene"] == record["scene"] and exr_meta["channels"] == MONO_CHANNELS
    for name in [*PREVIEW_FILES.values(), CONTACT_SHEET_FILE]:
        with Image.open(sphere_run / name) as image:
            assert image.format == "PNG" and image.mode == "RGB"
    with Image.open(sphere_run / PREVIEW_FILES["I0"]) as image:
        assert image.size == (32, 32)
    with Image.open(sphere_run / CONTACT_SHEET_FILE) as image:
        assert image.width > 2 * 192  # 2 x 2 sheet, small tiles enlarged
    assert not [p for p in sphere_run.iterdir() if p.name.endswith(".tmp")]


def test_analyser_identity(sphere_run):
    c, _ = read_exr(sphere_run / "polarization.exr")
    S0 = c["S0"]
    assert lit_pixels(S0).sum() > 300  # the sphere covers much of the image
    tolerance = dict(rtol=1e-5, atol=1e-7 * float(S0.max()))
    np.testing.assert_allclose(c["I0"] + c["I90"], S0, **tolerance)
    np.testing.assert_allclose(c["I45"] + c["I135"], S0, **tolerance)
    np.testing.assert_allclose(c["I0"] - c["I90"], c["S1"], rtol=1e-5, atol=1e-7 * S0.max())


def test_specular_only_render_is_not_cross_polarized(tmp_path, capsys):
    status, out, err = run_cli(capsys, "render", SPHERE, tmp_path / "spec", *SMALL,
                               "-D", "rho_ss=0", "-D", "rho_sss=0")
    assert status == 0, err
    c, _ = read_exr(tmp_path / "spec" / "polarization.exr")
    lit = lit_pixels(c["I0"])
    assert lit.sum() > 300
    ratio = np.abs(c["I90"][lit]) / c["I0"][lit]
    assert ratio.max() < 1e-5


def test_refuses_earlier_results_without_overwrite(sphere_run, capsys):
    before = {p.name: p.read_bytes() for p in sphere_run.iterdir()}
    status, _, err = run_cli(capsys, "render", SPHERE, sphere_run, *SMALL)
    assert status == 2
    assert "render: error:" in err and "--overwrite" in err and str(sphere_run) in err
    assert {p.name: p.read_bytes() for p in sphere_run.iterdir()} == before


def test_overwrite_replaces_results_and_keeps_other_files(tmp_path, capsys):
    outdir = tmp_path / "out"
    outdir.mkdir()
    (outdir / "notes.txt").write_text("mine")
    assert run_cli(capsys, "render", SPHERE, outdir, *SMALL)[0] == 0
    status, out, _ = run_cli(capsys, "render", SPHERE, outdir, *SMALL, "--seed", "7",
                             "--overwrite")
    assert status == 0 and "polarization.exr" in out and out.count("\n") == 1
    assert json.loads((outdir / "render.json").read_text())["seed"] == 7
    assert (outdir / "notes.txt").read_text() == "mine"


def test_spectral_variant_writes_colour_channels(tmp_path, capsys):
    status, _, err = run_cli(capsys, "render", SPHERE, tmp_path / "rgb", "-D", "resolution=16",
                             "--spp", "2", "--variant", "llvm_ad_spectral_polarized")
    assert status == 0, err
    c, meta = read_exr(tmp_path / "rgb" / "polarization.exr")
    assert list(c) == [f"{n}.{k}" for n in MONO_CHANNELS for k in "RGB"]
    assert meta["spp"] == 2
    for k in "RGB":
        np.testing.assert_allclose(c[f"I0.{k}"] + c[f"I90.{k}"], c[f"S0.{k}"], rtol=1e-5,
                                   atol=1e-7 * c[f"S0.{k}"].max())


@pytest.mark.parametrize("variant, message", [
    ("llvm_ad_mono", "not polarized"),
    ("scalar_rgb", "not polarized"),
    ("no_such_variant", "unknown Mitsuba variant"),
])
def test_rejects_unpolarized_or_unknown_variants(tmp_path, capsys, variant, message):
    status, _, err = run_cli(capsys, "render", SPHERE, tmp_path / "o", "--variant", variant)
    assert status == 2 and message in err and variant in err
    assert not (tmp_path / "o").exists()


def test_missing_scene(tmp_path, capsys):
    status, _, err = run_cli(capsys, "render", tmp_path / "nope.xml", tmp_path / "o")
    assert status == 2 and "nope.xml" in err and "does not exist" in err


def test_malformed_scene(tmp_path, capsys):
    scene = tmp_path / "broken.xml"
    scene.write_text('<scene version="3.0.0"><integrator type="stokes">')
    status, _, err = run_cli(capsys, "render", scene, tmp_path / "o")
    assert status == 2 and "cannot load scene" in err and "broken.xml" in err
    assert "pars" in err.lower()  # Mitsuba's parser message is passed on
    assert not (tmp_path / "o").exists()


def test_unknown_define_and_bad_define(tmp_path, capsys):
    status, _, err = run_cli(capsys, "render", SPHERE, tmp_path / "o", "-D", "colour=red")
    assert status == 2 and "unused parameters" in err and "colour" in err
    status, _, err = run_cli(capsys, "render", SPHERE, tmp_path / "o", "-D", "spp")
    assert status == 2 and "NAME=VALUE" in err


def test_scene_without_stokes_integrator(tmp_path, capsys):
    scene = tmp_path / "plain.xml"
    scene.write_text(SPHERE.read_text().replace(
        '<integrator type="stokes">\n        <integrator type="direct"/>\n    </integrator>',
        '<integrator type="direct"/>'))
    assert '<integrator type="stokes">' not in scene.read_text()
    status, _, err = run_cli(capsys, "render", scene, tmp_path / "o", *SMALL)
    assert status == 2 and "not 'stokes'" in err and "plain.xml" in err
    assert not (tmp_path / "o").exists()


def test_console_script_runs_the_demo_command(tmp_path):
    script = Path(sys.executable).parent / "polarbssrdf"
    if not script.exists():
        pytest.skip("console script not installed next to the interpreter")
    result = subprocess.run([str(script), "render", str(SPHERE), str(tmp_path / "out"),
                             "--overwrite", *SMALL], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "preview.png").exists()
    result = subprocess.run([str(script), "render", str(SPHERE), str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.startswith("polarbssrdf render: error:")


def test_channel_split_on_a_synthetic_render():
    """Channel naming and the analyser identity without Mitsuba, and clear errors."""
    rng = np.random.default_rng(1)
    names = ["Y", *[f"S{k}.{c}" for k in range(4) for c in "RGB"]]
    image = rng.normal(size=(3, 4, len(names))).astype(np.float32)
    image[:, :, 1:4] = np.abs(image[:, :, 1:4]) + 3  # S0 > |S1|, |S2|
    mono = polarization_channels(image, names, monochrome=True)
    assert list(mono) == MONO_CHANNELS
    assert np.array_equal(mono["S0"], image[:, :, 1])
    assert np.array_equal(mono["S3"], image[:, :, 10])
    np.testing.assert_allclose(mono["I45"], 0.5 * (image[:, :, 1] + image[:, :, 7]), rtol=1e-6)
    colour = polarization_channels(image, names, monochrome=False)
    assert list(colour) == [f"{n}.{k}" for n in MONO_CHANNELS for k in "RGB"]
    assert np.array_equal(colour["S2.B"], image[:, :, 9])
    with pytest.raises(ValueError, match=r"no channel 'S0.R' .*R, G, B.*'stokes' integrator"):
        polarization_channels(np.zeros((2, 2, 3)), ["R", "G", "B"], monochrome=True)
    with pytest.raises(ValueError, match="13 channels but 3 channel names"):
        polarization_channels(image, ["Y", "S0.R", "S1.R"], monochrome=True)


def test_previews_of_a_black_render_do_not_fail():
    channels = {name: np.zeros((8, 8), np.float32) for name in MONO_CHANNELS}
    previews = preview_images(channels, preview_settings(channels))
    assert set(previews) == set(PREVIEW_FILES)
    for image in previews.values():
        assert image.shape == (8, 8, 3) and image.dtype == np.uint8
    assert previews["I0"].max() == 0 and previews["DoLP"].max() == 0


# --------------------------------------------------------------------------
# Issue 8: film sizes, plugin errors, sensors, exposure, colour bars
# --------------------------------------------------------------------------

LIGHTSTAGE = REPO / "scenes" / "lightstage.xml"
TINY = ["-D", "resolution=24", "-D", "spp=2"]


def test_zero_sized_film_is_a_clear_error(tmp_path, capsys):
    status, _, err = run_cli(capsys, "render", SPHERE, tmp_path / "o", "-D", "resolution=0")
    assert status == 2, err
    assert "0 x 0 pixels" in err and "at least 1" in err and "-D resolution=0" in err
    assert "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()
    scene = write_scene(tmp_path, "narrow.xml", '<integer name="width" value="$resolution"/>',
                        '<integer name="width" value="0"/>')
    status, _, err = run_cli(capsys, "render", scene, tmp_path / "o", *SMALL)
    assert status == 2 and "sensor 0 (sensor00) has a film of 0 x 32 pixels" in err


def write_scene(tmp_path, name, old, new):
    """A copy of scenes/sphere.xml with one piece of text replaced."""
    text = SPHERE.read_text()
    assert old in text
    scene = tmp_path / name
    scene.write_text(text.replace(old, new))
    return scene


@pytest.mark.parametrize("name, old, new, message", [
    ("parallel.xml", '<vector name="polarization_axis" x="1" y="0" z="0"/>',
     '<vector name="polarization_axis" x="0" y="0" z="1"/>',
     "ppoint: 'polarizer_normal' must not be parallel to 'polarization_axis'"),
    ("albedo.xml", '<float name="rho_sss" value="$rho_sss"/>',
     '<float name="rho_sss" value="1.7"/>',
     "pbssrdf: parameter 'rho_sss' = 1.7 is outside its valid range [0, 1]"),
])
def test_plugin_errors_show_the_plugin_message_without_traceback(tmp_path, capsys, name, old,
                                                                  new, message):
    scene = write_scene(tmp_path, name, old, new)
    status, _, err = run_cli(capsys, "render", scene, tmp_path / "o", *TINY)
    assert status == 2
    assert message in err and name in err and "line " in err  # where, and what
    assert "Traceback" not in err and 'File "' not in err
    assert err.count("\n") <= 2 and err.startswith("polarbssrdf render: error: cannot load scene")


def read_record(outdir):
    return json.loads((outdir / "render.json").read_text())


@pytest.fixture(scope="module")
def lightstage_runs(tmp_path_factory):
    """Tiny renders of scenes/lightstage.xml: the default sensor, --sensor 3, --sensor cam05."""
    root = tmp_path_factory.mktemp("lightstage")
    runs = {}
    for key, extra in (("default", []), ("3", ["--sensor", "3"]), ("cam05", ["--sensor", "cam05"])):
        runs[key] = root / key
        assert main(["render", str(LIGHTSTAGE), str(runs[key]), *TINY, *extra]) == 0
    return runs


def test_sensor_is_chosen_by_index_or_id_and_recorded(lightstage_runs):
    assert read_record(lightstage_runs["default"])["sensor"] == {"index": 0, "id": "cam00"}
    assert read_record(lightstage_runs["3"])["sensor"] == {"index": 3, "id": "cam03"}
    assert read_record(lightstage_runs["cam05"])["sensor"] == {"index": 5, "id": "cam05"}
    images = {key: read_exr(path / "polarization.exr")[0]["S0"]
              for key, path in lightstage_runs.items()}
    for key in ("3", "cam05"):
        assert np.abs(images[key] - images["default"]).max() > 0.1 * images["default"].max()


@pytest.mark.parametrize("sensor", ["cam99", "8", "-1", ""])
def test_unknown_sensor_lists_the_available_ones(tmp_path, capsys, sensor):
    status, _, err = run_cli(capsys, "render", LIGHTSTAGE, tmp_path / "o", *TINY,
                             f"--sensor={sensor}")
    assert status == 2 and f"no sensor '{sensor}'" in err
    assert all(f"{k} cam0{k}" in err for k in range(8))
    assert not (tmp_path / "o").exists()


def test_sensor_all_renders_each_sensor_into_its_own_directory(tmp_path, capsys):
    status, out, err = run_cli(capsys, "render", LIGHTSTAGE, tmp_path / "o", "-D",
                               "resolution=8", "-D", "spp=1", "--sensor", "all")
    assert status == 0, err
    names = [f"cam{k:02d}" for k in range(8)]
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == names
    for k, name in enumerate(names):
        assert read_record(tmp_path / "o" / name)["sensor"] == {"index": k, "id": name}
    assert out.count("\n") == 8
    # A second run refuses before rendering anything; a sensor without an id is 'sensorNN'.
    status, _, err = run_cli(capsys, "render", LIGHTSTAGE, tmp_path / "o", "--sensor", "all")
    assert status == 2 and "--overwrite" in err
    assert run_cli(capsys, "render", SPHERE, tmp_path / "s", *SMALL, "--sensor", "all")[0] == 0
    assert read_record(tmp_path / "s" / "sensor00")["sensor"] == {"index": 0, "id": "sensor00"}


def test_lightstage_scene_is_exposed_without_clipping(lightstage_runs):
    """The face's 99th-percentile I0 is 0.5-0.8 and the preview shows it as rendered."""
    outdir = lightstage_runs["default"]
    channels, _ = read_exr(outdir / "polarization.exr")
    face = lit_pixels(channels["S0"])
    assert face.sum() > 50
    assert 0.5 <= np.percentile(channels["I0"][face], 99) <= 0.8
    settings = read_record(outdir)["preview_settings"]
    assert settings["exposure_mode"] == "as rendered" and settings["exposure"] == 1.0
    with Image.open(outdir / "I0.png") as image:
        preview = np.asarray(image)[..., 0][face]
    assert (preview >= 250).mean() < 0.01  # was 16% with the automatic exposure


def test_auto_exposure_for_renders_outside_the_displayable_range():
    rng = np.random.default_rng(0)
    S0 = rng.uniform(1.0, 2.0, (8, 8)).astype(np.float32)
    zeros = np.zeros_like(S0)
    channels = {"I0": S0 / 2, "I45": S0 / 2, "I90": S0 / 2, "I135": S0 / 2,
                "S0": S0, "S1": zeros, "S2": zeros, "S3": zeros}
    for scale, mode in ((1.0, "as rendered"), (10.0, "auto"), (1e-3, "auto")):
        settings = preview_settings({k: v * scale for k, v in channels.items()})
        assert settings["exposure_mode"] == mode
        white = settings["white_point"]
        assert settings["exposure"] == (1.0 if mode == "as rendered" else pytest.approx(1 / white))


def test_false_colour_previews_have_a_labelled_colour_bar(sphere_run):
    record = json.loads((sphere_run / "render.json").read_text())
    for name in ("S1", "S2", "DoLP", "AoLP"):
        with Image.open(sphere_run / PREVIEW_FILES[name]) as image:
            pixels = np.asarray(image)
        # Enlarged for readable labels, with a title strip and a bar on the right.
        assert pixels.shape[0] >= 160 and pixels.shape[1] > pixels.shape[0]
        assert record["previews"][name] == PREVIEW_FILES[name]
    with Image.open(sphere_run / PREVIEW_FILES["DoLP"]) as image:
        pixels = np.asarray(image).astype(int)
    # The bar holds the whole viridis range: its top (DoLP 1) is yellow, its bottom dark violet.
    yellow = np.all(np.abs(pixels - [253, 231, 37]) <= 6, axis=-1)
    violet = np.all(np.abs(pixels - [68, 1, 84]) <= 6, axis=-1)
    assert yellow[:, 32 * 5:].sum() > 20 and violet[:, 32 * 5:].sum() > 20
