"""synth's truth maps: biophysical maps as [base, std, low, high], bases off Table 2, features."""

import dataclasses
import json
import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest
from scipy import ndimage
from scipy.ndimage import gaussian_filter

from polarbssrdf.skin.parameters import TABLE2, TABLE2_STD, table2_spread_across_rows
from polarbssrdf.synth.microgeometry import DEFAULT_PORES
from polarbssrdf.synth.truth import (
    BIOPHYSICAL,
    DEFAULT_SKIN_LAYERS,
    SKIN_LAYERS,
    TruthSettings,
    disk_weight,
    feature_weight,
    frame_maps,
    load_settings,
    table2_offset_settings,
    truth_maps,
)

SUPPLEMENT = Path(__file__).resolve().parents[3] / "shared" / "seeds" / "000_cb884cfb311fcb48.txt"
TEXTURE = 128


@pytest.fixture(scope="module")
def sphere():
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.synth.synthesize import object_mesh

    mi.set_variant("llvm_ad_mono_polarized")
    return texel_atlas(to_mitsuba(object_mesh("sphere")), TEXTURE)


def old_truth_maps(atlas, settings, rng):
    """The truth maps as synth drew them before biophysical bases and features existed."""
    texel_mm = float(np.median(atlas.texel_size_mm[atlas.valid]))
    correlation = settings.correlation_mm / texel_mm

    def field():
        f = gaussian_filter(rng.standard_normal(atlas.valid.shape), correlation, mode="wrap")
        return f / max(f.std(), 1e-12)

    maps = {}
    for name, (base, std, low, high) in settings.reflectance.items():
        maps[name] = np.where(atlas.valid, np.clip(base + std * field(), low, high), base)
    row = TABLE2[tuple(settings.skin)]
    for name in BIOPHYSICAL:
        base = getattr(row, name)
        value = np.clip(base + settings.biophysical_std[name] * field(), 0.0, 1.0)
        maps[name] = np.where(atlas.valid, value, base)
    return {name: value.astype(np.float32) for name, value in maps.items()}


@pytest.mark.parametrize("skin", [("forehead", "II"), ("cheek", "IV")])
def test_settings_without_bases_or_features_draw_the_maps_they_drew_before(sphere, skin):
    # the wrinkles and pores (issue 33) are new, carved into the displacement last
    # (tests/synth/test_microgeometry.py): without them the maps are the old ones
    settings = TruthSettings(skin=skin, pores=None)
    ours = truth_maps(sphere, settings, np.random.default_rng(3))
    before = old_truth_maps(sphere, settings, np.random.default_rng(3))
    # the skin's layer maps are new, drawn after everything else
    assert set(ours) == set(before) | set(SKIN_LAYERS)
    for name in before:
        np.testing.assert_array_equal(ours[name], before[name], err_msg=name)
    # the row given explicitly as [base, std, 0, 1] is the same settings
    row = TABLE2[skin]
    explicit = TruthSettings(skin=skin, pores=None, biophysical={
        n: (getattr(row, n), settings.biophysical_std[n], 0.0, 1.0) for n in BIOPHYSICAL})
    again = truth_maps(sphere, explicit, np.random.default_rng(3))
    for name in ours:
        np.testing.assert_array_equal(again[name], ours[name], err_msg=name)


def test_a_base_moves_its_map_and_nothing_else(sphere):
    plain = truth_maps(sphere, TruthSettings(), np.random.default_rng(5))
    moved = truth_maps(sphere, TruthSettings(biophysical={"C_h_in": (0.05, 0.008, 0.0, 1.0)}),
                       np.random.default_rng(5))
    for name in plain:
        if name != "C_h_in":
            np.testing.assert_array_equal(moved[name], plain[name], err_msg=name)
    valid = sphere.valid
    shift = TABLE2[("forehead", "II")].C_h_in - 0.05
    # same field around another base (clipping at 0 only where the old base was near it)
    unclipped = valid & (plain["C_h_in"] > 0)
    np.testing.assert_allclose(moved["C_h_in"][unclipped] + shift, plain["C_h_in"][unclipped], atol=1e-6)


def test_low_and_high_clip_the_map_and_the_flush(sphere):
    settings = TruthSettings(biophysical={"C_h_out": (0.08, 0.03, 0.07, 0.09)}, hemoglobin_swing=0.5)
    maps = truth_maps(sphere, settings, np.random.default_rng(1))
    values = maps["C_h_out"][sphere.valid]
    assert values.min() >= np.float32(0.07) and values.max() <= np.float32(0.09)
    assert (values == np.float32(0.09)).mean() > 0.2  # a 1-sigma-wide box clips about a third
    last = frame_maps(maps, 4, 5, settings)
    assert last["C_h_out"].max() <= np.float32(0.09) and last["C_h_in"].max() > maps["C_h_in"].max()


@pytest.mark.parametrize("spread", ["row", "rows"])
def test_offset_settings_move_every_base_by_the_spread(sphere, spread):
    spreads = 1.5
    for skin in TABLE2:
        settings = table2_offset_settings(skin, spreads, spread=spread)
        scale = TABLE2_STD[skin] if spread == "row" else table2_spread_across_rows()
        for name, (base, std, low, high) in settings.biophysical_maps().items():
            mean = getattr(TABLE2[skin], name)
            assert base - mean == pytest.approx(spreads * scale[name], rel=1e-12), (skin, name)
            assert (std, low, high) == (settings.biophysical_std[name], 0.0, 1.0)
        assert settings.skin_parameters().C_m == pytest.approx(TABLE2[skin].C_m + spreads * scale["C_m"])
        assert settings.skin_parameters().eta == TABLE2[skin].eta
    # the maps' means sit off the row by about the shift, not at the table's mean
    skin = ("cheek", "II")
    maps = truth_maps(sphere, table2_offset_settings(skin, 1.0), np.random.default_rng(2))
    for name in BIOPHYSICAL:
        shift = TABLE2_STD[skin][name]
        mean = float(maps[name][sphere.valid].mean())
        assert abs(mean - getattr(TABLE2[skin], name)) > 0.5 * shift, name


def test_offset_settings_refuse_a_base_near_zero_and_take_signs():
    with pytest.raises(ValueError, match="C_h_in.*two map standard deviations"):
        table2_offset_settings(("cheek", "II"), 1.0, signs={"C_h_in": -1})
    down = table2_offset_settings(("forehead", "IV"), 1.0, signs={"C_m": -1})
    assert down.biophysical["C_m"][0] == pytest.approx(0.08909 - 0.00330)
    for bad, message in (({"skin": ("chin", "I")}, "skin must be one of"),
                         ({"spread": "all"}, "spread must be"),
                         ({"signs": {"C_m": 2}}, "signs must map"),
                         ({"spreads": -1}, "spreads must be")):
        arguments = {"skin": ("cheek", "I"), "spreads": 1.0, **bad}
        with pytest.raises(ValueError, match=message):
            table2_offset_settings(**arguments)
    with_std = table2_offset_settings(("cheek", "I"), 1.0, biophysical_std={"C_m": 0.001})
    assert with_std.biophysical["C_m"][1] == 0.001


@pytest.mark.skipif(not SUPPLEMENT.is_file(), reason="the supplement text is not beside the checkout")
def test_table2_means_and_spreads_are_the_supplements():
    lines = SUPPLEMENT.read_text(encoding="utf-8").splitlines()
    labels = {"He. (inner)": "C_h_in", "He. (outer)": "C_h_out", "Melanin": "C_m",
              "Rel. eumel.": "beta_m", "Refrac. idx": "eta"}
    found = {}
    region = None
    for line in lines:
        if line.strip() in ("Forehead", "Cheek"):
            region = line.strip().lower()
        label = next((key for key in labels if key in line), None)
        if region and label:
            pairs = re.findall(r"(\d\.\d+)\s*\\?\s*\(\s*(\d\.\d+)\s*\)", line)
            assert len(pairs) == 4, line
            for skin_type, (mean, std) in zip(("I", "II", "III", "IV"), pairs):
                found[(region, skin_type, labels[label])] = (float(mean), float(std))
    assert len(found) == 8 * 5
    for (region, skin_type, name), (mean, std) in found.items():
        assert getattr(TABLE2[(region, skin_type)], name) == mean, (region, skin_type, name)
        assert TABLE2_STD[(region, skin_type)][name] == std, (region, skin_type, name)


def test_disk_weight_is_one_at_the_centre_half_at_the_rim_and_falls_off():
    w = disk_weight([0.0, 1.5, 3.0], 3.0, 0.3)
    assert w[0] == 1.0 and w[1] == pytest.approx(0.5, abs=0.01) and w[2] < 0.01
    assert np.all(np.diff(disk_weight(np.linspace(0, 10, 50), 3.0, 0.3)) <= 0)


def test_freckles_raise_melanin_severalfold_in_disks_of_their_size(sphere):
    count, factor, diameter = 6, 4.0, 6.0
    freckles = {"name": "freckles", "map": "C_m", "factor": factor, "diameter_mm": diameter,
                "count": count}
    plain = truth_maps(sphere, TruthSettings(), np.random.default_rng(9))
    spotted = truth_maps(sphere, TruthSettings(features=[freckles]), np.random.default_rng(9))
    for name in plain:
        # the layer maps and the pores are drawn after the features' centres
        if name not in ("C_m", "displacement") and name not in SKIN_LAYERS:
            np.testing.assert_array_equal(spotted[name], plain[name], err_msg=name)
    ratio = np.where(sphere.valid, spotted["C_m"] / plain["C_m"], 1.0)
    assert ratio.max() == pytest.approx(factor, rel=0.05)
    assert ratio.min() >= 1.0 - 1e-6
    inside = ratio > 1.0 + 0.5 * (factor - 1.0)  # weight above 1/2: within the diameter
    labels, spots = ndimage.label(inside)
    assert spots == count  # six 6 mm disks on a 60 mm sphere (2 x 10^4 mm^2) barely ever touch
    # each disk covers its area on the surface: int w dA = pi (R^2 + pi^2 e^2 / 3) for a logistic rim
    weight = feature_weight(sphere, freckles, np.random.default_rng(0))
    covered = float((weight * np.prod(sphere.texel_size_mm, axis=-1)).sum())
    radius, edge = diameter / 2, diameter / 10
    assert covered == pytest.approx(count * np.pi * (radius ** 2 + np.pi ** 2 * edge ** 2 / 3), rel=0.05)
    # far from every spot the map is untouched
    points = sphere.position.astype(np.float64)
    gap = np.min(np.linalg.norm(points[:, :, None, :] - points[inside][None, None], axis=-1), axis=-1)
    far = sphere.valid & (gap > 2.0 * diameter)  # 20 edges beyond the rim: weight < 1e-8
    np.testing.assert_allclose(spotted["C_m"][far], plain["C_m"][far], rtol=1.2e-7)  # float32 rounding


def test_a_blood_patch_at_a_given_place(sphere):
    patch = {"map": "C_h_in", "factor": 2.0, "diameter_mm": 30.0, "edge_mm": 2.0,
             "centers_uv": [[0.25, 0.5]]}
    plain = truth_maps(sphere, TruthSettings(), np.random.default_rng(4))
    flushed = truth_maps(sphere, TruthSettings(features=[patch]), np.random.default_rng(4))
    ratio = np.where(sphere.valid, flushed["C_h_in"] / np.maximum(plain["C_h_in"], 1e-9), 1.0)
    i, j = np.unravel_index(np.argmax(ratio), ratio.shape)
    assert (abs(j + 0.5 - 0.25 * TEXTURE) <= 2) and (abs(i + 0.5 - 0.5 * TEXTURE) <= 2)
    inner = ratio > 1.5
    area = float((np.prod(sphere.texel_size_mm, axis=-1) * inner).sum())
    assert area == pytest.approx(np.pi * 15.0 ** 2, rel=0.1)
    # random centres come after the fields: settings without random features draw no more
    assert np.array_equal(flushed["C_m"], plain["C_m"])


@pytest.mark.parametrize("feature, message", [
    ({"map": "C_x", "factor": 2, "diameter_mm": 3, "count": 1}, r"features\[0\]\.map"),
    ({"map": "C_m", "factor": 0, "diameter_mm": 3, "count": 1}, r"features\[0\]\.factor"),
    ({"map": "C_m", "factor": 2, "diameter_mm": 3}, "exactly one of 'count' and 'centers_uv'"),
    ({"map": "C_m", "factor": 2, "diameter_mm": 3, "count": 1, "centers_uv": [[0, 0]]}, "exactly one"),
    ({"map": "C_m", "factor": 2, "diameter_mm": 3, "count": 1.5}, r"count"),
    ({"map": "C_m", "factor": 2, "diameter_mm": 3, "centers_uv": [[0.5, 1.5]]}, r"centers_uv"),
    ({"map": "C_m", "factor": 2, "count": 1}, "missing key 'diameter_mm'"),
    ({"map": "C_m", "factor": 2, "diameter_mm": 3, "count": 1, "radius": 2}, r"unknown key.*radius"),
])
def test_bad_features_are_refused_by_name(feature, message):
    with pytest.raises(ValueError, match=message):
        TruthSettings(features=[feature])


def test_settings_file_with_bases_and_features(tmp_path):
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"skin": ["cheek", "III"],
                                "biophysical": {"C_m": [0.06, 0.005, 0.0, 0.5]},
                                "features": [{"map": "C_m", "factor": 3, "diameter_mm": 2, "count": 4}]}))
    settings = load_settings(path)
    assert settings.biophysical_maps()["C_m"] == (0.06, 0.005, 0.0, 0.5)
    assert settings.biophysical_maps()["beta_m"][0] == TABLE2[("cheek", "III")].beta_m
    assert settings.features[0]["count"] == 4
    for bad, message in (({"biophysical": {"C_m": [0.06, 0.005, 0.1, 0.5]}}, "biophysical C_m"),
                         ({"biophysical": {"C_m": [0.06, 0.005, 0.0, 0.5]},
                           "biophysical_std": {"C_m": 0.01}}, "both biophysical and biophysical_std"),
                         ({"biophysical": {"melanin": [0.06, 0.005, 0.0, 0.5]}}, "melanin"),
                         ({"features": {"map": "C_m"}}, "features must be a list"),
                         ({"features": [{"map": "C_m"}]}, r"features\[0\]")):
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=message) as error:
            load_settings(path)
        assert str(path) in str(error.value)


def test_the_record_of_default_settings_is_unchanged_and_features_are_recorded():
    from polarbssrdf.synth.synthesize import truth_settings_json

    record = truth_settings_json(TruthSettings())
    # as before, and the skin's layer maps (issue 31), the wrinkles and pores (issue 33)
    assert set(record) == {"reflectance", "skin", "biophysical_std", "correlation_mm", "hemoglobin_swing",
                           "skin_layers", "wrinkles", "pores"}
    assert record["wrinkles"] == "face" and record["pores"] == DEFAULT_PORES
    assert record["skin_layers"] == {k: list(v) for k, v in DEFAULT_SKIN_LAYERS.items()}
    spotted = TruthSettings(features=[{"map": "C_m", "factor": 3, "diameter_mm": 2, "count": 4}],
                            biophysical={"C_m": (0.06, 0.005, 0.0, 0.5)})
    record = truth_settings_json(spotted)
    assert record["features"][0]["factor"] == 3 and record["biophysical"]["C_m"] == [0.06, 0.005, 0.0, 0.5]
    # what is recorded loads back as the same settings
    again = TruthSettings(**{**record, "skin": tuple(record["skin"]),
                             "biophysical": {k: tuple(v) for k, v in record["biophysical"].items()},
                             "reflectance": {k: tuple(v) for k, v in record["reflectance"].items()},
                             "skin_layers": {k: tuple(v) for k, v in record["skin_layers"].items()}})
    assert dataclasses.asdict(again) == dataclasses.asdict(spotted)


def test_synth_blurs_with_the_profile_of_the_moved_bases():
    from polarbssrdf.render.subsurface import layer_profile_kernels
    from polarbssrdf.spectral import shipped_default_bands
    from polarbssrdf.synth.synthesize import SynthesisSettings, prepare_capture

    mi.set_variant("llvm_ad_mono_polarized")
    bands = shipped_default_bands()[:2]
    settings = table2_offset_settings(("forehead", "I"), 3.0)
    prepared = prepare_capture(SynthesisSettings(object="sphere", views=1, resolution=16, texture=16,
                                                 spp=1), bands, settings)
    moved = dataclasses.replace(TABLE2[("forehead", "I")],
                                **{n: settings.biophysical[n][0] for n in BIOPHYSICAL})
    row = layer_profile_kernels(bands, TABLE2[("forehead", "I")])
    assert repr(prepared.kernels) == repr(layer_profile_kernels(bands, moved))
    assert repr(prepared.kernels) != repr(row)
