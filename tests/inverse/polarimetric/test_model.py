"""The per-texel-view model reproduces what Mitsuba renders with ``pbssrdf`` and ``ppoint``.

The reference is an independent path: Mitsuba's ``stokes(direct)`` integrator
with the plugins, its own light sampling, Stokes frames and sensor frame. The
model is evaluated at the pixel-centre rays of the same camera. The whole
scene is turned by a generic rotation: with axis-aligned cameras and
polarizers the Stokes frames line up and frame errors cancel (an earlier
version of ``coordinate_system`` passed that way and was wrong for half the
normals).
"""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from polarbssrdf._arrays import to_jit

PARAMS = dict(eta=1.45, rho_s=0.8, alpha_s=0.35, rho_ss=0.3, alpha_ss=0.9)
RHO_SSS = 0.6
RESOLUTION = 64


def _rotation(x, y, z):
    cx, sx, cy, sy, cz, sz = np.cos(x), np.sin(x), np.cos(y), np.sin(y), np.cos(z), np.sin(z)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


ROTATION = _rotation(0.7, -0.4, 1.1)
CAMERA = ROTATION @ [0.0, 0.0, 400.0]
UP = ROTATION @ [0.0, 1.0, 0.0]
LIGHT = ROTATION @ [40.0, 0.0, 400.0]  # 5.7 degrees off the camera axis, along image x
POLARIZATION_AXIS = ROTATION @ [1.0, 0.0, 0.0]  # camera right: light polarized along image x
POLARIZER_NORMAL = ROTATION @ [0.0, 0.0, -1.0]  # the sheet faces along the camera axis


@pytest.fixture(scope="module")
def rendered_sphere():
    mi.set_variant("llvm_ad_mono_polarized")
    to_world = mi.ScalarTransform4f().look_at(origin=CAMERA.tolist(), target=[0, 0, 0],
                                              up=UP.tolist())
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "inner": {"type": "direct"}},
        "sensor": {"type": "perspective", "fov": 16, "to_world": to_world,
                   "sampler": {"type": "independent", "sample_count": 256},
                   "film": {"type": "hdrfilm", "width": RESOLUTION, "height": RESOLUTION,
                            "pixel_format": "luminance", "rfilter": {"type": "box"}}},
        "light": {"type": "ppoint", "position": LIGHT.tolist(), "intensity": 4e4,
                  "polarization_axis": POLARIZATION_AXIS.tolist(),
                  "polarizer_normal": POLARIZER_NORMAL.tolist()},
        "ball": {"type": "sphere", "radius": 50.0,
                 "bsdf": {"type": "pbssrdf", "rho_sss": RHO_SSS, **PARAMS}},
    })
    from polarbssrdf.render.view import render_analyser_images

    images, _ = render_analyser_images(scene, spp=256, seed=3)
    return scene, images


def _pixel_centre_geometry(scene):
    """Surface points, normals and per-ray frames of the pixel-centre rays."""
    sensor = scene.sensors()[0]
    rows, cols = np.meshgrid(np.arange(RESOLUTION), np.arange(RESOLUTION), indexing="ij")
    position = mi.Point2f(((cols.ravel() + 0.5) / RESOLUTION).astype(np.float32),
                          ((rows.ravel() + 0.5) / RESOLUTION).astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    hit = np.array(si.is_valid())
    p = np.array(si.p, dtype=np.float64).T
    n = np.array(si.sh_frame.n, dtype=np.float64).T
    ray_d = np.array(ray.d, dtype=np.float64).T
    return hit, p, n, ray_d


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_model_matches_mitsuba_render(rendered_sphere):
    from polarbssrdf.inverse.polarimetric.model import ViewGeometry, predict_stokes

    scene, images = rendered_sphere
    hit, p, n, ray_d = _pixel_centre_geometry(scene)
    to_camera = _unit(CAMERA - p)
    to_light_vec = LIGHT - p
    distance = np.linalg.norm(to_light_vec, axis=-1)
    to_light = to_light_vec / distance[:, None]
    # ppoint's dichroic sheet: absorption axis b = normal x axis, field = d x b
    absorption = np.cross(POLARIZER_NORMAL, POLARIZATION_AXIS)
    field = _unit(np.cross(-to_light, absorption))
    camera_basis = _unit(np.cross(ray_d, UP))  # stokes integrator: d x up
    # the fully lit part of the sphere, away from the silhouette
    keep = hit & (np.sum(n * to_camera, axis=-1) > 0.3)
    Float, Array3f = mi.Float, mi.Vector3f

    def vec(a):
        a = a[keep].astype(np.float32)
        return Array3f(*(to_jit(Float, a[:, i], np.float32) for i in range(3)))

    geometry = ViewGeometry(vec(to_camera), vec(to_light),
                            to_jit(Float, 4e4 / distance[keep] ** 2, np.float32), vec(field),
                            vec(camera_basis))
    stokes = predict_stokes(geometry, vec(n), *[to_jit(Float, np.full(keep.sum(), v), np.float32)
                                                for v in PARAMS.values()])
    predicted = [np.array(image) for image in stokes.analyser_images(RHO_SSS)]
    reference = [images[name].ravel()[keep] for name in ("I0", "I45", "I90", "I135")]
    mean_sss = np.mean(2 * reference[2])

    def separations(I0, I45, I90, I135):
        return {"I_sss": 2 * I90, "I_zeta": I135 - I45, "I_s": I0 - I90}

    ours, theirs = separations(*predicted), separations(*reference)
    rms = {k: np.sqrt(np.mean((ours[k] - theirs[k]) ** 2)) for k in ours}
    signal = {k: np.sqrt(np.mean(theirs[k] ** 2)) for k in theirs}
    # the polarization images are small but not trivially so: the test sees them
    assert signal["I_zeta"] > 0.01 * mean_sss and signal["I_s"] > 0.02 * mean_sss
    # pixel-centre prediction vs a pixel-area average: second-order differences only
    assert rms["I_sss"] < 5e-3 * mean_sss
    assert rms["I_zeta"] < 0.02 * signal["I_zeta"]
    assert rms["I_s"] < 0.02 * signal["I_s"]


def test_coaxial_approximation_differs_with_offset_light(rendered_sphere):
    """The authors' exactly-coaxial approximation is measurably off with a 5.7 degree offset."""
    from polarbssrdf.inverse.polarimetric.model import ViewGeometry, predict_stokes

    scene, images = rendered_sphere
    hit, p, n, ray_d = _pixel_centre_geometry(scene)
    keep = hit & (np.sum(n * _unit(CAMERA - p), axis=-1) > 0.3)
    Float, Array3f = mi.Float, mi.Vector3f

    def vec(a):
        a = a[keep].astype(np.float32)
        return Array3f(*(to_jit(Float, a[:, i], np.float32) for i in range(3)))

    to_light = LIGHT - p
    distance = np.linalg.norm(to_light, axis=-1)
    absorption = np.cross(POLARIZER_NORMAL, POLARIZATION_AXIS)
    geometry = ViewGeometry(vec(_unit(CAMERA - p)), vec(to_light / distance[:, None]),
                            to_jit(Float, 4e4 / distance[keep] ** 2, np.float32),
                            vec(_unit(np.cross(-to_light / distance[:, None], absorption))),
                            vec(_unit(np.cross(ray_d, UP))))
    args = [vec(n)] + [to_jit(Float, np.full(keep.sum(), v), np.float32) for v in PARAMS.values()]
    exact = np.array(predict_stokes(geometry, *args).analyser_images(RHO_SSS)[0])
    coaxial = np.array(predict_stokes(geometry, *args, coaxial=True).analyser_images(RHO_SSS)[0])
    reference = images["I0"].ravel()[keep]
    error_exact = np.abs(exact - reference).mean()
    error_coaxial = np.abs(coaxial - reference).mean()
    assert error_coaxial > 3 * error_exact


def test_model_is_differentiable_in_every_parameter():
    """Gradients of a predicted image reach every parameter and the normal, and match central differences."""
    from polarbssrdf.inverse.polarimetric.model import ViewGeometry, predict_stokes

    mi.set_variant("llvm_ad_mono_polarized")
    Float, Array3f = mi.Float, mi.Vector3f
    rng = np.random.default_rng(4)
    count = 32
    normal = _unit(rng.normal(size=(count, 3)) * [0.3, 0.3, 0.0] + [0, 0, 1])
    to_camera = _unit(rng.normal(size=(count, 3)) * [0.4, 0.4, 0.0] + [0, 0, 1])
    to_light = _unit(to_camera + [0.1, 0.0, 0.0])
    field = _unit(np.cross(to_light, [0.0, 1.0, 0.0]))
    basis = _unit(np.cross(-to_camera, [0.0, 1.0, 0.0]))

    def vec(a):
        a = a.astype(np.float64)
        return Array3f(*(to_jit(Float, a[:, i], np.float32) for i in range(3)))

    geometry = ViewGeometry(vec(to_camera), vec(to_light), to_jit(Float, np.ones(count), np.float32), vec(field),
                            vec(basis))
    base = dict(PARAMS)
    weights = rng.uniform(0.5, 1.5, size=(4, count))

    def objective(values):
        params = {k: to_jit(Float, np.full(count, v), np.float32) for k, v in values.items()}
        for value in params.values():
            dr.enable_grad(value)
        images = predict_stokes(geometry, vec(normal), **params).analyser_images(0.5)
        total = sum(dr.sum(to_jit(Float, w, np.float32) * image) for w, image in zip(weights, images))
        return total, params

    total, params = objective(base)
    dr.backward(total)
    for name in PARAMS:
        analytic = float(dr.sum(params[name].grad)[0])
        step = 1e-4
        plus = float(objective({**base, name: base[name] + step})[0][0])
        minus = float(objective({**base, name: base[name] - step})[0][0])
        numeric = (plus - minus) / (2 * step)
        assert analytic == pytest.approx(numeric, rel=1e-2, abs=1e-3 * abs(float(total[0]))), name
