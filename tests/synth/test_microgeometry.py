"""Wrinkles and pores in synth's truth displacement (issue 33, item 1)."""

import numpy as np
import pytest

import mitsuba as mi

from polarbssrdf.geometry import face_mesh, face_region_masks, texel_atlas, to_mitsuba
from polarbssrdf.synth.microgeometry import (
    DEFAULT_PORES,
    face_wrinkle_paths,
    pore_depth,
    texel_sigma_mm,
    unresolved_features,
    wrinkle_depth,
)
from polarbssrdf.synth.truth import TruthSettings, load_settings, truth_maps


@pytest.fixture(scope="module")
def atlases():
    mi.set_variant("llvm_ad_mono_polarized")
    mesh = face_mesh(1)
    return {size: texel_atlas(to_mitsuba(mesh), size) for size in (64, 128, 512)}


def texel_mm(atlas):
    return float(np.median(atlas.texel_size_mm[atlas.valid]))


def block_mean(fine, valid_fine, factor):
    """Mean of the valid fine texels in each factor x factor block (NaN where none)."""
    T = fine.shape[0] // factor
    total = np.where(valid_fine, fine, 0.0).reshape(T, factor, T, factor).sum(axis=(1, 3))
    count = valid_fine.reshape(T, factor, T, factor).sum(axis=(1, 3))
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


CHEEK_WRINKLE = {"path_uv": [[0.25, 0.55], [0.40, 0.62]], "depth_mm": 0.2, "width_mm": 1.5}


def test_a_wrinkle_is_its_texel_average(atlases):
    """At 128^2 (1.8 mm texels) a 1.5 mm furrow is stored as its average over the texel:
    against the same furrow drawn at 512^2 and averaged over 4 x 4 blocks, the depth at the
    centre line agrees within 15% and the carved volume within 5%."""
    coarse, fine = atlases[128], atlases[512]
    depth = wrinkle_depth(coarse, CHEEK_WRINKLE, texel_mm(coarse))
    reference = block_mean(wrinkle_depth(fine, CHEEK_WRINKLE, texel_mm(fine)), fine.valid, 4)
    both = coarse.valid & np.isfinite(reference)
    deepest = reference[both].max()
    assert deepest > 0.5 * CHEEK_WRINKLE["depth_mm"]
    assert abs(depth[both].max() - deepest) < 0.15 * deepest
    area = np.prod(coarse.texel_size_mm.astype(np.float64), axis=-1)
    volume, reference_volume = np.sum((depth * area)[both]), np.sum((reference * area)[both])
    assert abs(volume - reference_volume) < 0.05 * reference_volume
    # the furrow is where its path is, and nothing far from it
    sigma, sigma_eff = texel_sigma_mm(CHEEK_WRINKLE["width_mm"], texel_mm(coarse))
    assert depth[both].max() == pytest.approx(CHEEK_WRINKLE["depth_mm"] * sigma / sigma_eff, rel=0.1)
    assert np.count_nonzero(depth > 0.01) < 0.05 * np.count_nonzero(coarse.valid)


def test_pores_at_their_density_and_volume(atlases):
    atlas = atlases[128]
    pores = {"density_per_cm2": 30.0, "diameter_mm": 0.4, "depth_mm": 0.1}
    area = np.prod(atlas.texel_size_mm.astype(np.float64), axis=-1)
    expected = pores["density_per_cm2"] * area[atlas.valid].sum() / 100.0
    depth = pore_depth(atlas, pores, texel_mm(atlas), np.random.default_rng(3))
    sigma = pores["diameter_mm"] / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    per_pore = pores["depth_mm"] * 2.0 * np.pi * sigma ** 2  # a Gaussian pit's volume, mm^3
    count = np.sum((depth * area)[atlas.valid]) / per_pore
    assert abs(count - expected) < 4.0 * np.sqrt(expected) + 0.03 * expected
    assert np.all(depth[~atlas.valid] == 0) and depth.min() >= 0
    none = pore_depth(atlas, {**pores, "density_per_cm2": 0.0}, texel_mm(atlas), np.random.default_rng(3))
    assert not none.any()


def test_the_face_wrinkles_sit_where_faces_have_them(atlases):
    atlas = atlases[128]
    wrinkles = face_wrinkle_paths(face_mesh(0))
    names = [w["name"] for w in wrinkles]
    assert sum(n.startswith("forehead") for n in names) == 3
    assert sum(n.startswith("crow's feet") for n in names) == 6
    assert sum(n.startswith("nasolabial") for n in names) == 2
    forehead = face_region_masks(128)["forehead"]
    T = 128
    for wrinkle in wrinkles:
        path = np.asarray(wrinkle["path_uv"])
        rows, cols = (path[:, 1] * T).astype(int), (path[:, 0] * T).astype(int)
        assert atlas.valid[rows, cols].all(), wrinkle["name"]
        middle = path[len(path) // 2]
        inside = forehead[int(middle[1] * T), int(middle[0] * T)]
        assert inside == wrinkle["name"].startswith("forehead"), wrinkle["name"]
    # forehead above the eyes, the eyes above the nasolabial folds (Mitsuba v grows downwards)
    v = {kind: np.mean([np.mean(np.asarray(w["path_uv"])[:, 1]) for w in wrinkles if w["name"].startswith(kind)])
         for kind in ("forehead", "crow", "nasolabial")}
    assert v["forehead"] < v["crow"] < v["nasolabial"]


def test_synth_says_what_is_below_the_texel(atlases):
    wrinkles = face_wrinkle_paths(face_mesh(0))
    coarse = unresolved_features(wrinkles, DEFAULT_PORES, texel_mm(atlases[64]))
    assert any("11 of 11 wrinkles" in note for note in coarse)
    assert any(note.startswith("pores") for note in coarse)
    fine = unresolved_features(wrinkles, DEFAULT_PORES, 0.5)
    assert not any("wrinkles" in note for note in fine) and any("pores" in note for note in fine)
    assert unresolved_features([], None, 2.0) == []


def test_the_relief_is_carved_last(atlases):
    """The other maps do not change with the relief; the displacement is deeper by it."""
    atlas = atlases[64]
    plain = truth_maps(atlas, TruthSettings(wrinkles=[], pores=None), np.random.default_rng(9))
    carved = truth_maps(atlas, TruthSettings(), np.random.default_rng(9), face_mesh(0))
    for name in plain:
        if name != "displacement":
            np.testing.assert_array_equal(plain[name], carved[name], err_msg=name)
    removed = (plain["displacement"] - carved["displacement"])[atlas.valid]
    sigma, sigma_eff = texel_sigma_mm(0.8, texel_mm(atlas))  # the default furrow, 3.6 mm texels
    assert removed.min() >= -1e-6 and removed.max() > 0.8 * 0.15 * sigma / sigma_eff
    # the sphere has no landmarks: "face" wrinkles are none there, pores still apply
    assert TruthSettings().wrinkle_list(None) == []


@pytest.mark.parametrize("settings, message", [
    ({"wrinkles": "forehead"}, "wrinkles must be"),
    ({"wrinkles": [{"path_uv": [[0.1, 0.1]], "depth_mm": 0.1, "width_mm": 1}]}, "path_uv"),
    ({"wrinkles": [{"path_uv": [[0.1, 0.1], [0.2, 1.5]], "depth_mm": 0.1, "width_mm": 1}]}, "path_uv"),
    ({"wrinkles": [{"path_uv": [[0.1, 0.1], [0.2, 0.2]], "depth_mm": -0.1, "width_mm": 1}]}, "depth_mm"),
    ({"wrinkles": [{"path_uv": [[0.1, 0.1], [0.2, 0.2]], "width_mm": 1}]}, "missing key 'depth_mm'"),
    ({"wrinkles": [{"path_uv": [[0.1, 0.1], [0.2, 0.2]], "depth_mm": 0.1, "width_mm": 1, "deep": 1}]},
     "unknown key"),
    ({"pores": {"density_per_cm2": 10, "diameter_mm": 0, "depth_mm": 0.1}}, "pores.diameter_mm"),
    ({"pores": {"density_per_cm2": 10, "depth_mm": 0.1}}, "missing key .diameter_mm."),
])
def test_bad_relief_settings_name_the_key(tmp_path, settings, message):
    import json

    path = tmp_path / "params.json"
    path.write_text(json.dumps(settings))
    with pytest.raises(ValueError, match=message) as caught:
        load_settings(path)
    assert str(path) in str(caught.value)
