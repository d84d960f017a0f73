"""Pieces of the HTML report that need no result directory (the whole report: test_demo.py)."""

from __future__ import annotations

import io

import numpy as np
import pytest


def test_shown_frames_spread_over_the_sequence_with_both_ends():
    from polarbssrdf.report.page import shown_frames

    assert shown_frames([3, 1, 2]) == [1, 2, 3]
    picked = shown_frames(list(range(1, 300)), count=4)
    assert picked[0] == 1 and picked[-1] == 299 and len(picked) == 4
    assert picked == sorted(picked)


def test_lazy_frames_read_on_demand_and_keep_only_a_few():
    from polarbssrdf.report.page import LazyFrames

    reads = []

    def read(frame):
        reads.append(frame)
        return {"x": np.full((2, 2), frame)}

    frames = LazyFrames(range(10), read)
    assert len(frames) == 10 and 7 in frames and 10 not in frames and reads == []
    assert frames[7]["x"][0, 0] == 7 and frames[7]["x"][0, 0] == 7
    assert reads == [7]  # cached
    for frame in range(10):
        frames[frame]
    assert len(frames._cache) == LazyFrames.KEEP
    with pytest.raises(KeyError):
        frames[11]


def test_map_comparison_figure_scales_truth_and_estimate_alike():
    from PIL import Image

    from polarbssrdf.report.figures import map_comparison_png

    truth = np.linspace(1.4, 1.6, 32 * 32).reshape(32, 32)
    mask = np.ones((32, 32), bool)
    mask[:4] = False
    png = map_comparison_png("eta", truth + 0.01, truth, mask, "1")
    with Image.open(io.BytesIO(png)) as image:
        assert image.width > 2.5 * image.height  # three panels side by side
    alone = map_comparison_png("eta", truth, None, mask, "1")
    with Image.open(io.BytesIO(alone)) as image:
        assert image.width < 1.5 * image.height  # no truth: the recovered map only


def test_metrics_table_lists_each_map_with_the_constant_map_ratio():
    from polarbssrdf.report.page import metrics_html

    absolute = {"mae": 0.01, "constant_mae": 0.03, "unit": "1"}
    relative = {"relative_error": 0.02, "constant_relative_error": 0.05}
    evaluation = {"static": {"frame": 0, "texels_scored": 100, "holdout": None, "maps": {
        "eta": absolute, "alpha_s": absolute, "alpha_ss": absolute,
        "displacement": {**absolute, "unit": "mm"}, "rho_s": relative, "rho_ss": relative,
        "rho_sss": {"bands": {"G": relative}},
        "normal": {"mean_deg": 0.5, "base_mesh_mean_deg": 1.0}}}}
    page = metrics_html(evaluation)
    assert page.count("<tr>") == 1 + 4 + 3 + 1  # header, four MAEs, three albedos, normals
    assert "3.00x" in page and "2.50x" in page and "2.00x" in page


# --------------------------------------------------------------------------- issue 21, 20
# Hand-made report data (no capture, no render): each test builds only what the section reads.
def _fake_data(maps=None, truth=None, evaluation=None, valid=None, holdout=(), cameras=(),
               no_truth_reason="the capture has no ground truth", bio_summary=None):
    from types import SimpleNamespace

    from polarbssrdf.report.page import LazyFrames, ReportData

    stages = {stage: LazyFrames(list(frames), lambda f, frames=frames: frames[f])
              for stage, frames in (maps or {}).items()}
    images = [SimpleNamespace(camera=c, kind="analyser") for c in cameras]
    capture = SimpleNamespace(manifest=SimpleNamespace(
        frame=lambda f: SimpleNamespace(images=images), band_names=("G",)))
    manifest = SimpleNamespace(settings={"frame": 0, "holdout": list(holdout)},
                               units={"eta": "1", "displacement": "mm", "rho_sss": "1"})
    data = ReportData(result_dir=None, manifest=manifest, capture=capture,
                      atlas=SimpleNamespace(valid=valid), maps=stages,
                      truth=LazyFrames(list(truth), truth.__getitem__) if truth else {},
                      evaluation=evaluation, bio_summary=bio_summary)
    data.no_truth_reason = None if truth else no_truth_reason
    return data


def test_dimensionless_colour_bars_read_unitless_not_1():
    from polarbssrdf.report import figures

    figure = figures._figure(3, 3)
    figures._map_axes(figure.add_subplot(1, 1, 1), np.zeros((4, 4)), "eta", 0, 1, "viridis",
                      "1", figure)
    labels = [axes.get_ylabel() for axes in figure.axes]
    assert "unitless" in labels and "1" not in labels
    assert figures.unit_label("") == "unitless" and figures.unit_label("mm") == "mm"


def test_loss_legends_do_not_cover_the_curves():
    from polarbssrdf.report.figures import loss_curves_figure

    static = [{"epoch": e, "total": 10.0 / e, "sss": 5.0 / e, "s": 3.0 / e, "psi": 1.0 / e,
               "phi": 2.0 / e, "H_laplacian": 0.5 / e} for e in range(1, 21)]
    dynamic = {"1": [{"epoch": e, "total": 4.0 / e} for e in range(1, 6)]}
    bio = {"0": [{"losses": [3.0, 2.0, 1.5]}]}
    figure = loss_curves_figure(static, dynamic, bio)
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    plots = [axes for axes in figure.axes if axes.get_legend() is not None]
    assert len(plots) == 3
    for axes in plots:
        legend = axes.get_legend().get_window_extent(renderer)
        assert not legend.overlaps(axes.get_window_extent(renderer)), axes.get_title()


def test_coverage_of_gaussian_errors_matches_erf_and_flags_a_wrong_std():
    from polarbssrdf.report.calibration import COVERAGE_K, coverage_fractions, expected_coverage

    assert COVERAGE_K[0] == 0.25 and COVERAGE_K[-1] == 3.0
    rng = np.random.default_rng(3)
    truth = rng.uniform(0.01, 0.4, (64, 64))
    std = rng.uniform(0.002, 0.02, (64, 64))
    recovered = truth + std * rng.normal(size=truth.shape)
    mask = np.ones(truth.shape, bool)
    mask[:8] = False  # 3584 texels counted
    std_bad = std.copy()
    std_bad[8, :4] = 0.0  # no std: not counted
    recovered[9, :4] = np.nan  # not counted
    fractions, texels = coverage_fractions(recovered, truth, std_bad, mask)
    assert texels == 56 * 64 - 8
    # binomial spread of a fraction over 3576 texels is at most 0.0084: 4 sigma
    np.testing.assert_allclose(fractions, expected_coverage(), atol=0.034)
    assert expected_coverage((1.0,))[0] == pytest.approx(0.6827, abs=1e-4)
    wide, _ = coverage_fractions(recovered, truth, 2 * std, mask)  # std twice too large
    narrow, _ = coverage_fractions(recovered, truth, std / 2, mask)  # overconfident
    k1 = COVERAGE_K.index(1.0)
    assert wide[k1] > 0.9 and narrow[k1] < 0.45
    empty, none = coverage_fractions(recovered, truth, std, np.zeros(truth.shape, bool))
    assert none == 0 and np.isnan(empty).all()


def _bio_maps(rng, shape, with_std=True):
    from polarbssrdf.inverse.biophysical.model import PARAMETERS

    truth = {name: rng.uniform(0.02, 0.3, shape).astype(np.float32) for name in PARAMETERS}
    maps = {}
    for name in PARAMETERS:
        std = rng.uniform(0.002, 0.01, shape)
        maps[name] = (truth[name] + std * rng.normal(size=shape)).astype(np.float32)
        if with_std:
            maps[f"{name}_std"] = std.astype(np.float32)
    maps["residual"] = rng.uniform(0.001, 0.01, shape).astype(np.float32)
    maps["flagged"] = np.zeros(shape, np.float32)
    maps["flagged"][:, :5] = 1.0
    maps["residual"][:, :5] = 0.0  # the stage writes 0 where the input was not confident
    if with_std:
        maps["albedo_gain"] = np.ones(shape, np.float32)
    return maps, truth


def test_calibration_and_std_panels_from_a_hand_made_map_file(tmp_path):
    """A bio map file with the posterior std channels (issue 20): the std beside each
    chromophore, the albedo gain, and the calibration plot; none of it without them."""
    from polarbssrdf.io.exr import read_exr, write_exr
    from polarbssrdf.report import page
    from polarbssrdf.report.calibration import expected_coverage

    rng = np.random.default_rng(5)
    shape = (40, 40)
    maps, truth = _bio_maps(rng, shape)
    path = write_exr(tmp_path / "maps_f0000.exr", maps)
    read = {0: read_exr(path)[0]}
    valid = np.ones(shape, bool)
    valid[-4:] = False
    data = _fake_data(maps={"bio": read}, truth={0: truth}, valid=valid)
    curves = page.calibration_curves(data, [0])
    assert sorted(curves) == sorted(page.BIO_PARAMETERS)
    for name, (fractions, texels) in curves.items():
        assert texels == 36 * 35  # on the mesh, not flagged
        np.testing.assert_allclose(fractions, expected_coverage(), atol=0.06, err_msg=name)
    panels = page._bio_panels(data, 0, read[0], truth)
    by_name = {p[0]: p for p in panels}
    for name in page.BIO_PARAMETERS:
        assert by_name[name][5] is not None  # std beside the map
    assert by_name["albedo_gain"][4] == "1" and by_name["albedo_gain"][5] is None
    section = page.biophysical_section(data)
    assert "posterior standard deviation" in section
    calibration = page.calibration_html(data, [0])
    assert "posterior calibration" in calibration
    for name in page.BIO_PARAMETERS:
        assert f"{name} (bio)" in calibration

    plain, _ = _bio_maps(rng, shape, with_std=False)
    path = write_exr(tmp_path / "plain.exr", plain)
    data = _fake_data(maps={"bio": {0: read_exr(path)[0]}}, truth={0: truth}, valid=valid)
    assert page.calibration_curves(data, [0]) == {} and page.calibration_html(data, [0]) == ""
    panels = page._bio_panels(data, 0, data.maps["bio"][0], truth)
    assert all(p[5] is None for p in panels) and "albedo_gain" not in {p[0] for p in panels}
    assert "posterior standard deviation" not in page.biophysical_section(data)


def _static_maps(rng, shape, bands, too_small=()):
    """A static map file with a posterior std per map whose error is drawn from it (twice
    the std for the maps in ``too_small``), and its truth."""
    names = list(("eta", "alpha_s", "alpha_ss", "rho_s", "rho_ss", "displacement")) + [
        f"rho_sss.{band}" for band in bands]
    truth, maps = {}, {"confidence": np.ones(shape, np.float32)}
    for name in names:
        truth[name] = rng.uniform(0.3, 0.6, shape).astype(np.float32)
        std = rng.uniform(0.002, 0.01, shape)
        scale = 2.0 if name in too_small else 1.0
        maps[name] = (truth[name] + scale * std * rng.normal(size=shape)).astype(np.float32)
        maps[f"{name}_std"] = std.astype(np.float32)
    maps["confidence"][:3] = 0.0
    return maps, truth


def test_static_std_beside_the_error_and_every_stage_in_one_calibration_plot(monkeypatch):
    """Issue 33 item 3: each static map's posterior std and z-score beside its error, a map
    held at its face level says so beside its figure, and one calibration plot pools the
    static, dynamic and biophysical maps (the albedo's bands into one curve)."""
    from polarbssrdf.report import page
    from polarbssrdf.report.calibration import COVERAGE_K

    rng = np.random.default_rng(11)
    shape = (30, 30)
    valid = np.ones(shape, bool)
    valid[:, -2:] = False
    static, truth = _static_maps(rng, shape, ("G", "R"), too_small=("displacement",))
    dynamic, dynamic_truth = _static_maps(rng, shape, ("G", "R"))
    bio, bio_truth = _bio_maps(rng, shape)
    data = _fake_data(maps={"static": {0: static}, "dynamic": {1: dynamic}, "bio": {0: bio, 1: bio}},
                      truth={0: {**truth, **bio_truth}, 1: {**dynamic_truth, **bio_truth}},
                      valid=valid)
    data.capture.manifest.band_names = ("G", "R")
    data.metadata["static"] = {0: {"held_at_face_mean": {
        "rho_ss": {"mean": 0.45, "level": 0.46, "spread": 0.05, "noise_std": 0.1}}}}

    drawn = {}

    def record(name, recovered, truth, mask, unit="1", relative=False, std=None, note=None):
        drawn[name] = (std is not None, note)
        return b"png"

    monkeypatch.setattr(page, "map_comparison_png", record)
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    section = page.static_maps_section(data)
    for name in ("eta", "alpha_s", "alpha_ss", "rho_s", "rho_ss", "displacement", "rho_sss.G"):
        assert drawn[name][0], name
    assert drawn["rho_ss"][1] == "rho_ss: held at its face level"
    assert drawn["eta"][1] is None
    assert "held at one face value 0.46" in section and "error divided by it" in section

    curves, stages = page.stage_calibration_curves(data)
    at_two = COVERAGE_K.index(2.0)
    for stage, frames in (("static", 1), ("dynamic", 1)):
        for name in ("eta", "alpha_s", "rho_ss", "rho_sss"):
            fractions, texels = curves[f"{name} ({stage})"]
            bands = 2 if name == "rho_sss" else 1
            assert texels == bands * frames * 27 * 28, (name, stage)  # confident, on the mesh
            assert abs(fractions[at_two] - 0.954) < 0.03, (name, stage)
    assert curves["displacement (static)"][0][at_two] < 0.8  # its std is half its error's
    assert curves["C_m (bio)"][1] == 2 * 30 * 23  # both bio frames pooled, flagged left out
    assert {stages[label] for label in curves} == {"static", "dynamic", "bio"}
    plotted = {}
    monkeypatch.setattr(page, "calibration_png",
                        lambda curves, notes=None, markers=None: plotted.update(
                            notes=notes, markers=markers) or b"png")
    assert "rho_sss (static) 0.9" in page.calibration_html(data, [0, 1])
    assert plotted["notes"]["rho_ss (static)"] == "held at its face level"
    assert plotted["markers"]["eta (static)"] != plotted["markers"]["eta (dynamic)"]
    assert plotted["markers"]["C_m (bio)"] not in (plotted["markers"]["eta (static)"],
                                                    plotted["markers"]["eta (dynamic)"])


def test_biophysical_residual_is_masked_like_the_chromophores(monkeypatch):
    """The residual was drawn over the whole mesh: 0 (dark) where the other panels are grey."""
    from polarbssrdf.report import page

    drawn = {}

    def record(name, recovered, truth, mask, *args, **kwargs):
        drawn[name] = np.asarray(mask, bool).copy()
        return b"png"

    monkeypatch.setattr(page, "map_comparison_png", record)
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    maps, _ = _bio_maps(np.random.default_rng(1), (12, 12), with_std=False)
    data = _fake_data(maps={"bio": {0: maps}}, valid=np.ones((12, 12), bool))
    page.biophysical_section(data)
    assert not drawn["residual"][:, :5].any()
    np.testing.assert_array_equal(drawn["residual"], drawn["C_m"])


def test_one_frame_has_no_hemoglobin_plot_and_the_region_table_labels_its_columns(monkeypatch):
    from polarbssrdf.report import page

    monkeypatch.setattr(page, "map_comparison_png", lambda *a, **k: b"png")
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    maps, _ = _bio_maps(np.random.default_rng(2), (12, 12), with_std=False)
    stats = {p: {"mean": 0.1, "std": 0.01} for p in page.BIO_PARAMETERS}
    summary = {"units": {}, "regions": {"surface": {"texels": 100,
                                                    "frames": {"0": stats}}}}
    data = _fake_data(maps={"bio": {0: maps}}, valid=np.ones((12, 12), bool),
                      bio_summary=summary)
    section = page.biophysical_section(data)
    assert "alt='hemoglobin over time'" not in section and "Hemoglobin over time" not in section
    assert "One frame (0)" in section
    assert "<th></th>" not in section and "<th>source</th>" in section


def test_metrics_mark_maps_that_lose_to_the_best_constant_map():
    from polarbssrdf.report.page import LOSES, losing_maps, metrics_html

    good = {"mae": 0.01, "constant_mae": 0.03, "unit": "1"}
    bad = {"mae": 0.03, "constant_mae": 0.03, "unit": "1"}  # a tie loses: no information
    relative = {"relative_error": 0.02, "constant_relative_error": 0.05}
    worse = {"relative_error": 0.08, "constant_relative_error": 0.05}
    bio_map = {"mae_of_range": 0.05, "constant_mae_of_range": 0.10}
    evaluation = {"static": {"frame": 0, "texels_scored": 100, "holdout": None, "maps": {
        "eta": good, "alpha_s": bad, "alpha_ss": good,
        "displacement": {**good, "unit": "mm"}, "rho_s": relative, "rho_ss": worse,
        "rho_sss": {"bands": {"G": relative}},
        "normal": {"mean_deg": 0.5, "base_mesh_mean_deg": 1.0}}},
        "bio": {"0": {"maps": {"C_m": {"mae_of_range": 0.2, "constant_mae_of_range": 0.1},
                               "beta_m": bio_map, "C_h_out": bio_map, "C_h_in": bio_map}}}}
    losers = losing_maps(evaluation)
    assert sorted(losers["static"]) == ["alpha_s", "rho_ss"]
    assert list(losers["bio"]["0"]) == ["C_m"]
    page = metrics_html(evaluation)
    rows = {row.split("<td>")[1].split("</td>")[0]: row
            for row in page.split("<tr")[1:] if "<td>" in row}
    assert 'class="loses"' in rows["alpha_s"] and LOSES in rows["alpha_s"]
    assert 'class="loses"' in rows["rho_ss"]
    assert 'class="loses"' not in rows["eta"] and 'class="loses"' not in rows["rho_s"]
    assert "3 map(s) no better than the best constant map" in page
    assert "<td>unitless</td>" in page and "<td>1</td>" not in page
    assert losing_maps(None) == {"static": {}, "bio": {}}


def test_most_of_the_surface_unconfident_is_said_at_the_top():
    from polarbssrdf.report.page import confidence_warning

    valid = np.ones((10, 10), bool)
    valid[0] = False  # 90 texels on the mesh
    confidence = np.full((10, 10), 0.5, np.float32)
    confidence[1:7] = 0.0  # 60 of 90 texels: 67%
    data = _fake_data(maps={"static": {0: {"confidence": confidence}}}, valid=valid,
                      holdout=["cam3"], cameras=["cam0", "cam1", "cam2", "cam3"])
    text = confidence_warning(data)
    assert "67% of the surface (3 views fitted) has confidence 0" in text
    confidence[1:5] = 0.5  # 20 of 90
    assert confidence_warning(data) == ""


def test_static_maps_without_truth_say_why_and_nothing_about_truth(monkeypatch):
    from types import SimpleNamespace

    from polarbssrdf.report import page

    monkeypatch.setattr(page, "map_comparison_png", lambda *a, **k: b"png")
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    maps = {name: np.zeros((8, 8), np.float32) for name in page.STATIC_MAPS}
    maps.update({"rho_sss.G": np.zeros((8, 8)), "confidence": np.ones((8, 8))})
    data = _fake_data(maps={"static": {0: maps}}, valid=np.ones((8, 8), bool),
                      no_truth_reason="the capture has no ground truth")
    section = page.static_maps_section(data)
    assert "relative to the truth" not in section and "the capture has no ground truth" in section
    assert section.count('<div class="grid">') == 1 and section.count("<img") == 8

    assert page.no_truth_reason(SimpleNamespace(truth=None), 32) == \
        "the capture has no ground truth"
    other = page.no_truth_reason(SimpleNamespace(truth=SimpleNamespace(texture_size=64)), 32)
    assert "64 x 64" in other and "32 x 32" in other and "--texture 64" in other
    assert page.no_truth_reason(SimpleNamespace(truth=SimpleNamespace(texture_size=32)),
                                32) is None


def test_input_views_mark_the_held_out_camera(monkeypatch):
    from polarbssrdf.report import page

    titles = []
    monkeypatch.setattr(page, "captured_view",
                        lambda capture, record: {"G": {"I0": np.ones((4, 4)),
                                                       "I90": np.ones((4, 4))}})
    monkeypatch.setattr(page, "input_views_png",
                        lambda views, unit: titles.extend(v[0] for v in views) or b"png")
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    data = _fake_data(holdout=["cam1"], cameras=["cam0", "cam1", "cam2"])
    section = page.input_views_section(data)
    assert titles == ["cam0 (G)", "cam1 (G, held out)", "cam2 (G)"]
    assert "cam1 was held out of the fit" in section and "W sr<sup>-1</sup>" in section


# --------------------------------------------------------------------------- issue 32, item 4
# An uncertainty a user can read: the pieces on hand-made maps (the whole report in a
# browser: tests/test_demo.py).
def _bio_file(tmp_path, rng, shape=(24, 24)):
    """A bio map file whose beta_m the fit held at its face mean (older files say so in
    ``held_at_face_mean``) and whose C_h_in is prior-dominated (std = the prior spread)."""
    from polarbssrdf.io.exr import read_exr, write_exr

    maps, truth = _bio_maps(rng, shape)
    maps["C_h_in_std"] = np.full(shape, 0.02, np.float32)
    metadata = {"noise": {"held_at_face_mean": ["beta_m"],
                          "face_means": {"beta_m": {"mean": 0.05, "std": 0.001}},
                          "spread": {"C_m": 0.05, "C_h_out": 0.05, "C_h_in": 0.02}},
                "held": []}
    path = write_exr(tmp_path / "maps_f0000.exr", maps, metadata=metadata)
    return read_exr(path), truth


# --------------------------------------------------------------------------- held maps
def test_a_held_or_prior_dominated_map_says_so_beside_its_maps_and_curve(tmp_path,
                                                                         monkeypatch):
    from polarbssrdf.inverse.evaluation.trust import bio_map_notes
    from polarbssrdf.report import page

    (maps, metadata), truth = _bio_file(tmp_path, np.random.default_rng(4))
    notes = bio_map_notes(maps, metadata)
    assert notes["beta_m"]["kind"] == "held_at_face_mean" and "0.05" in notes["beta_m"]["text"]
    assert notes["C_h_in"]["kind"] == "prior_dominated"
    assert "C_m" not in notes and "C_h_out" not in notes  # std well below the spread
    later = bio_map_notes(maps, {"held": ["C_m", "beta_m"]})  # a later frame of a sequence
    assert later["C_m"]["kind"] == "held_at_first_frame"

    drawn, legends = {}, {}
    monkeypatch.setattr(page, "map_comparison_png",
                        lambda name, *a, note=None, **k: drawn.setdefault(name, note) and b"")
    monkeypatch.setattr(page, "calibration_png",
                        lambda curves, notes=None, markers=None: legends.update(notes or {}) or b"")
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}'>")
    data = _fake_data(maps={"bio": {0: maps}}, truth={0: truth},
                      valid=np.ones(maps["C_m"].shape, bool))
    data.metadata = {"bio": {0: metadata}}
    section = page.biophysical_section(data)
    assert '<p class="held">beta_m, frame 0: held at its face mean 0.05' in section
    assert '<p class="held">C_h_in, frame 0: prior-dominated' in section
    assert drawn["beta_m"] == "beta_m: held at its face mean" and drawn["C_m"] is None
    page.calibration_html(data, [0])
    assert legends == {"beta_m (bio)": "held at its face mean (frame 0)",
                       "C_h_in (bio)": "prior-dominated (frame 0)"}


def test_the_terminal_names_the_maps_the_bands_do_not_measure(tmp_path):
    """reconstruct's bio line and the demo's closing lines (issue 32, item 4)."""
    from polarbssrdf.inverse.pipeline import unmeasured_text
    from polarbssrdf.io.exr import write_exr

    (maps, metadata), _ = _bio_file(tmp_path / "", np.random.default_rng(4))
    (tmp_path / "bio").mkdir()
    write_exr(tmp_path / "bio" / "maps_f0000.exr", maps, metadata=metadata)
    write_exr(tmp_path / "bio" / "maps_f0001.exr", maps, metadata={**metadata,
                                                                   "held": ["C_m"]})
    text = unmeasured_text(tmp_path, [0, 1])
    assert text.startswith("; not measured by the bands")
    assert "beta_m held at its face mean (frames 0, 1)" in text
    assert "C_h_in prior-dominated (frames 0, 1)" in text
    assert "C_m" not in text  # a later frame holding the first frame's melanin is the design


# --------------------------------------------------------------------------- figures
def test_an_error_over_std_map_stands_beside_the_std_map():
    from polarbssrdf.report.figures import Z_LIMIT, map_comparison_figure

    rng = np.random.default_rng(8)
    truth = rng.uniform(0.02, 0.3, (32, 32))
    std = np.full((32, 32), 0.01)
    recovered = truth + std * rng.normal(size=truth.shape)
    mask = np.ones(truth.shape, bool)
    figure = map_comparison_figure("C_m", recovered, truth, mask, std=std)
    titles = [axes.get_title() for axes in figure.axes if axes.get_title()]
    assert titles[3] == "C_m: posterior std" and titles[4].startswith("error / std: ")
    assert "(ideal 95%)" in titles[4]
    z_axes = figure.axes[[a.get_title() for a in figure.axes].index(titles[4])]
    assert z_axes.images[0].get_clim() == (-Z_LIMIT, Z_LIMIT)
    # without truth there is no error, so no z-score either
    alone = map_comparison_figure("C_m", recovered, None, mask, std=std)
    assert not any("error / std" in axes.get_title() for axes in alone.axes)


def test_the_calibration_axis_is_k_up_to_3_with_room():
    """Against erf(k / sqrt 2) the points at k = 2.5 and 3 sat 1% of the axis apart,
    squeezed against its right edge."""
    from polarbssrdf.report.calibration import COVERAGE_K, expected_coverage
    from polarbssrdf.report.figures import calibration_figure

    curves = {"C_m": (expected_coverage() * 0.9, 1000)}
    figure = calibration_figure(curves, notes={"C_m": "held at its face mean (frame 0)"})
    axes = figure.axes[0]
    low, high = axes.get_xlim()
    x = axes.lines[-1].get_xdata()
    np.testing.assert_allclose(x, COVERAGE_K)  # the abscissa is k itself
    assert x[-1] == 3.0 and high - x[-1] >= 0.05 * (high - low)  # room after k = 3
    at = list(COVERAGE_K).index(2.5)
    assert (x[-1] - x[at]) / (high - low) > 0.1  # k = 2.5 and 3 apart
    labels = [text.get_text() for text in axes.get_legend().get_texts()]
    assert "C_m (1,000 texels, held at its face mean (frame 0))" in labels


# --------------------------------------------------------------------------- tables
def test_the_region_table_says_what_plus_minus_is():
    from polarbssrdf.report.page import BIO_PARAMETERS, table2_html

    stats = {p: {"mean": 0.1, "std": 0.01} for p in BIO_PARAMETERS}
    summary = {"regions": {"cheeks": {"texels": 250, "frames": {"0": stats}}}}
    table = table2_html(summary, None, [0])
    assert "mean &plusmn; spatial std" in table
    assert "standard deviation of the map over the region's texels" in table
    assert "not an uncertainty" in table and "<td>250</td>" in table


def test_the_two_std_coverage_is_printed_beside_its_ideal():
    from polarbssrdf.inverse.evaluation.scores import COVERAGE_IDEAL, uncertainty_scores
    from polarbssrdf.report.page import metrics_html

    assert COVERAGE_IDEAL == pytest.approx(0.9545, abs=1e-4)
    scores = uncertainty_scores(np.array([0.0, 0.1, 0.5]), np.array([0.1, 0.1, 0.1]))
    assert scores["coverage_ideal"] == pytest.approx(0.9545, abs=1e-4)

    entry = {"mae_of_range": 0.05, "constant_mae_of_range": 0.10, "coverage": 0.62}
    page = metrics_html({"bio": {"0": {"maps": {p: dict(entry) for p in
                                                ("C_m", "beta_m", "C_h_out", "C_h_in")}}}})
    assert "within 2 posterior std" in page and "<th>ideal</th>" in page
    assert "<td>0.620</td>" in page and "<td>0.954</td>" in page


def by_key_of(lines):
    return {line.split(":")[0].strip(): line for line in lines}


def test_the_demo_closing_lines_mark_maps_worse_than_a_constant():
    from polarbssrdf.demo import closing_lines

    loses = {"mae_of_range": 0.2, "constant_mae_of_range": 0.1, "coverage": 0.5}
    wins = {"mae_of_range": 0.05, "constant_mae_of_range": 0.1, "coverage": 0.95}
    metrics = {
        "headline": {"static eta MAE": 0.02, "static eta MAE of the best constant map": 0.03,
                     "static alpha_s MAE": 0.04,
                     "static alpha_s MAE of the best constant map": 0.03,
                     "bio beta_m MAE / Table 2 range (mean over frames)": 0.2,
                     "bio beta_m MAE of the best constant map / Table 2 range": 0.1,
                     "bio beta_m fraction within 2 std (mean over frames)": 0.5},
        "evaluation": {"static": {"maps": {"alpha_s": {"mae": 0.04, "constant_mae": 0.03}}},
                       "bio": {"0": {"maps": {"beta_m": loses, "C_m": wins}},
                               "1": {"maps": {"beta_m": loses, "C_m": wins}}}},
        "bio_notes": {"0": {"beta_m": {"kind": "prior_dominated", "label": "prior-dominated",
                                       "text": "..."}}},
        "static_notes": {"rho_ss": {"kind": "held_at_face_mean", "label": "held at its face level",
                                    "text": "..."}}}
    metrics["headline"]["static eta fraction within 2 std"] = 0.93
    lines = closing_lines(metrics)
    assert by_key_of(lines)["static eta fraction within 2 std"].endswith("0.93 (ideal 0.954)")
    assert any("held at one face value" in line and line.endswith(": rho_ss") for line in lines)
    by_key = {line.split(":")[0].strip(): line for line in lines}
    assert by_key["static eta MAE"] == "  static eta MAE: 0.02 (best constant map: 0.03)"
    assert by_key["static alpha_s MAE"].endswith(
        "(best constant map: 0.03)  <- no better than the best constant map")
    assert by_key["bio beta_m MAE / Table 2 range (mean over frames)"].endswith(
        "<- no better than the best constant map")
    assert by_key["bio beta_m fraction within 2 std (mean over frames)"].endswith(
        "0.5 (ideal 0.954)")
    assert not any(line.strip().startswith("static eta MAE of the best") for line in lines)
    assert ("  no better than the best constant map (marked in the report): alpha_s (static), "
            "beta_m (bio, frames 0, 1)") in lines
    assert lines[-1].endswith("beta_m prior-dominated (frame 0)")


def test_the_normals_section_shows_the_displacement_transfer_curve(monkeypatch):
    """Issue 33 item 2: which scales of the relief a capture resolves, from evaluate's
    displacement.transfer, beside the normal maps; nothing without an evaluation."""
    from polarbssrdf.report import figures, page

    curve = [{"sigma_mm": [low, high], "gain": gain, "correlation": 0.9, "truth_rms_mm": 0.01,
              "error_rms_mm": 0.005}
             for (low, high), gain in zip(((0.0, 0.9), (0.9, 1.8), (1.8, 3.6)), (0.2, 0.6, 0.9))]
    figure = figures.transfer_figure(curve)
    axes = figure.axes[0]
    gains = axes.lines[1].get_ydata()  # after the reference line at 1
    np.testing.assert_allclose(gains, [0.2, 0.6, 0.9])
    centres = axes.lines[1].get_xdata()
    assert centres[0] == pytest.approx(0.45) and centres[1] == pytest.approx(np.sqrt(0.9 * 1.8))

    shape = (8, 8)
    maps = {"confidence": np.ones(shape), **{f"normal.{a}": np.zeros(shape) for a in "xy"},
            "normal.z": np.ones(shape)}
    monkeypatch.setattr(page, "normals_png", lambda *a: b"png")
    monkeypatch.setattr(page, "transfer_png", lambda c: repr(c).encode())
    monkeypatch.setattr(page, "_image", lambda png, alt: f"<img alt='{alt}' data='{png.decode()}'>")
    data = _fake_data(maps={"static": {0: maps}}, valid=np.ones(shape, bool),
                      evaluation={"static": {"maps": {"displacement": {"transfer": curve}}}})
    section = page.normals_section(data)
    assert "displacement transfer curve" in section and "'gain': 0.6" in section
    data = _fake_data(maps={"static": {0: maps}}, valid=np.ones(shape, bool))
    assert "transfer" not in page.normals_section(data)
