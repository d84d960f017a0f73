"""The ``pbssrdf`` BSDF plugin: reference comparisons, sampling, energy, gradients, errors."""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from helpers import mueller_to_numpy

# Mitsuba's EXR reader and writer (mi.Bitmap) hang with one Dr.Jit thread (tests/conftest.py)
pytestmark = pytest.mark.all_cores

POLARIZED_VARIANTS = ["llvm_ad_mono_polarized", "llvm_ad_spectral_polarized"]


def pbssrdf(**params):
    return mi.load_dict({"type": "pbssrdf", **params})


def interaction(wi):
    """A surface interaction in the local frame (normal +z) with directions ``wi`` (n x 3)."""
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(wi.T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Normal3f(0, 0, 1)
    if mi.is_spectral:
        si.wavelengths = dr.full(mi.UnpolarizedSpectrum, 550.0, len(wi))
    return si


@pytest.mark.parametrize("variant", POLARIZED_VARIANTS)
@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
@pytest.mark.parametrize("eta,alpha,albedo", [(1.5, 0.3, 0.5), (1.33, 0.08, 0.8),
                                              (1.8, 0.9, 0.2)])
def test_matches_pplastic(variant, mode, eta, alpha, albedo, hemisphere):
    """Specular + subsurface lobes (rho_ss = 0) equal Mitsuba's C++ pplastic (Baek 2018).

    Directions closer than 0.05 in cosine to the horizon are left out: there
    pplastic's float32 tan^2 = (x^2 + y^2) / z^2 loses digits (checked against a
    float64 evaluation: ours stays correct). The exactly collinear set is
    excluded too: pplastic's fallback frame is wrong there (tested separately).
    """
    mi.set_variant(variant)
    n = 12000
    wi, wo = hemisphere(n, min_cos=0.05), hemisphere(n, min_cos=0.05)
    keep = np.linalg.norm(wi - wo, axis=1) > 1e-3
    wi, wo = wi[keep], wo[keep]
    assert len(wi) >= 10000
    ours = pbssrdf(eta=eta, alpha_s=alpha, rho_s=1.0, rho_ss=0.0, rho_sss=albedo)
    reference = mi.load_dict({"type": "pplastic", "distribution": "ggx", "alpha": alpha,
                              "int_ior": eta, "ext_ior": 1.0,
                              "diffuse_reflectance": {"type": "uniform", "value": albedo}})
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    si = interaction(wi)
    A = mueller_to_numpy(ours.eval(ctx, si, mi.Vector3f(wo.T)))
    B = mueller_to_numpy(reference.eval(ctx, si, mi.Vector3f(wo.T)))
    scale = np.abs(B).max(axis=(0, 1))
    error = np.abs(A - B).max(axis=(0, 1)) / scale
    assert np.all(scale > 0)
    assert error.max() < 1e-4, f"worst relative error {error.max():.2e}"


@pytest.mark.parametrize("variant", POLARIZED_VARIANTS)
def test_exact_retroreflection_has_no_cross_polarized_specular(variant, hemisphere, rng):
    """wi == wo bit for bit: light polarized along any axis comes back along it."""
    mi.set_variant(variant)
    v = hemisphere(2000, min_cos=0.05)
    bsdf = pbssrdf(eta=1.45, alpha_s=0.4, rho_ss=0.5, rho_sss=0.0)
    M = bsdf.eval(mi.BSDFContext(), interaction(v), mi.Vector3f(v.T))
    # any axis perpendicular to v, expressed in the in/out Stokes bases
    e = np.cross(v, rng.normal(size=v.shape))
    e = mi.Vector3f((e / np.linalg.norm(e, axis=1, keepdims=True)).T)
    d = mi.Vector3f(v.T)
    to_in = mi.mueller.rotate_stokes_basis(-d, e, mi.mueller.stokes_basis(-d))
    from_out = mi.mueller.rotate_stokes_basis(d, mi.mueller.stokes_basis(d), e)
    X = mueller_to_numpy(mi.Spectrum(from_out) * M * mi.Spectrum(to_in))
    stokes = X[:, 0] + X[:, 1]  # X applied to [1, 1, 0, 0], polarized along e
    S0, S1, S2 = stokes[0], stokes[1], stokes[2]
    assert np.abs(S0 - S1).max() <= 1e-6 * np.abs(S0).max()  # I90 = (S0 - S1) / 2
    assert np.abs(S2).max() <= 1e-6 * np.abs(S0).max()


def test_reciprocity_of_intensity(hemisphere):
    mi.set_variant("llvm_ad_mono_polarized")
    wi, wo = hemisphere(5000, 0.02), hemisphere(5000, 0.02)
    bsdf = pbssrdf(eta=1.4, alpha_s=0.35, rho_ss=0.4, alpha_ss=0.8, rho_sss=0.6)
    ctx = mi.BSDFContext()
    f_io = mueller_to_numpy(bsdf.eval(ctx, interaction(wi), mi.Vector3f(wo.T)))[0, 0, :, 0] / wo[:, 2]
    f_oi = mueller_to_numpy(bsdf.eval(ctx, interaction(wo), mi.Vector3f(wi.T)))[0, 0, :, 0] / wi[:, 2]
    np.testing.assert_allclose(f_io, f_oi, rtol=2e-5)


def test_unpolarized_variant_returns_the_intensity(hemisphere):
    wi, wo = hemisphere(3000, 0.02), hemisphere(3000, 0.02)
    params = dict(eta=1.38, alpha_s=0.25, rho_s=0.9, rho_ss=0.35, alpha_ss=0.7, rho_sss=0.55)
    mi.set_variant("llvm_ad_mono_polarized")
    polarized = mueller_to_numpy(pbssrdf(**params).eval(
        mi.BSDFContext(), interaction(wi), mi.Vector3f(wo.T)))[0, 0, :, 0]
    for variant in ["llvm_ad_rgb", "llvm_ad_mono"]:
        mi.set_variant(variant)
        value = np.array(pbssrdf(**params).eval(mi.BSDFContext(), interaction(wi),
                                                mi.Vector3f(wo.T)))
        np.testing.assert_allclose(value[0], polarized, rtol=1e-5, atol=1e-9)


def test_components_add_up(hemisphere):
    mi.set_variant("llvm_ad_mono_polarized")
    wi, wo = hemisphere(1000, 0.05), hemisphere(1000, 0.05)
    bsdf = pbssrdf(eta=1.4, alpha_s=0.35, rho_ss=0.4, alpha_ss=0.8, rho_sss=0.6)
    si, wo_m = interaction(wi), mi.Vector3f(wo.T)
    total = mueller_to_numpy(bsdf.eval(mi.BSDFContext(), si, wo_m))
    parts = []
    for component in range(3):
        ctx = mi.BSDFContext()
        ctx.component = component
        parts.append(mueller_to_numpy(bsdf.eval(ctx, si, wo_m)))
    np.testing.assert_allclose(sum(parts), total, rtol=1e-5, atol=1e-9)
    glossy = mi.BSDFContext()
    glossy.type_mask = +mi.BSDFFlags.GlossyReflection
    np.testing.assert_allclose(mueller_to_numpy(bsdf.eval(glossy, si, wo_m)), parts[0] + parts[1],
                               rtol=1e-5, atol=1e-9)
    assert bsdf.component_count() == 3


@pytest.mark.parametrize("params", [
    dict(eta=1.4, alpha_s=0.08, rho_s=1.0, rho_ss=0.0, rho_sss=0.5),   # smooth
    dict(eta=1.1, alpha_s=0.6, rho_s=0.5, rho_ss=0.5, alpha_ss=0.95, rho_sss=0.3),  # low eta
    dict(eta=1.9, alpha_s=0.35, rho_s=0.7, rho_ss=0.3, alpha_ss=0.7, rho_sss=0.8),  # high eta
    dict(eta=1.45, alpha_s=1.0, rho_s=1.0, rho_ss=0.0, rho_sss=0.0),   # rough, glossy only
])
@pytest.mark.parametrize("cos_theta_i", [0.95, 0.5, 0.15])
def test_chi2_sampling(params, cos_theta_i):
    """sample() draws directions with the density pdf() reports (Mitsuba's chi^2 test).

    Mitsuba's ``BSDFAdapter`` expects unpolarized weights, so the adapter
    here is the same with the Mueller weight's (0, 0) entry.
    """
    mi.set_variant("llvm_ad_mono_polarized")
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    bsdf = pbssrdf(**params)
    wi = [float(np.sqrt(1 - cos_theta_i**2)), 0.0, cos_theta_i]

    def context(n):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(*wi)
        return si, mi.BSDFContext()

    def sample_func(sample):
        si, ctx = context(dr.width(sample))
        bs, weight = bsdf.sample(ctx, si, sample[0], mi.Vector2f(sample[1], sample[2]))
        valid = dr.select(weight[0, 0][0] > 0, 1.0, 0.0)
        return bs.wo, mi.Float(valid)

    def pdf_func(wo):
        si, ctx = context(dr.width(wo))
        return bsdf.pdf(ctx, si, wo)

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                         sample_dim=3, ires=16, res=101, seed=7)
    assert test.run(), test.messages


@pytest.mark.parametrize("params", [
    dict(eta=1.4, alpha_s=0.3, rho_s=1.0, rho_ss=0.0, rho_sss=1.0),
    dict(eta=1.8, alpha_s=0.05, rho_s=0.6, rho_ss=0.4, alpha_ss=0.95, rho_sss=1.0),
    dict(eta=1.2, alpha_s=1.0, rho_s=0.5, rho_ss=0.5, alpha_ss=1.0, rho_sss=0.9),
    dict(eta=1.42, alpha_s=0.55, rho_s=0.8, rho_ss=0.2, alpha_ss=0.97, rho_sss=0.7),
])
def test_directional_albedo_below_one_and_sampling_is_unbiased(params):
    """Albedo from sample() weights equals the eval/pdf estimate and stays below 1.

    The lobes conserve energy whenever rho_s + rho_ss <= 1 and rho_sss <= 1
    (each glossy lobe reflects at most the Fresnel reflectance, the
    subsurface lobe at most the transmitted rest).
    """
    mi.set_variant("llvm_ad_mono_polarized")
    bsdf = pbssrdf(**params)
    n = 400_000
    sampler = np.random.default_rng(3)
    for cos_theta_i in [1.0, 0.7, 0.3, 0.08]:
        wi = np.tile([np.sqrt(1 - cos_theta_i**2), 0.0, cos_theta_i], (n, 1))
        si = interaction(wi)
        ctx = mi.BSDFContext()
        bs, weight = bsdf.sample(ctx, si, mi.Float(sampler.uniform(size=n)),
                                 mi.Point2f(sampler.uniform(size=(2, n))))
        albedo = float(np.mean(mueller_to_numpy(weight)[0, 0, :, 0]))
        # independent estimate: uniform hemisphere sampling of eval()
        u = sampler.uniform(size=(2, n))
        wo = mi.warp.square_to_uniform_hemisphere(mi.Point2f(u))
        value = mueller_to_numpy(bsdf.eval(ctx, si, wo))[0, 0, :, 0]
        reference = float(np.mean(value) * 2 * np.pi)
        assert albedo < 1.0
        assert albedo == pytest.approx(reference, rel=0.03, abs=2e-3)
        # sample() and eval_pdf() agree
        value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_allclose(np.array(pdf), np.array(bs.pdf), rtol=1e-5)
        w = mueller_to_numpy(weight)[0, 0, :, 0]
        ok = np.array(bs.pdf) > 0
        np.testing.assert_allclose(w[ok], mueller_to_numpy(value)[0, 0, ok, 0] / np.array(pdf)[ok],
                                   rtol=1e-4, atol=1e-7)


def test_parameters_are_exposed_and_differentiable():
    mi.set_variant("llvm_ad_mono_polarized")
    bsdf = pbssrdf(eta=1.4, alpha_s=0.3)
    params = mi.traverse(bsdf)
    for name in ["eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss", "rho_sss"]:
        assert f"{name}.value" in params.keys()
    params["eta.value"] = 1.55
    params.update()
    dr.enable_grad(params["eta.value"])
    wi = np.array([[0.3, 0.1, 0.95]]) / np.linalg.norm([0.3, 0.1, 0.95])
    value = bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(-0.2, 0.05, 0.98))
    dr.backward(value[0, 0][0])
    assert abs(float(dr.grad(params["eta.value"])[0])) > 0


@pytest.mark.parametrize("name,value,message", [
    ("eta", 1.0, "eta"), ("eta", 0.7, "eta"), ("rho_s", -0.1, "rho_s"),
    ("rho_sss", -0.5, "rho_sss"), ("rho_ss", 1.5, "rho_ss"), ("alpha_s", 0.0, "alpha_s"),
    ("alpha_ss", 1.2, "alpha_ss"), ("alpha_s", float("nan"), "alpha_s"),
])
def test_bad_parameters_fail_at_load_time(name, value, message):
    mi.set_variant("llvm_ad_mono_polarized")
    with pytest.raises(Exception, match=message) as info:
        pbssrdf(**{name: value})
    assert "range" in str(info.value) or "NaN" in str(info.value)


def test_missing_texture_file_names_the_file(tmp_path):
    mi.set_variant("llvm_ad_mono_polarized")
    missing = tmp_path / "no_such_map.exr"
    with pytest.raises(Exception, match="no_such_map.exr"):
        pbssrdf(rho_sss={"type": "bitmap", "filename": str(missing)})


def test_out_of_range_texture_data_fails(tmp_path):
    mi.set_variant("llvm_ad_mono_polarized")
    data = np.full((4, 4, 1), 1.3, dtype=np.float32)
    data[2, 2] = 0.95  # one texel below the minimum index of refraction
    path = tmp_path / "eta.exr"
    mi.Bitmap(data).write(str(path))
    with pytest.raises(Exception, match="eta"):
        pbssrdf(eta={"type": "bitmap", "filename": str(path), "raw": True})
    data[2, 2] = 1.5
    mi.Bitmap(data).write(str(path))
    bsdf = pbssrdf(eta={"type": "bitmap", "filename": str(path), "raw": True})
    assert "eta.data" in mi.traverse(bsdf).keys()


def test_grazing_directions_match_a_double_precision_evaluation(rng):
    """Where pplastic loses digits (cosines below 0.05), pbssrdf keeps them.

    The plugin's float32 eval is compared with the same model evaluated in
    float64 by the optics module (which is what the plugin calls).
    """
    from polarbssrdf.optics import pbrdf_mueller

    mi.set_variant("llvm_ad_mono_polarized")
    n = 5000

    def grazing(count):
        azimuth = rng.uniform(0, 2 * np.pi, count)
        cos_theta = rng.uniform(1e-3, 0.05, count)
        sin_theta = np.sqrt(1 - cos_theta**2)
        return np.stack([sin_theta * np.cos(azimuth), sin_theta * np.sin(azimuth), cos_theta], 1)

    wi, wo = grazing(n), grazing(n)
    wi[: n // 2, 2] = rng.uniform(0.3, 1.0, n // 2)  # half the pairs: one direction grazing
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wi, wo = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    params = dict(eta=1.45, rho_s=1.0, alpha_s=0.3, rho_ss=0.4, alpha_ss=0.8, rho_sss=0.6)
    single = mueller_to_numpy(pbssrdf(**params).eval(mi.BSDFContext(), interaction(wi),
                                                     mi.Vector3f(wo.T)))[..., 0]
    Array3f64 = dr.llvm.ad.Array3f64
    double = mueller_to_numpy(pbrdf_mueller(Array3f64(wi.T), Array3f64(wo.T), **params)) * wo[:, 2]
    scale = np.abs(double).max(axis=(0, 1))
    assert np.all(scale > 0)
    assert (np.abs(single - double).max(axis=(0, 1)) / scale).max() < 1e-4


def srgb_to_linear(encoded):
    """The sRGB transfer function (IEC 61966-2-1), decoding values in [0, 1]."""
    encoded = np.asarray(encoded, dtype=np.float64)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def write_8bit(path, values, channels=1):
    """Write 8-bit ``values`` (rows x columns) as a grey or RGB PNG/JPEG file with PIL."""
    from PIL import Image

    values = np.asarray(values, dtype=np.uint8)
    if channels == 3:
        values = np.stack([values] * 3, axis=-1)
    Image.fromarray(values).save(path, quality=95)
    return str(path)


def gradient(low=40, high=220, size=16):
    """A size x size 8-bit gradient along the columns (u), from ``low`` to ``high``."""
    return np.tile(np.linspace(low, high, size).round(), (size, 1))


@pytest.mark.parametrize("variant", ["llvm_ad_mono_polarized", "llvm_ad_spectral_polarized",
                                     "scalar_rgb"])
@pytest.mark.parametrize("suffix", ["png", "jpg"])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("raw", [False, True])
def test_8bit_textures_load(tmp_path, variant, suffix, channels, raw):
    """8-bit files are stored as 0-255 integers: the check sees the values the texture returns."""
    mi.set_variant(variant)
    path = write_8bit(tmp_path / f"albedo.{suffix}", gradient(0, 255), channels)
    bsdf = pbssrdf(rho_sss={"type": "bitmap", "filename": path, "raw": raw})
    assert "rho_sss.data" in mi.traverse(bsdf).keys()


@pytest.mark.parametrize("raw", [False, True])
def test_8bit_texture_range_check_reports_the_decoded_value(tmp_path, raw):
    """An 8-bit eta map is always out of range; the error quotes the value eval would return."""
    mi.set_variant("llvm_ad_mono_polarized")
    path = write_8bit(tmp_path / "eta.png", np.full((8, 8), 128))
    expected = 128 / 255 if raw else srgb_to_linear(128 / 255)
    with pytest.raises(Exception, match="eta") as info:
        pbssrdf(eta={"type": "bitmap", "filename": path, "raw": raw})
    message = str(info.value)
    assert "range" in message
    reported = float(message.split(" = ")[1].split()[0])
    assert reported == pytest.approx(expected, rel=1e-4)


def test_range_check_follows_the_texture_uv_transform(tmp_path):
    """With a ``to_uv`` transform the check still looks up the texel holding the bad value."""
    mi.set_variant("llvm_ad_mono_polarized")
    data = np.full((8, 8, 1), 1.3, dtype=np.float32)
    data[5, 2] = 0.9
    path = tmp_path / "eta.exr"
    mi.Bitmap(data).write(str(path))
    to_uv = mi.ScalarTransform4f().translate([0.3, -0.2, 0]).scale([2.0, 3.0, 1.0])
    with pytest.raises(Exception, match="eta.* = 0.9 "):
        pbssrdf(eta={"type": "bitmap", "filename": str(path), "raw": True, "to_uv": to_uv})


def test_nan_in_texture_data_fails(tmp_path):
    mi.set_variant("llvm_ad_mono_polarized")
    data = np.full((4, 4, 1), 0.5, dtype=np.float32)
    data[1, 3] = np.nan
    path = tmp_path / "rho_sss.exr"
    mi.Bitmap(data).write(str(path))
    with pytest.raises(Exception, match="rho_sss.*NaN"):
        pbssrdf(rho_sss={"type": "bitmap", "filename": str(path), "raw": True})


def test_sphere_with_a_png_albedo_renders_like_its_decoded_float_map(tmp_path):
    """A PNG albedo renders finite, brighter where the albedo is higher, like its sRGB decoding.

    The sphere's u is the azimuth atan2(y, x) / 2 pi seen from the +z camera:
    u < 0.5 (the darker half of the gradient) is the upper half of the image.
    """
    mi.set_variant("llvm_ad_mono_polarized")
    values = gradient()
    png = write_8bit(tmp_path / "albedo.png", values)
    exr = tmp_path / "albedo.exr"
    decoded = srgb_to_linear(values / 255.0).astype(np.float32)[..., None]
    mi.Bitmap(decoded).write(str(exr))

    def render(texture_file):
        albedo = {"type": "bitmap", "filename": str(texture_file)}
        scene = {
            "type": "scene",
            "integrator": {"type": "stokes", "inner": {"type": "direct"}},
            "sensor": {
                "type": "perspective", "fov": 14,
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 500], target=[0, 0, 0],
                                                           up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": 32, "height": 32,
                         "rfilter": {"type": "box"}},
            },
            "light": {"type": "ppoint", "position": [0.0, 0.0, 500.0], "intensity": 5e5},
            "sphere": {"type": "sphere", "radius": 50.0,
                       "bsdf": {"type": "pbssrdf", "rho_s": 0.0, "rho_ss": 0.0,
                                "rho_sss": albedo}},
        }
        return np.array(mi.render(mi.load_dict(scene), spp=4, seed=1))[..., 1]  # S0

    S0 = render(png)
    assert np.all(np.isfinite(S0))
    upper, lower = S0[:16].sum(), S0[16:].sum()
    assert lower > 1.5 * upper > 0
    np.testing.assert_allclose(S0, render(exr), rtol=1e-3, atol=1e-6 * S0.max())
