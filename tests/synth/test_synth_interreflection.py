"""Interreflection in synthetic views: off by default, so images follow the per-texel model.

With the same seed the camera rays are the same, so without interreflection
a view is exactly (up to float rounding) the sum of its glossy part (the
lobes lit by the point light) and its subsurface glow seen directly, which
is what the per-texel model predicts. With interreflection the glossy lobes
also reflect other texels' glow: in the face's concave regions, not on a
sphere.
"""

import dataclasses

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.render.subsurface import layered_exitance, transmitted_irradiance
from polarbssrdf.render.view import render_analyser_images, view_scene
from polarbssrdf.spectral import default_bands
from polarbssrdf.synth.synthesize import (
    SynthesisSettings,
    capture_manifest,
    prepare_capture,
    prepare_frame,
    render_frame_view,
)

SPP = 8
ROUNDING = 1e-5  # of the glow's maximum


def view_parts(name):
    """Renderer of camera 0 of a small ``name`` capture, its maps and the band-0 exitance."""
    mi.set_variant("llvm_ad_mono_polarized")
    settings = SynthesisSettings(object=name, views=1, resolution=64, texture=64, spp=SPP)
    prepared = prepare_capture(settings, default_bands()[:1])
    state = prepare_frame(prepared, 0)
    camera = prepared.stage.cameras[0]
    light = prepared.stage.light(prepared.stage.light_for_camera[camera.name])

    def render(maps, exitance, interreflection):
        scene = view_scene(state.mesh, camera, light, maps, exitance, SPP, 0,
                           interreflection=interreflection)
        return render_analyser_images(scene, SPP, seed=5)[0], scene

    zero = np.zeros_like(state.maps["eta"])
    _, scene = render(state.maps, zero, False)
    irradiance = transmitted_irradiance(scene, state.atlas, state.maps["eta"])
    exitance = layered_exitance(irradiance, state.layers[0], prepared.kernels[0], state.atlas)
    return render, state.maps, exitance, (prepared, state)


@pytest.fixture(scope="module")
def face():
    return view_parts("face")


def interreflected(render, maps, exitance, interreflection):
    """``(residual, glow)`` per analyser: the view minus its glossy part and its direct glow."""
    zero = np.zeros_like(maps["eta"])
    dull = dict(maps, rho_s=zero, rho_ss=zero)  # no glossy lobes: the glow seen directly
    full, _ = render(maps, exitance, interreflection)
    glossy, _ = render(maps, zero, interreflection)
    glow, _ = render(dull, exitance, interreflection)
    return {a: full[a] - glossy[a] - glow[a] for a in ("I0", "I90")}, glow


def test_without_interreflection_a_face_view_is_glossy_plus_direct_glow(face):
    render, maps, exitance, _ = face
    residual, glow = interreflected(render, maps, exitance, interreflection=False)
    for analyser in ("I0", "I90"):
        assert np.abs(residual[analyser]).max() < ROUNDING * glow[analyser].max()


def test_with_interreflection_glossy_lobes_reflect_the_glow_in_concave_regions(face):
    render, maps, exitance, _ = face
    residual, glow = interreflected(render, maps, exitance, interreflection=True)
    lit = glow["I90"] > 0.05 * glow["I90"].max()
    share = residual["I90"][lit] / glow["I90"][lit]
    assert share.max() > 0.1  # eye sockets, beside the nose
    assert np.median(share) < 0.01  # most of the face sees no other texel
    assert residual["I90"].min() > -ROUNDING * glow["I90"].max()  # it only adds light


def test_a_sphere_has_no_interreflection():
    render, maps, exitance, _ = view_parts("sphere")
    on, _ = render(maps, exitance, True)
    off, _ = render(maps, exitance, False)
    for analyser in ("I0", "I90"):
        np.testing.assert_allclose(on[analyser], off[analyser], rtol=0,
                                   atol=ROUNDING * off[analyser].max())


def test_synth_leaves_interreflection_off_and_records_the_choice(face):
    _, _, _, (prepared, state) = face
    assert prepared.settings.interreflection is False
    assert capture_manifest(prepared).metadata["settings"]["interreflection"] is False
    camera = prepared.stage.cameras[0]
    off = render_frame_view(prepared, state, camera)
    with_it = dataclasses.replace(prepared, settings=dataclasses.replace(
        prepared.settings, interreflection=True))
    on = render_frame_view(with_it, state, camera)
    name = f"{prepared.bands[0].name}.I90"
    assert (on[name] - off[name]).max() > 0.05 * off[name].max()
    assert capture_manifest(with_it).metadata["settings"]["interreflection"] is True
