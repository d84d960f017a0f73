"""The biophysical stage of ``reconstruct``: frames, held melanin, region summary, files, errors."""

import json

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.spectral import default_bands

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
SKIN = ("forehead", "IV")
STD = {"C_m": 0.012, "beta_m": 0.01, "C_h_out": 0.02, "C_h_in": 0.012}
T = 48
FRAMES = 5
KNOWN_LAYERS = {"thickness_mm": (0.25, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}
"""Thickness and oxygenation at the fit's values: these tests are about the stage's frames and
summaries (bench/bio_off_prior.py measures faces where they are not known)."""


@pytest.fixture(scope="module")
def sequence():
    """A face whose cheeks flush over 5 frames (synth's frame model), as albedo maps with 0.5% noise."""
    from polarbssrdf.geometry import face_mesh, face_region_masks, texel_atlas, to_mitsuba
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import TruthSettings, frame_maps, truth_maps
    from scipy.ndimage import gaussian_filter

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), T)
    settings = TruthSettings(skin=SKIN, biophysical_std=STD, skin_layers=KNOWN_LAYERS)
    static = truth_maps(atlas, settings, np.random.default_rng(1))
    masks = face_region_masks(T)
    flush = gaussian_filter(masks["cheeks"].astype(np.float64), 1.0)
    flush /= flush.max()
    bands = default_bands()
    rng = np.random.default_rng(2)
    frames = []
    for frame in range(FRAMES):
        maps = frame_maps(static, frame, FRAMES, settings, flush)
        albedo = subsurface_albedo(maps, bands)
        inputs = {f"rho_sss.{b.name}": (albedo[i] * (1 + 0.005 * rng.standard_normal(albedo[i].shape)))
                  .astype(np.float32) for i, b in enumerate(bands)}
        inputs["eta"] = maps["eta"]
        frames.append((maps, inputs))
    region = masks["cheeks"] & atlas.valid & (flush > 0.5)
    return atlas, bands, frames, region, masks


def test_frames_follow_a_hemoglobin_flush_with_melanin_held(sequence):
    from polarbssrdf.inverse.biophysical.stage import fit_frame
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig

    atlas, bands, frames, region, _ = sequence
    config = BiophysicalConfig()
    reference = None
    recovered, truth = [], []
    for maps, inputs in frames:
        result = fit_frame(inputs, bands, atlas, config, reference)
        if reference is None:
            reference = result.maps
        else:  # melanin is held at the first frame's values on the surface
            for name in ("C_m", "beta_m"):
                np.testing.assert_array_equal(result.maps[name][atlas.valid],
                                              reference[name][atlas.valid])
        recovered.append(float(result.maps["C_h_out"][region].mean()))
        truth.append(float(maps["C_h_out"][region].mean()))
    recovered, truth = np.array(recovered), np.array(truth)
    print("C_h_out in the flush region: truth", truth.round(4), "recovered", recovered.round(4))
    assert truth[-1] > 1.2 * truth[0]  # the sequence does flush
    assert np.corrcoef(recovered, truth)[0, 1] > 0.9
    change, expected = recovered[-1] - recovered[0], truth[-1] - truth[0]
    assert abs(change - expected) < 0.3 * abs(expected)


def test_freeing_melanin_lets_it_move(sequence):
    from polarbssrdf.inverse.biophysical.stage import fit_frame
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig

    atlas, bands, frames, _, _ = sequence
    config = BiophysicalConfig(iterations=2, rounds=1)
    first = fit_frame(frames[0][1], bands, atlas, config)
    free = fit_frame(frames[-1][1], bands, atlas, config, first.maps, free_melanin=True)
    assert np.any(free.maps["C_m"][atlas.valid] != first.maps["C_m"][atlas.valid])


def test_region_summary_is_the_mean_and_spread_inside_each_mask():
    from polarbssrdf.inverse.biophysical.stage import region_summary

    rng = np.random.default_rng(0)
    maps = {name: rng.uniform(0, 0.1, (8, 8)).astype(np.float32) for name in PARAMETERS}
    maps["flagged"] = np.zeros((8, 8), np.float32)
    maps["flagged"][0, 0] = 1.0
    inside = np.zeros((8, 8), bool)
    inside[:3, :3] = True
    summary = region_summary({0: maps, 3: maps}, {"patch": inside, "empty": np.zeros((8, 8), bool)})
    assert set(summary["regions"]) == {"patch"}  # a region without texels is left out
    patch = summary["regions"]["patch"]
    assert patch["texels"] == 8  # the flagged texel is not counted
    kept = inside.copy()
    kept[0, 0] = False
    for frame in ("0", "3"):
        for name in PARAMETERS:
            assert patch["frames"][frame][name]["mean"] == pytest.approx(maps[name][kept].mean(), rel=1e-6)
            assert patch["frames"][frame][name]["std"] == pytest.approx(maps[name][kept].std(), rel=1e-5)


def test_unknown_bio_settings_are_named():
    from polarbssrdf.inverse.config import static_config

    with pytest.raises(ValueError, match="bio.*'colour'"):
        static_config({"bio": {"colour": 1}})
    with pytest.raises(ValueError, match="smoothness"):
        static_config({"bio": {"smoothness": {"C_x": 1.0}}})
    assert static_config({"bio": {"free_melanin": True, "iterations": 3}}).bio["iterations"] == 3


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    from polarbssrdf.cli import main

    root = tmp_path_factory.mktemp("bio_cli")
    capture = root / "capture"
    assert main(["synth", str(capture), "--object", "face", "--views", "4", "--resolution", "96",
                 "--texture", "48", "--spp", "2", "--quiet"]) == 0
    return root, capture


def test_reconstruct_runs_static_then_bio_and_registers_the_maps(small_capture):
    from PIL import Image

    from polarbssrdf.cli import main
    from polarbssrdf.inverse.results.directory import read_result, read_stage_maps

    root, capture = small_capture
    config = root / "config.json"
    config.write_text(json.dumps({"bio": {"iterations": 3, "rounds": 1}}))
    outdir = root / "run"
    assert main(["reconstruct", str(capture), str(outdir), "--iterations", "3", "--config",
                 str(config), "--quiet"]) == 0
    records = {(r["stage"], r["frame"]) for r in read_result(outdir).maps}
    assert records == {("static", 0), ("bio", 0)}
    maps = read_stage_maps(outdir, "bio", 0)
    assert set(maps) == {*PARAMETERS, *(f"{n}_std" for n in PARAMETERS),
                         "residual", "flagged"}
    surface = maps["flagged"] == 0
    for name in PARAMETERS:  # a posterior spread where the maps are: positive, below the bounds' range
        std = maps[f"{name}_std"]
        assert np.all(np.isfinite(std)) and np.all(std >= 0), name
        assert np.median(std[surface & (std > 0)]) > 0, name
    for name, values in maps.items():
        assert np.all(np.isfinite(values)), name
    for name in (*PARAMETERS, "residual"):
        with Image.open(outdir / "bio" / "previews" / f"{name}_f0000.png") as image:
            image.load()
            assert min(image.size) > 50
    summary = json.loads((outdir / "bio" / "summary.json").read_text())
    assert {"surface", "forehead", "cheeks"} <= set(summary["regions"])
    forehead = summary["regions"]["forehead"]["frames"]["0"]["C_m"]
    assert 0.0 <= forehead["mean"] <= 0.5 and forehead["std"] >= 0.0
    # the biophysical stage alone on the same result reads the static maps it holds
    (outdir / "bio" / "maps_f0000.exr").unlink()
    assert main(["reconstruct", str(capture), str(outdir), "--stages", "bio", "--config",
                 str(config), "--quiet"]) == 0
    assert (outdir / "bio" / "maps_f0000.exr").is_file()


def test_bio_without_an_earlier_stage_says_what_to_run(small_capture, capsys):
    from polarbssrdf.cli import main

    root, capture = small_capture
    code = main(["reconstruct", str(capture), str(root / "empty"), "--stages", "bio", "--quiet"])
    assert code != 0
    assert "--stages static,bio" in capsys.readouterr().err


def test_the_forehead_summary_of_a_table2_face_recovers_that_row():
    """A face made from Table 2's (forehead, IV) row: the recovered forehead means lie within 10%
    of the row's values (beta_m, weakly identifiable from six bands, within 0.05 of it) and
    within 3% of the truth's forehead means. The spread is small (synth's default, C_h_in
    +-0.008 on 0.027, moves the forehead's own mean 24% off the row)."""
    from polarbssrdf.geometry import face_mesh, face_region_masks, texel_atlas, to_mitsuba
    from polarbssrdf.inverse.biophysical.stage import fit_frame, region_summary
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig
    from polarbssrdf.skin.parameters import TABLE2
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import TruthSettings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    size = 96
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), size)
    spread = {"C_m": 0.001, "beta_m": 0.003, "C_h_out": 0.002, "C_h_in": 0.001}
    maps = truth_maps(atlas, TruthSettings(skin=SKIN, biophysical_std=spread, skin_layers=KNOWN_LAYERS),
                      np.random.default_rng(3))
    bands = default_bands()
    albedo = subsurface_albedo(maps, bands)
    inputs = {f"rho_sss.{b.name}": albedo[i] for i, b in enumerate(bands)}
    inputs["eta"] = maps["eta"]
    result = fit_frame(inputs, bands, atlas, BiophysicalConfig())
    masks = {name: mask & atlas.valid for name, mask in face_region_masks(size).items()}
    summary = region_summary({0: result.channels()}, masks)
    forehead = summary["regions"]["forehead"]["frames"]["0"]
    row = TABLE2[SKIN]
    print({name: (round(forehead[name]["mean"], 4), round(float(maps[name][masks["forehead"]].mean()), 4),
                  getattr(row, name)) for name in PARAMETERS})
    for name in ("C_m", "C_h_out", "C_h_in"):
        assert forehead[name]["mean"] == pytest.approx(getattr(row, name), rel=0.10), name
        truth = float(maps[name][masks["forehead"]].mean())
        assert forehead[name]["mean"] == pytest.approx(truth, rel=0.03), name
    assert abs(forehead["beta_m"]["mean"] - row.beta_m) < 0.05


def test_evaluate_scores_biophysical_maps_in_table2_ranges(small_capture):
    """``evaluate --stage bio``: maps equal to the truth score 0, the truth's mean scores the
    constant-map baseline."""
    from polarbssrdf.inverse.evaluation.scores import evaluate_result
    from polarbssrdf.inverse.results.directory import prepare_result_directory, write_stage_maps
    from polarbssrdf.io.exr import read_exr
    from polarbssrdf.skin.parameters import table2_ranges

    root, capture = small_capture
    outdir = root / "scored"
    truth, _ = read_exr(capture / "truth" / "maps_f0000.exr")
    prepare_result_directory(outdir, capture, truth["C_m"].shape[0], {"stages": ["bio"]})
    exact = {name: truth[name] for name in PARAMETERS}
    exact["flagged"] = np.zeros_like(truth["C_m"])
    write_stage_maps(outdir, "bio", 0, exact)
    report = evaluate_result(outdir, stage="bio")
    assert report["texels_scored"] > 100
    for name in PARAMETERS:
        assert report["maps"][name]["mae_of_range"] == pytest.approx(0.0, abs=1e-7)
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.io import load_capture

    surface = texel_atlas(to_mitsuba(load_capture(capture, check_images=False).load_mesh()),
                          truth["C_m"].shape[0]).valid
    # the truth's mean over the surface: the best constant map's level
    mean = {name: np.full_like(truth[name], float(np.mean(truth[name][surface])))
            for name in PARAMETERS}
    ranges = table2_ranges()
    constant = evaluate_result(outdir, stage="bio")["maps"]
    write_stage_maps(outdir, "bio", 0, {**mean, "flagged": exact["flagged"]})
    scored = evaluate_result(outdir, stage="bio")["maps"]
    for name in PARAMETERS:
        assert scored[name]["mae_of_range"] > 0
        assert scored[name]["mae_of_range"] == pytest.approx(
            constant[name]["constant_mae_of_range"], rel=1e-4)
        assert scored[name]["table2_range"] == list(ranges[name])


def test_overwrite_with_only_later_stages_is_refused_and_keeps_the_run(small_capture, capsys):
    """``--overwrite --stages bio`` would remove the static maps bio reads: an error, nothing lost."""
    import shutil

    from polarbssrdf.cli import main

    root, capture = small_capture
    outdir = root / "keep"
    assert main(["reconstruct", str(capture), str(outdir), "--stages", "static",
                 "--iterations", "1", "--quiet"]) == 0
    before = sorted(p.relative_to(outdir) for p in outdir.rglob("*"))
    capsys.readouterr()
    assert main(["reconstruct", str(capture), str(outdir), "--stages", "bio", "--overwrite",
                 "--quiet"]) == 2
    assert "would remove the static maps" in capsys.readouterr().err
    assert sorted(p.relative_to(outdir) for p in outdir.rglob("*")) == before
    shutil.rmtree(outdir)
