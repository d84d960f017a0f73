"""The face-level start of the polarimetric fit (face_level.fit_face_levels): from the far
constant start it fits the views as well as the truth's means do, and when a fit runs it."""

import mitsuba as mi
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from synthetic_texel_views import InMemoryStore, sphere_views

from polarbssrdf.inverse.config import static_config
from polarbssrdf.inverse.polarimetric.face_level import (
    face_level_system,
    fit_face_levels,
    set_constant_maps,
    solve_albedos,
)
from polarbssrdf.inverse.polarimetric.fit import initial_parameters, run_polarimetric_fit
from polarbssrdf.inverse.polarimetric.model import GLOSSY_PARAMETERS
from polarbssrdf.inverse.polarimetric.optimize import MapParameters, active_weights
from polarbssrdf.inverse.polarimetric.patches import PatchCache, texture_patches

T = 24

TRUE_LEVELS = {"eta": 1.455, "rho_s": 0.74, "alpha_s": 0.50, "rho_ss": 0.27, "alpha_ss": 0.90}
"""Face means off the config's start (1.4, 0.5, 0.35, 0.2, 1.0)."""

SPREADS = {"eta": 0.015, "rho_s": 0.06, "alpha_s": 0.03, "rho_ss": 0.03, "alpha_ss": 0.015}

ETA_TOLERANCE = 0.006
"""A ninth of the start's distance from the truth: the polarization measures the index."""


@pytest.fixture(scope="module")
def sphere():
    """A 12-view sphere with varying maps about :data:`TRUE_LEVELS` (its own seed), 1% noise."""
    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import texel_atlas, to_mitsuba, uv_sphere

    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=36, segments=72)), T)
    rng = np.random.default_rng(3101)

    def field(mean, std, scale=2.0):
        values = gaussian_filter(rng.standard_normal((T, T)), scale, mode="wrap")
        return (mean + std * values / values.std()).astype(np.float32)

    truth = {name: field(TRUE_LEVELS[name], SPREADS[name]) for name in GLOSSY_PARAMETERS}
    truth["alpha_ss"] = np.clip(truth["alpha_ss"], 0.7, 1.0)
    truth["normal"] = atlas.normal
    rho_sss = np.stack([field(0.45, 0.05), field(0.65, 0.05)])
    views = sphere_views(atlas, truth, rho_sss, n_cameras=12, noise=0.01, seed=3101)
    store = InMemoryStore(views, T, ("b0", "b1"), block_size=8)
    seen = np.zeros(T * T, bool)
    seen[views.texel] = True
    return store, atlas, truth, seen.reshape(T, T) & atlas.valid


def _start(store, atlas, config):
    maps, rho_sss = initial_parameters(config, T, len(store.bands))
    return MapParameters(maps, rho_sss, config.learning_rates)


def _chi_square_at(store, atlas, config, levels):
    params = _start(store, atlas, config)
    set_constant_maps(params, levels)
    cache = PatchCache(store, atlas)
    patches = texture_patches(T, config.patch_size, store.block_size)
    solve_albedos(params, cache, patches, config)
    return face_level_system(params, cache, patches, config, active_weights(config),
                             config.photometric_noise, GLOSSY_PARAMETERS, atlas.valid)[0]


def test_the_face_levels_fit_the_views_as_well_as_the_truths_means(sphere):
    """From the config's far start, Levenberg-Marquardt reaches constants that explain the views
    at least as well as the truth's own face means, and the index at its mean. (The lobes'
    split of the constants is not the truth's means: on 12 ring views a constant fits the
    varying lobes best with a broader, stronger specular lobe, and the per-texel epochs take
    it from there.)"""
    store, atlas, truth, seen = sphere
    config = static_config(patch_size=16)
    params = _start(store, atlas, config)
    patches = texture_patches(T, config.patch_size, store.block_size)
    record = fit_face_levels(params, PatchCache(store, atlas), patches, config,
                             active_weights(config), GLOSSY_PARAMETERS, atlas.valid, 12)
    assert record["evaluations"] <= 12
    assert np.all(np.diff(record["chi_square"]) < 0)
    means = {name: float(np.mean(truth[name][seen])) for name in GLOSSY_PARAMETERS}
    assert record["chi_square"][0] > 2.0 * _chi_square_at(store, atlas, config, means)
    assert record["chi_square"][-1] <= _chi_square_at(store, atlas, config, means)
    maps = params.to_numpy()
    for name in GLOSSY_PARAMETERS:
        assert np.ptp(maps[name]) == 0.0, name  # one value for the face
        assert float(maps[name].flat[0]) == pytest.approx(record["values"][name], abs=1e-6)
    assert record["values"]["eta"] == pytest.approx(means["eta"], abs=ETA_TOLERANCE)
    # rho_sss solved for the final levels, not left at the start's
    assert _chi_square_at(store, atlas, config, record["values"]) == pytest.approx(
        record["chi_square"][-1], rel=1e-4)


def test_a_fit_asked_for_it_starts_at_the_face_levels_unless_handed_its_start(sphere):
    store, atlas, _, _ = sphere
    config = static_config(patch_size=16, iterations=1, face_level_evaluations=12)
    fitted = run_polarimetric_fit(store, atlas, config, progress=False)
    assert set(fitted.face_levels["values"]) == set(GLOSSY_PARAMETERS)
    default = run_polarimetric_fit(store, atlas, static_config(patch_size=16, iterations=1),
                                   progress=False)
    assert default.face_levels is None  # off by default (config.py says why)
    handed = run_polarimetric_fit(store, atlas, config, progress=False,
                                  params=_start(store, atlas, config))
    assert handed.face_levels is None
    partly = run_polarimetric_fit(store, atlas, config, progress=False,
                                  start={"eta": np.full((T, T), 1.45, np.float32)})
    assert "eta" not in partly.face_levels["values"]


@pytest.mark.parametrize("value", [-1, 1, 2.5, "12"])
def test_the_evaluations_must_be_off_or_a_count_of_passes(value):
    with pytest.raises(ValueError, match="face_level_evaluations"):
        static_config(face_level_evaluations=value)
