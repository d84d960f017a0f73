"""The ``ppoint`` emitter: Mitsuba's ``point`` as reference, polarization state and frames."""

import numpy as np
import pytest

import mitsuba as mi

CAMERA = [0.0, 0.0, 500.0]


def scene_dict(emitter, bsdf, integrator="direct", polarized=True, resolution=32):
    integrator = {"type": integrator}
    if polarized:
        integrator = {"type": "stokes", "inner": integrator}
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "perspective", "fov": 14,
            "to_world": mi.ScalarTransform4f().look_at(origin=CAMERA, target=[0, 0, 0],
                                                       up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                     "rfilter": {"type": "box"}},
        },
        "light": emitter,
        "sphere": {"type": "sphere", "radius": 50.0, "bsdf": bsdf},
    }


def ppoint(**extra):
    return {"type": "ppoint", "position": [30.0, 40.0, 480.0], "intensity": 4e5, **extra}


def point():
    return {"type": "point", "position": [30.0, 40.0, 480.0], "intensity": 4e5}


def render(d, spp=4):
    return np.array(mi.render(mi.load_dict(d), spp=spp, seed=2))


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_unpolarized_variant_matches_mitsuba_point(variant):
    mi.set_variant(variant)
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.4, 0.3]}}
    ours = render(scene_dict(ppoint(), bsdf, "path", polarized=False, resolution=16))
    theirs = render(scene_dict(point(), bsdf, "path", polarized=False, resolution=16))
    assert theirs.max() > 0
    np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("integrator", ["direct", "path", "volpath"])
@pytest.mark.parametrize("variant", ["llvm_ad_mono_polarized", "llvm_ad_spectral_polarized"])
def test_intensity_matches_point_through_a_depolarizing_surface(variant, integrator):
    mi.set_variant(variant)
    bsdf = {"type": "diffuse"}
    ours = render(scene_dict(ppoint(), bsdf, integrator))
    theirs = render(scene_dict(point(), bsdf, integrator))
    # channels: RGB, then S0..S3 as RGB triplets; a Lambertian surface depolarizes
    np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-7)


def coaxial_stokes_image(axis, variant="llvm_ad_mono_polarized", **extra):
    mi.set_variant(variant)
    emitter = {"type": "ppoint", "position": CAMERA, "intensity": 4e5,
               "polarization_axis": axis, "polarizer_normal": [0, 0, -1], **extra}
    glossy = {"type": "pbssrdf", "eta": 1.5, "alpha_s": 0.3, "rho_ss": 0.0, "rho_sss": 0.0}
    image = render(scene_dict(emitter, glossy, resolution=24))
    return tuple(image[..., -12 + 3 * k + 1] for k in range(4))  # G of S0..S3 (the last 12)


@pytest.mark.parametrize("axis,expected", [
    ([1, 0, 0], (1, 0)),           # along image right: S1 = S0
    ([0, 1, 0], (-1, 0)),          # along image up: S1 = -S0
    ([1, 1, 0], (0, 1)),           # 45 degrees counter-clockwise: S2 = S0
    ([1, -1, 0], (0, -1)),         # 135 degrees: S2 = -S0
])
def test_polarization_axis_sets_the_image_frame_stokes(axis, expected):
    """A retro-reflecting mirror lobe returns the light's polarization to the camera.

    Mitsuba's `stokes` frame is x = d x up for every pixel ray d: a sheet
    polarizer along image x (absorbing along up) matches it exactly, other
    axes differ off the optical axis at second order in the field angle
    (3e-4 of S0 at the 5 degrees of this image's corners).
    """
    S0, S1, S2, S3 = coaxial_stokes_image(axis)
    lit = S0 > 1e-3 * S0.max()
    tolerance = (1e-6 if axis == [1, 0, 0] else 1e-3) * S0.max()
    np.testing.assert_allclose(S1[lit], expected[0] * S0[lit], atol=tolerance)
    np.testing.assert_allclose(S2[lit], expected[1] * S0[lit], atol=tolerance)
    assert np.abs(S3[lit]).max() <= 1e-6 * S0.max()


def test_spectral_and_scalar_variants_agree_with_mono():
    reference = coaxial_stokes_image([1, 1, 0])
    for variant in ["llvm_ad_spectral_polarized", "scalar_spectral_polarized"]:
        S0, S1, S2, _ = coaxial_stokes_image([1, 1, 0], variant)
        lit = reference[0] > 1e-2 * reference[0].max()
        # a white-spectrum light and grey material: the same image up to colour conversion
        np.testing.assert_allclose(S2[lit] / S0[lit], 1.0, atol=1e-3)


def test_projection_and_sheet_models_agree_on_the_optical_axis():
    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.plugins.ppoint import linear_polarization_stokes, polarization_direction

    def vec(v):
        return mi.Vector3f(*[float(x) for x in v])

    axis = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3)
    normal = np.array([0.0, 0.0, -1.0])
    d = vec(normal)
    projected = linear_polarization_stokes(d, polarization_direction(d, vec(axis)))
    sheet = linear_polarization_stokes(
        d, polarization_direction(d, vec(axis), vec(np.cross(normal, axis))))
    for a, b in zip(projected, sheet):
        assert float(a[0]) == pytest.approx(float(b[0]), abs=1e-6)
    # and off the axis they differ, as they should
    d = vec(np.array([0.3, 0.3, -1.0]) / np.linalg.norm([0.3, 0.3, -1.0]))
    projected = linear_polarization_stokes(d, polarization_direction(d, vec(axis)))
    sheet = linear_polarization_stokes(
        d, polarization_direction(d, vec(axis), vec(np.cross(normal, axis))))
    assert abs(float(projected[1][0]) - float(sheet[1][0])) > 1e-3


def test_parameters_are_exposed():
    mi.set_variant("llvm_ad_mono_polarized")
    params = mi.traverse(mi.load_dict(ppoint()))
    for key in ["position", "polarization_axis", "intensity.value"]:
        assert key in params.keys()


@pytest.mark.parametrize("extra,message", [
    (dict(polarization_axis=[0, 0, 0]), "polarization_axis"),
    (dict(polarization_axis=[0, 0, 1], polarizer_normal=[0, 0, -1]), "parallel"),
    (dict(intensity=-1.0), "intensity"),
    (dict(position=[0, float("nan"), 0]), "position"),
])
def test_bad_parameters_fail_at_load_time(extra, message):
    mi.set_variant("llvm_ad_mono_polarized")
    with pytest.raises(Exception, match=message):
        mi.load_dict(ppoint(**extra))
