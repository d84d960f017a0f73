"""Rendered coaxial images of the sphere scene: polarization sanity, gradients, recovery."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.optics import diffuse_degree_of_polarization, polarization_images

SCENE = "scenes/sphere.xml"


@pytest.fixture(autouse=True)
def variant(request):
    mi.set_variant("llvm_ad_mono_polarized")


def stokes_channels(image):
    """S0..S3 from a mono `stokes` render (channels Y, S0.RGB, S1.RGB, S2.RGB, S3.RGB)."""
    image = np.asarray(image)
    return tuple(image[..., 1 + 3 * k] for k in range(4))


def pixel_zenith_cosines(scene):
    """cos(theta) between normal and view direction through each pixel centre (NaN off the sphere)."""
    sensor = scene.sensors()[0]
    width, height = sensor.film().crop_size()
    y, x = np.mgrid[0:height, 0:width]
    uv = mi.Point2f(((x + 0.5) / width).ravel(), ((y + 0.5) / height).ravel())
    rays, _ = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5))
    si = scene.ray_intersect(rays)
    cos_theta = np.array(dr.dot(si.n, -rays.d))
    cos_theta[~np.array(si.is_valid())] = np.nan
    return cos_theta.reshape(height, width)


def render(scene, spp=16, seed=0):
    return stokes_channels(mi.render(scene, spp=spp, seed=seed))


def test_coaxial_glossy_lobes_are_not_cross_polarized():
    scene = mi.load_file(SCENE, resolution=96, rho_sss=0.0, rho_ss=0.4)
    I0, I45, I90, I135 = polarization_images(render(scene))
    lit = I0 > 1e-4 * I0.max()
    assert lit.sum() > 1000
    assert np.abs(I90[lit]).max() < 1e-5 * I0[lit].max()
    assert np.all(np.abs(I90[lit]) < 1e-5 * I0[lit] + 1e-12)


def test_subsurface_degree_of_polarization_is_atkinson_hancock():
    eta = 1.45
    scene = mi.load_file(SCENE, resolution=192, rho_s=0.0, rho_ss=0.0, eta=eta)
    S0, S1, S2, _ = render(scene, spp=64)
    cos_theta = pixel_zenith_cosines(scene)
    # away from the centre (DoP ~ 0) and the silhouette (theta varies fast within a pixel)
    theta = np.arccos(np.clip(cos_theta, 0, 1))
    usable = np.isfinite(cos_theta) & (theta > np.deg2rad(20)) & (theta < np.deg2rad(70))
    assert usable.sum() > 2000
    dop = np.hypot(S1, S2)[usable] / S0[usable]
    expected = diffuse_degree_of_polarization(eta, theta[usable])
    assert np.abs(dop / expected - 1).max() < 0.02


@pytest.mark.parametrize("key,step", [("eta.value", 1e-2), ("alpha_s.value", 1e-2)])
def test_gradients_match_finite_differences(key, step):
    """d(sum w * image)/d(param) through stokes(direct) vs central differences.

    mi.render's gradient pass draws its pixel samples with ``seed_grad``; the
    finite differences render with that seed, so both see the same samples.
    """
    scene = mi.load_file(SCENE, resolution=48, spp=4)
    params = mi.traverse(scene)
    key = [k for k in params.keys() if k.endswith(key)][0]
    x0 = float(params[key][0])
    weights = mi.TensorXf(np.random.default_rng(1).uniform(size=(48, 48, 13)).astype(np.float32))

    def objective(seed=3, seed_grad=5):
        image = mi.render(scene, params, spp=4, seed=seed, seed_grad=seed_grad)
        return dr.sum(image * weights, axis=None)

    dr.enable_grad(params[key])
    params.update()
    value = objective()
    dr.backward(value)
    gradient = float(dr.grad(params[key])[0])
    dr.disable_grad(params[key])

    def at(x):
        params[key] = mi.Float(x)
        params.update()
        return float(objective(seed=5, seed_grad=6).array[0])

    finite = (at(x0 + step) - at(x0 - step)) / (2 * step)
    params[key] = mi.Float(x0)
    params.update()
    assert gradient == pytest.approx(finite, rel=0.01)


@pytest.fixture(scope="module")
def recovery_reference():
    mi.set_variant("llvm_ad_mono_polarized")
    return mi.render(mi.load_file(SCENE, resolution=64, eta=1.45, alpha_s=0.30), spp=64, seed=1)


@pytest.mark.parametrize("start", [dict(eta=1.33, alpha_s=0.45), dict(eta=1.6, alpha_s=0.15),
                                   dict(eta=1.3, alpha_s=0.2), dict(eta=1.55, alpha_s=0.5)])
def test_optimization_recovers_eta_and_specular_roughness(recovery_reference, start):
    """30 Adam iterations on the S0, S1, S2 images recover eta = 1.45, alpha_s = 0.30.

    Each Stokes image's squared error is normalized by its energy, so the weak
    polarization signals (which pin eta) weigh as much as the intensity.
    """
    truth = dict(eta=1.45, alpha_s=0.30)
    reference = recovery_reference
    channels = (1, 4, 7)  # S0, S1, S2
    energy = {c: dr.mean(dr.square(reference[..., c]), axis=None) for c in channels}
    scene = mi.load_file(SCENE, resolution=64, **start)
    params = mi.traverse(scene)
    keys = {name: [k for k in params.keys() if k.endswith(f"{name}.value")][0] for name in truth}
    learning_rate = 0.06
    optimizer = mi.ad.Adam(lr=learning_rate, beta_1=0.6)
    for key in keys.values():
        optimizer[key] = params[key]
    params.update(optimizer)
    iterations = 30
    for iteration in range(iterations):
        optimizer.set_learning_rate(learning_rate * 0.1 ** (iteration / (iterations - 1)))
        image = mi.render(scene, params, spp=8, seed=iteration)
        loss = sum(dr.mean(dr.square(image[..., c] - reference[..., c]), axis=None) / energy[c]
                   for c in channels)
        dr.backward(loss)
        optimizer.step()
        optimizer[keys["eta"]] = dr.clip(optimizer[keys["eta"]], 1.05, 2.5)
        optimizer[keys["alpha_s"]] = dr.clip(optimizer[keys["alpha_s"]], 0.02, 1.0)
        params.update(optimizer)
    for name, key in keys.items():
        assert float(params[key][0]) == pytest.approx(truth[name], abs=0.01), name
