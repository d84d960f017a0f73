"""Spectral curves and bands: construction, integration, serialization."""

import json

import numpy as np
import pytest
from colour import SpectralDistribution

from polarbssrdf.spectral import (
    Band,
    band_average,
    band_weights_matrix,
    bands_from_json,
    bands_to_json,
    comb_curve,
    complementary_curve,
    default_bands,
    default_light,
    make_band,
    sample_curve,
    spectral_distribution,
    wavelength_grid,
)


def test_wavelength_grid_and_curves():
    wl = wavelength_grid(400, 700, 5)
    assert wl.size == 61 and wl[0] == 400 and wl[-1] == 700
    sd = spectral_distribution([400, 500, 600], [0.0, 1.0, 0.0])
    assert isinstance(sd, SpectralDistribution)
    np.testing.assert_allclose(sample_curve(sd, [450, 500, 650]), [0.5, 1.0, 0.0])
    np.testing.assert_allclose(sample_curve(([400, 500], [1, 3]), [380, 450, 520]), [0.0, 2.0, 0.0])
    with pytest.raises(ValueError):
        sample_curve("not a curve", wl)
    with pytest.raises(ValueError):
        spectral_distribution([500, 400], [1, 2])


def test_band_is_the_product_of_its_parts():
    wl = wavelength_grid(400, 700, 5)
    cam = lambda x: np.exp(-(((x - 550) / 50) ** 2))  # noqa: E731
    filt = comb_curve(70.0, 440.0)
    band = make_band("test", wl, cam, filt, default_light())
    np.testing.assert_allclose(band.weights, cam(wl) * filt(wl) * sample_curve(default_light(), wl))


def test_band_average_definition():
    band = default_bands()[2]
    assert band_average(lambda wl: np.full_like(wl, 0.37), band) == pytest.approx(0.37)
    # the average of lambda itself is the band's centroid
    assert band_average(lambda wl: wl, band) == pytest.approx(band.centroid_nm)
    # arrays with leading texel axes
    values = np.stack([np.full(band.wavelengths_nm.size, 0.2), band.wavelengths_nm])
    np.testing.assert_allclose(band_average(values, band), [0.2, band.centroid_nm])
    with pytest.raises(ValueError, match="samples"):
        band_average(np.ones(3), band)


def test_weights_matrix_agrees_with_band_average():
    bands = default_bands()
    wl = bands[0].wavelengths_nm
    matrix = band_weights_matrix(bands, wl)
    assert matrix.shape == (6, wl.size)
    np.testing.assert_allclose(matrix.sum(axis=1), 1.0)
    spectrum = 0.1 + 0.5 * np.sin(wl / 37.0) ** 2
    np.testing.assert_allclose(spectrum @ matrix.T, [band_average(spectrum, b) for b in bands], rtol=1e-12)


def test_default_six_bands():
    bands = default_bands()
    assert len(bands) == 6 and len({b.name for b in bands}) == 6
    centroids = [b.centroid_nm for b in bands]
    assert np.all(np.diff(centroids) > 0) and 430 < centroids[0] and centroids[-1] < 650
    # the two comb filters are complementary, so each channel's two bands sum
    # to the unfiltered channel (up to the filters' constant floor + peak)
    filt_a = comb_curve(70.0, 440.0)
    wl = wavelength_grid()
    np.testing.assert_allclose(filt_a(wl) + complementary_curve(filt_a)(wl), 0.97)
    # distinct bands: no two weight curves nearly proportional
    w = np.array([b.weights / np.linalg.norm(b.weights) for b in bands])
    gram = w @ w.T
    assert np.max(gram[~np.eye(6, dtype=bool)]) < 0.95


def test_json_round_trip_and_validation():
    bands = default_bands()
    text = bands_to_json(bands)
    json.loads(text)  # plain JSON
    back = bands_from_json(text)
    for a, b in zip(bands, back):
        assert a.name == b.name
        np.testing.assert_array_equal(a.weights, b.weights)
    with pytest.raises(ValueError, match="schema"):
        bands_from_json(json.dumps({"schema_version": 99, "bands": []}))
    with pytest.raises(ValueError, match="lacks field"):
        Band.from_dict({"name": "x"})
    with pytest.raises(ValueError, match=">= 0"):
        Band("neg", np.array([400.0, 500.0]), np.array([1.0, -1.0]))


def test_shipped_default_band_file_is_the_default_bands(tmp_path):
    from polarbssrdf.spectral import read_bands, shipped_default_bands

    shipped = shipped_default_bands()
    generated = default_bands()
    assert [b.name for b in shipped] == [b.name for b in generated]
    for a, b in zip(shipped, generated):
        np.testing.assert_allclose(a.wavelengths_nm, b.wavelengths_nm)
        np.testing.assert_allclose(a.weights, b.weights, rtol=1e-12)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        read_bands(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{oops")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_bands(tmp_path / "bad.json")
    (tmp_path / "empty.json").write_text('{"schema_version": 1, "bands": []}')
    with pytest.raises(ValueError, match="at least one band"):
        read_bands(tmp_path / "empty.json")


@pytest.mark.parametrize("content", [
    [{"name": "B", "wavelengths_nm": [400, 500], "weights": [1, 1]}],  # the list alone
    {"schema_version": 1, "bands": {"B": {}}},
    {"schema_version": 1, "bands": ["B"]},
    {"schema_version": 1, "bands": [{"name": "B", "wavelengths_nm": 400, "weights": 1}]},
])
@pytest.mark.parametrize("command", [["skin", "bands", "--bands"],
                                     ["synth", "OUT", "--object", "sphere", "--bands"]])
def test_a_malformed_band_file_is_one_line_naming_it(tmp_path, content, command):
    """Issue 32, item 7: a bare JSON list gave an AttributeError from both commands."""
    from helpers import run_cli

    path = tmp_path / "bands.json"
    path.write_text(json.dumps(content))
    argv = [str(tmp_path / "capture") if word == "OUT" else word for word in command]
    status, _, stderr = run_cli(*argv, path)
    assert status == 2, stderr
    assert stderr.count("\n") == 1 and str(path) in stderr and "not a band file" in stderr
    assert not (tmp_path / "capture").exists()
