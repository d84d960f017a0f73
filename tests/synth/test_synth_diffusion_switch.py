"""``SynthesisSettings.subsurface_diffusion``: off, each texel emits ``R_bar E / c(eta)``.

That is the polarimetric stages' per-texel subsurface model (``rho_sss E``).
The reference is computed independently of the switch's code path: the
layered exitance of eq. 46 with every layer profile a delta (no blur), which
is ``R_bar E`` with ``R_bar`` of eq. 47 from the layer totals, divided by
``c(eta)``. About 3 s (a 48^2 face atlas, two bands, one 32 px view).
"""

import dataclasses

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.render.subsurface import (
    LAYER_PROFILES,
    layered_exitance,
    subsurface_exit_fraction,
)
from polarbssrdf.spectral import default_bands
from polarbssrdf.synth import synthesize as synth
from polarbssrdf.synth.synthesize import (
    SynthesisSettings,
    capture_manifest,
    prepare_capture,
    prepare_frame,
    subsurface_exitances,
)

DELTA = {name: (np.array([1.0]), np.array([1e-10])) for name in LAYER_PROFILES}
"""Every layer profile a delta: eq. 46 without blur."""


@pytest.fixture(scope="module")
def face():
    mi.set_variant("llvm_ad_mono_polarized")
    import polarbssrdf

    polarbssrdf.register_plugins()
    settings = SynthesisSettings(object="face", views=1, resolution=32, texture=48, spp=1,
                                 subsurface_diffusion=False)
    prepared = prepare_capture(settings, default_bands()[:2])
    return prepared, prepare_frame(prepared, 0)


def step_irradiance(atlas):
    """A irradiance map with a sharp edge down the middle of the texture (W/mm^2)."""
    T = atlas.resolution
    irradiance = np.where(np.arange(T)[None, :] < T // 2, 1.0, 0.2) * np.ones((T, 1))
    return (irradiance * atlas.valid).astype(np.float32)


def test_without_diffusion_each_texel_emits_R_bar_E_over_c_eta(face):
    prepared, state = face
    irradiance = step_irradiance(state.atlas)
    c_eta = subsurface_exit_fraction(state.maps["eta"])
    valid = state.atlas.valid
    locals_ = subsurface_exitances(irradiance, state, prepared, diffusion=False)
    weights = prepared.quadrature.weights
    for band in range(len(prepared.bands)):
        local = locals_[band]
        # the band integral of the unblurred layered exitance over the quadrature's nodes
        R_bar_E = sum(weights[band, q] * layered_exitance(irradiance, state.layers[q], DELTA, state.atlas)
                      for q in range(weights.shape[1]) if weights[band, q] > 0)
        expected = R_bar_E / c_eta
        assert np.all(expected[valid & (irradiance > 0)] > 0)
        np.testing.assert_allclose(local[valid], expected[valid], rtol=2e-5, atol=1e-9)


def test_the_renderer_gets_the_per_texel_exitance_and_the_capture_records_it(face, monkeypatch):
    prepared, state = face
    seen = []
    monkeypatch.setattr(synth, "set_exitance", lambda scene, values: seen.append(values))
    camera = prepared.stage.cameras[0]
    irradiance = []
    original = synth.transmitted_irradiance
    monkeypatch.setattr(synth, "transmitted_irradiance",
                        lambda *a, **k: irradiance.append(original(*a, **k)) or irradiance[-1])
    synth.render_frame_view(prepared, state, camera)
    assert len(seen) == len(prepared.bands) and np.max(irradiance[0]) > 0
    for band, values in enumerate(seen):
        np.testing.assert_allclose(values, state.albedo[band] * irradiance[0], rtol=1e-6,
                                   atol=1e-12)
    assert capture_manifest(prepared).metadata["settings"]["subsurface_diffusion"] is False
    default = dataclasses.replace(prepared, settings=dataclasses.replace(
        prepared.settings, subsurface_diffusion=True))
    # on (the default) it is left out, so captures made before the switch existed resume
    assert "subsurface_diffusion" not in capture_manifest(default).metadata["settings"]
