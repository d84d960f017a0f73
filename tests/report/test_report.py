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
