"""The face's oxygenation from the albedo's band shape (inverse/biophysical/oxygenation.py).

Faces the estimate was not made from: a truth seed of their own, oxygenation 0.66 (more than
one hyperprior std below the population's 0.75 the search starts at) with 0.02 of spread in
the face, an epidermis 0.02 mm thicker than the model holds, twice the default chromophore
spread, the index off the truth by a smooth field of the static stage's typical error, the
band integral a camera records, 1% white noise or none. The estimate must sit within two of
its own std of the face's mean oxygenation, know it at least twice as well as the hyperprior,
and miss it by at most half of what holding the population's value would.
"""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.spectral import default_bands

TRUE_GAMMA = 0.66
THICKNESS_OFF_MM = 0.02


def face(noise, seed):
    """``(atlas, rbar, eta_input, truth)`` of a 64^2 face (module docstring)."""
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.render.subsurface import subsurface_exit_fraction
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import DEFAULT_BIOPHYSICAL_STD, smooth_field, table2_offset_settings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), 64)
    layers = {"thickness_mm": (0.25 + THICKNESS_OFF_MM, 0.01, 0.10, 0.40), "gamma": (TRUE_GAMMA, 0.02, 0.50, 0.95)}
    spread = {k: 2 * v for k, v in DEFAULT_BIOPHYSICAL_STD.items()}
    settings = table2_offset_settings(("cheek", "III"), 1.0, spread="rows", skin_layers=layers,
                                      biophysical_std=spread)
    rng = np.random.default_rng(seed)
    truth = truth_maps(atlas, settings, rng)
    bands = default_bands()
    albedo = subsurface_albedo(truth, bands).astype(np.float64)
    albedo *= 1.0 + noise * rng.standard_normal(albedo.shape)
    eta = truth["eta"] + 0.013 * smooth_field(atlas.valid.shape, 5.0 / float(np.median(atlas.texel_size_mm[atlas.valid])), rng)
    rbar = albedo * subsurface_exit_fraction(eta)[None]
    return atlas, bands, rbar, eta.astype(np.float64), truth


@pytest.mark.parametrize("noise, seed", [(0.01, 3301), (0.0, 3302)])
def test_the_face_oxygenation_is_found_within_its_std(noise, seed):
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
    from polarbssrdf.inverse.biophysical.oxygenation import face_oxygenation

    atlas, bands, rbar, eta, truth = face(noise, seed)
    config = BiophysicalConfig()
    estimate = face_oxygenation(rbar, atlas.valid, atlas, bands, eta, config, config.thickness_mm)
    true = float(np.mean(truth["gamma"][atlas.valid]))
    error = estimate.gamma - true
    assert abs(error) <= 2.0 * estimate.std, (estimate, true)
    assert estimate.std <= 0.5 * config.nuisance_mean["gamma"][1]
    assert abs(error) <= 0.5 * abs(config.nuisance_mean["gamma"][0] - true)
    # the std carries the held thickness's share (the shift per mm is the linearized model's)
    assert estimate.thickness_std == pytest.approx(abs(estimate.thickness_shift_per_mm) * 0.05, rel=1e-9)


def test_the_parabola_vertex_of_a_quadratic_is_exact():
    from polarbssrdf.inverse.biophysical.oxygenation import parabola_vertex

    x = (0.62, 0.70, 0.73)
    y = [3.0 * (v - 0.6812) ** 2 + 0.4 for v in x]
    vertex, curvature = parabola_vertex(x, y)
    assert vertex == pytest.approx(0.6812, abs=1e-12) and curvature == pytest.approx(6.0, rel=1e-9)
    assert np.isnan(parabola_vertex(x, [-v for v in y])[0])


def test_the_fit_renders_at_the_estimated_oxygenation_and_holds_it_when_asked(monkeypatch):
    """The stage uses the estimate for its model and its std (the hyperprior's place), and a
    config with ``oxygenation: "held"`` never estimates."""
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.inverse.biophysical import fit as fit_module
    from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
    from polarbssrdf.inverse.biophysical.oxygenation import OxygenationEstimate
    from polarbssrdf.synth.synthesize import object_mesh

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(object_mesh("sphere")), 16)
    bands = default_bands()
    inputs = {f"rho_sss.{b.name}": np.full(atlas.valid.shape, value) for b, value in
              zip(bands, (0.30, 0.32, 0.38, 0.40, 0.55, 0.58))}
    calls = []

    def fake(*args):
        calls.append(args)
        return OxygenationEstimate(0.6123, 0.0111, 0.61, 0.001, 0.011, -0.2, [])

    monkeypatch.setattr(fit_module, "face_oxygenation", fake)
    quick = {"rounds": 1, "iterations": 1, "prior": "none"}
    result = fit_module.fit_biophysical(inputs, bands, atlas, BiophysicalConfig(**quick))
    assert len(calls) == 1
    face = result.noise["face"]
    assert face["gamma"] == 0.6123 and face["gamma_variance"] == pytest.approx(0.0111 ** 2)
    assert face["oxygenation"]["profile_gamma"] == 0.61
    held = fit_module.fit_biophysical(inputs, bands, atlas, BiophysicalConfig(oxygenation="held", gamma=0.7, **quick))
    assert len(calls) == 1 and held.noise["face"]["gamma"] == 0.7
    with pytest.raises(ValueError, match="oxygenation"):
        BiophysicalConfig(oxygenation="estimate")


def test_block_minima_are_each_blocks_own_and_their_mean_is_not_curvature_weighted():
    """Blocks whose residuals are parabolas of their own minimum and curvature (blood): each
    block's minimum comes back, and their texel-weighted mean is the blocks' mean oxygenation,
    where the summed residual's minimum leans to the high-curvature blocks."""
    import types

    from polarbssrdf.inverse.biophysical.oxygenation import block_minima, jackknife_std, parabola_vertex

    rng = np.random.default_rng(11)
    n = 40
    minima = 0.70 + 0.03 * rng.standard_normal(n)
    curvature = np.where(minima > 0.70, 10.0, 1.0)  # the more oxygenated blocks hold more blood
    weight = rng.uniform(0.5, 1.0, n)
    ok = np.ones(n + 3, bool)
    ok[[5, 17, 30]] = False  # blocks without data are not in the per-block arrays
    blocks = {}
    for gamma in (0.60, 0.65, 0.675, 0.70, 0.725, 0.75, 0.80):
        blocks[gamma] = (None, ok, weight, weight * curvature * (gamma - minima) ** 2 + 0.1)
    found, found_weight = block_minima(types.SimpleNamespace(blocks=blocks))
    assert np.all((minima > 0.60) & (minima < 0.80))  # every block's minimum is bracketed
    np.testing.assert_allclose(found, minima, atol=1e-12)
    np.testing.assert_array_equal(found_weight, weight)
    mean = np.sum(weight * minima) / np.sum(weight)
    xs = (0.675, 0.70, 0.725)
    summed, _ = parabola_vertex(xs, [float(np.sum(blocks[g][3])) for g in xs])
    assert abs(np.sum(weight * found) / np.sum(weight) - mean) < 0.1 * abs(summed - mean)
    assert np.isfinite(jackknife_std(found, weight)) and np.isnan(jackknife_std(found[:3], weight[:3]))
