"""The ``polarbssrdf skin`` commands through the real top-level CLI."""

import json

import numpy as np
import pytest

from polarbssrdf.cli import main
from polarbssrdf.skin.reflectance_csv import parse_wavelength_range, read_reflectance_csv

SPECTRUM = ["skin", "spectrum", "--melanin", "0.05", "--eumelanin", "0.05", "--hb-epidermis", "0.06",
            "--hb-dermis", "0.03"]


def test_spectrum_prints_csv(capsys):
    assert main(SPECTRUM) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "wavelength_nm,reflectance"
    rows = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    assert rows.shape == (61, 2) and rows[0, 0] == 400 and rows[-1, 0] == 700
    assert np.all((rows[:, 1] > 0) & (rows[:, 1] < 1))
    assert rows[-1, 1] > rows[10, 1]  # red above blue


def test_spectrum_plot_and_fit_round_trip(tmp_path, capsys):
    png = tmp_path / "spectrum.png"
    assert main(SPECTRUM + ["--wavelengths", "400:700:10", "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    csv = tmp_path / "spectrum.csv"
    csv.write_text(capsys.readouterr().out)
    assert main(["skin", "fit", str(csv)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["C_m"] == pytest.approx(0.05, rel=0.01)
    assert result["beta_m"] == pytest.approx(0.05, abs=0.01)
    assert result["C_h_out"] == pytest.approx(0.06, rel=0.01)
    assert result["C_h_in"] == pytest.approx(0.03, rel=0.02)
    assert 0 <= result["rmse"] < 1e-5


@pytest.mark.parametrize("argv, message", [
    (["--melanin", "-0.1"], "C_m must be a fraction"),
    (["--hb-dermis", "1.5"], "C_h_in must be a fraction"),
    (["--wavelengths", "350:750:10"], "400-700 nm"),
    (["--wavelengths", "400:700"], "start:stop:step"),
    (["--thickness", "0"], "thickness_mm must be > 0"),
])
def test_spectrum_bad_input(capsys, argv, message):
    args = list(SPECTRUM)
    for flag, value in zip(argv[::2], argv[1::2]):
        if flag in args:
            args[args.index(flag) + 1] = value
        else:
            args += [flag, value]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("polarbssrdf skin: error:") and message in err


@pytest.mark.parametrize("body, message", [
    ("wavelength,refl\n400,0.1\n", "line 1"),
    ("wavelength_nm,reflectance\n400,0.1\n410,abc\n", "line 3"),
    ("wavelength_nm,reflectance\n400,0.1\n410,0.2,3\n", "line 3"),
    ("# comment\nwavelength_nm,reflectance\n400,0.1\n400,0.2\n", "line 4"),
    ("wavelength_nm,reflectance\n400,1.7\n", "line 2"),
    ("wavelength_nm,reflectance\n", "no data"),
    ("wavelength_nm,reflectance\n390,0.1\n400,0.1\n410,0.1\n420,0.1\n", "400-700 nm"),
])
def test_fit_bad_csv(tmp_path, capsys, body, message):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    assert main(["skin", "fit", str(path)]) == 2
    assert message in capsys.readouterr().err


def test_fit_missing_file(tmp_path, capsys):
    assert main(["skin", "fit", str(tmp_path / "absent.csv")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_helpers():
    np.testing.assert_allclose(parse_wavelength_range("400:700:5"), np.arange(400, 701, 5))
    np.testing.assert_allclose(parse_wavelength_range("450,550,650"), [450, 550, 650])
    with pytest.raises(ValueError):
        parse_wavelength_range("700:400:5")
    with pytest.raises(FileNotFoundError):
        read_reflectance_csv("/nonexistent/file.csv")
