"""The separations of eq. 22-24 recover the rendered components of a coaxial capture."""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.optics import polarization_images, separate_observations

CAMERA = [0.0, 0.0, 500.0]
SKIN = dict(eta=1.42, rho_s=0.9, alpha_s=0.35, rho_ss=0.3, alpha_ss=0.9, rho_sss=0.6)


def render(light, **bsdf):
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "inner": {"type": "direct"}},
        "sensor": {"type": "perspective", "fov": 14,
                   "to_world": mi.ScalarTransform4f().look_at(origin=CAMERA, target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 96, "height": 96,
                            "rfilter": {"type": "box"}}},
        "light": light,
        "sphere": {"type": "sphere", "radius": 50.0, "bsdf": {"type": "pbssrdf", **bsdf}},
    })
    image = np.array(mi.render(scene, spp=16, seed=5), dtype=np.float64)
    return tuple(image[..., 1 + 3 * k] for k in range(4))  # S0..S3


@pytest.fixture(scope="module")
def renders():
    mi.set_variant("llvm_ad_mono_polarized")
    polarized = {"type": "ppoint", "position": CAMERA, "intensity": 5e5,
                 "polarization_axis": [1, 0, 0], "polarizer_normal": [0, 0, -1]}
    unpolarized = {"type": "point", "position": CAMERA, "intensity": 5e5}
    full = render(polarized, **SKIN)
    glossy = render(polarized, **dict(SKIN, rho_sss=0.0))
    subsurface_unpolarized = render(unpolarized, **dict(SKIN, rho_s=0.0, rho_ss=0.0))
    return full, glossy, subsurface_unpolarized


def test_separations_recover_the_components(renders):
    """I_sss = subsurface under unpolarized light (eq. 22); I_s = glossy - oriented subsurface (eq. 24).

    The separations neglect the T- T- terms (eq. 19), which are the square of
    the diffuse degree of polarization (< 0.8% of S0 below 60 degrees
    zenith); lit pixels are those where the subsurface light is above half its
    peak (zenith angles below about 60 degrees).
    """
    full, glossy, subsurface = renders
    I_sss, I_zeta, I_s = separate_observations(*polarization_images(full))
    lit = subsurface[0] > 0.5 * subsurface[0].max()
    assert lit.sum() > 1500
    scale = full[0][lit]
    # eq. 22: the cross-polarized image is the depolarized subsurface light
    assert np.abs(I_sss - subsurface[0])[lit].max() < 0.01 * scale.max()
    assert np.all(np.abs(I_sss - subsurface[0])[lit] < 0.01 * scale)
    # eq. 24: specular + single scattering, minus the oriented subsurface term
    # (the S1 of subsurface light under unpolarized light is -rho T- T+ xi)
    expected_I_s = glossy[0] + subsurface[1]
    assert np.all(np.abs(I_s - expected_I_s)[lit] < 0.01 * scale)
    # eq. 23: I_zeta is the subsurface light's diagonal polarization, -S2
    assert np.all(np.abs(I_zeta + subsurface[2])[lit] < 0.01 * scale)
    # and the glossy light is all in I_s: none of it is cross-polarized
    assert np.abs(glossy[0] - glossy[1])[lit].max() < 1e-5 * glossy[0].max()
