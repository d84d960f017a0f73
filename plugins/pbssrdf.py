"""BSDF ``pbssrdf``: the polarimetric skin reflectance of the supplement.

.. pluginparameters::

 * - eta
   - |float| or |texture|
   - Relative refractive index of skin over air, > 1. (Default: 1.4)
   - |exposed|, |differentiable|
 * - rho_s
   - |spectrum| or |texture|
   - Specular albedo ``rho_s`` in [0, 1] (eq. 5). (Default: 1.0)
   - |exposed|, |differentiable|
 * - alpha_s
   - |float| or |texture|
   - GGX roughness of the specular lobe, in (0, 1]. (Default: 0.3)
   - |exposed|, |differentiable|
 * - rho_ss
   - |spectrum| or |texture|
   - Single-scattering albedo ``rho_ss`` in [0, 1] (eq. 6). (Default: 0.0)
   - |exposed|, |differentiable|
 * - alpha_ss
   - |float| or |texture|
   - GGX roughness of the single-scattering lobe, in (0, 1]. (Default: 0.9)
   - |exposed|, |differentiable|
 * - rho_sss
   - |spectrum| or |texture|
   - Subsurface albedo ``rho_sss`` in [0, 1]: the albedo of the depolarizing
     lobe between two Fresnel transmissions (eq. 19). (Default: 0.5)
   - |exposed|, |differentiable|

Every parameter is checked against its range at load time. For a bitmap
texture the check reads the values the texture returns, not the stored data:
8-bit PNG and JPEG files are stored as 0-255 integers and decoded (from sRGB
unless ``raw``) at lookup.

Three components, selectable through ``BSDFContext`` like any Mitsuba BSDF:
0 = specular (glossy), 1 = single scattering (glossy), 2 = subsurface
(diffuse). A texture-space subsurface integrator evaluates only the glossy
components (``type_mask = GlossyReflection``) and applies the subsurface lobe
itself from the entry and exit factors in :mod:`polarbssrdf.optics.pbrdf`
(``subsurface_entry_stokes_row`` / ``subsurface_exit_stokes_column``), whose
product is exactly this plugin's subsurface lobe.

In polarized variants ``eval`` returns the Mueller matrix of
:func:`polarbssrdf.optics.pbrdf.pbrdf_mueller` times the cosine
foreshortening; in unpolarized variants its (0, 0) entry. ``sample``
importance-samples the three lobes (visible GGX normals for the glossy
lobes, the cosine hemisphere for the subsurface lobe) with lobe
probabilities proportional to their albedo times the Fresnel factor at the
incident direction.

.. tabs::
    .. code-tab:: xml

        <bsdf type="pbssrdf">
            <float name="eta" value="1.42"/>
            <float name="alpha_s" value="0.55"/>
            <rgb name="rho_sss" value="0.6, 0.4, 0.3"/>
        </bsdf>
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

from polarbssrdf.optics.fresnel import fresnel_reflectance, fresnel_transmittance, plus_minus
from polarbssrdf.optics.microfacet import ggx_distribution, smith_g1_ggx
from polarbssrdf.optics.pbrdf import pbrdf_intensity, pbrdf_mueller

class Parameter(NamedTuple):
    """Default and valid range of a plugin parameter."""

    default: float
    low: float
    low_inclusive: bool
    high: float | None
    high_inclusive: bool

    def describe_range(self):
        left = "[" if self.low_inclusive else "("
        right = "]" if self.high_inclusive else ")"
        upper = "inf" if self.high is None else f"{self.high:g}"
        return f"{left}{self.low:g}, {upper}{right}"

    def check(self, name, values, where=""):
        """Raise ValueError naming ``name`` if any value is non-finite or out of range."""
        values = np.asarray(values, dtype=np.float64)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"pbssrdf: parameter '{name}'{where} contains NaN or infinite values")
        bad = (values < self.low) if self.low_inclusive else (values <= self.low)
        if self.high is not None:
            bad |= (values > self.high) if self.high_inclusive else (values >= self.high)
        if np.any(bad):
            raise ValueError(
                f"pbssrdf: parameter '{name}'{where} = {float(values[bad].flat[0]):g} is outside "
                f"its valid range {self.describe_range()}")


PARAMETERS = {
    "eta": Parameter(1.4, 1.0, False, None, False),
    "rho_s": Parameter(1.0, 0.0, True, 1.0, True),
    "alpha_s": Parameter(0.3, 0.0, False, 1.0, True),
    "rho_ss": Parameter(0.0, 0.0, True, 1.0, True),
    "alpha_ss": Parameter(0.9, 0.0, False, 1.0, True),
    "rho_sss": Parameter(0.5, 0.0, True, 1.0, True),
}

SPECULAR, SINGLE_SCATTERING, SUBSURFACE = 0, 1, 2


def _load_texture(props, name):
    """The texture for ``name`` (a float becomes a uniform texture), checked against its range."""
    parameter = PARAMETERS[name]
    if name in props:
        value = props[name]
        if isinstance(value, (int, float)):
            parameter.check(name, [value])
    texture = props.get_texture(name, parameter.default)
    params = mi.traverse(texture)
    if "value" in params.keys():
        data = params["value"]
        # In spectral variants an RGB texture stores spectral-upsampling
        # coefficients, not reflectances: only monochrome values can be checked.
        if not mi.is_spectral or dr.depth_v(data) == 1:
            parameter.check(name, dr.ravel(data), " (texture 'value')")
    if "data" in params.keys():
        values = _bitmap_extreme_values(texture, params)
        if values is not None:
            parameter.check(name, values, " (texture 'data')")
    return texture


def _bitmap_extreme_values(texture, params):
    """The smallest and largest values a bitmap texture returns, per channel; None if unknown.

    The stored data is not what the texture returns: Mitsuba keeps 8-bit PNG
    and JPEG files as 0-255 integers and decodes them (from sRGB unless
    ``raw``) at lookup, and 16-bit files as half floats. Every such decoding
    is monotonic per channel, so the texels holding each channel's stored
    minimum and maximum also hold the extremes of what the texture returns:
    evaluating the texture there checks its true values at the cost of a few
    lookups, however large the texture is.
    """
    data = np.asarray(params["data"])
    if data.ndim != 3 or data.size == 0:
        return None
    height, width, channels = data.shape
    if channels not in (1, 3):
        return None
    # In spectral variants a non-raw RGB bitmap stores spectral-upsampling
    # coefficients, which eval_3 refuses: only monochrome values can be checked.
    if mi.is_spectral and channels == 3 and _is_sRGB_coefficients(texture):
        return None
    if np.issubdtype(data.dtype, np.floating) and not np.all(np.isfinite(data)):
        return data[~np.isfinite(data)]  # reported as non-finite by the range check
    # Per channel: faster than argmin over axis 0 of a texels x channels view.
    extremes = [find(data[..., channel]) for channel in range(channels)
                for find in (np.argmin, np.argmax)]
    rows, columns = np.divmod(np.array(extremes), width)
    uv = _texel_centre_uvs(params, rows, columns, height, width)
    return _evaluate_texture(texture, uv, channels)


def _is_sRGB_coefficients(texture):
    """Whether a 3-channel bitmap in a spectral variant holds upsampling coefficients (not raw)."""
    # The raw flag is not exposed to Python; the texture's description reports it.
    return "raw = 0" in str(texture)


def _texel_centre_uvs(params, rows, columns, height, width):
    """Surface UVs (2 x n) whose lookups land on the centres of texels (rows, columns).

    A bitmap made from an array indexes rows by v without a flip; the
    texture's ``to_uv`` transform is applied to the surface UV before the
    lookup, so its inverse maps texel centres back to surface UVs.
    """
    texel_uv = np.stack([(columns + 0.5) / width, (rows + 0.5) / height, np.ones(len(rows))])
    if "to_uv" in params.keys():
        # Inverted here: AffineTransform3f.inverse() drops the translation (Mitsuba 3.9).
        to_uv = np.array(params["to_uv"].matrix, dtype=np.float64)
        texel_uv = np.linalg.solve(to_uv, texel_uv)
    return texel_uv[:2] / texel_uv[2]


def _evaluate_texture(texture, uv, channels):
    """Values (channels x n) of ``texture`` at the surface UVs ``uv`` (2 x n)."""
    evaluate = texture.eval_1 if channels == 1 else texture.eval_3
    if not dr.is_jit_v(mi.Float):  # scalar variants evaluate one lookup at a time
        return np.array([np.ravel(np.array(evaluate(_interaction_at(u, v)), dtype=np.float64))
                         for u, v in uv.T]).T
    values = evaluate(_interaction_at(*uv, count=uv.shape[1]))
    return np.array(values, dtype=np.float64).reshape(channels, -1)


def _interaction_at(u, v, count=None):
    """A surface interaction at UV (u, v), of ``count`` lanes in JIT variants."""
    si = dr.zeros(mi.SurfaceInteraction3f) if count is None else \
        dr.zeros(mi.SurfaceInteraction3f, count)
    si.uv = mi.Point2f(u, v)
    if mi.is_spectral:
        si.wavelengths = dr.full(mi.UnpolarizedSpectrum, 550.0) if count is None else \
            dr.full(mi.UnpolarizedSpectrum, 550.0, count)
    return si


def _mean_channel(spectrum):
    """Average over the channels (wavelengths) of an unpolarized spectrum, per lane."""
    return dr.mean(spectrum, axis=0)


@functools.lru_cache(maxsize=None)
def _class_for_variant(variant):
    class PolarimetricBSSRDF(mi.BSDF):
        """Mitsuba BSDF ``pbssrdf``; see the module docstring."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.textures = {name: _load_texture(props, name) for name in PARAMETERS}
            glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            diffuse = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [glossy, glossy, diffuse]
            self.m_flags = glossy | diffuse

        # -- parameters -------------------------------------------------
        def traverse(self, callback):
            for name, texture in self.textures.items():
                callback.put(name, texture, mi.ParamFlags.Differentiable)

        def _parameters(self, si, active):
            t = self.textures
            return (t["eta"].eval_1(si, active), t["rho_s"].eval(si, active),
                    t["alpha_s"].eval_1(si, active), t["rho_ss"].eval(si, active),
                    t["alpha_ss"].eval_1(si, active), t["rho_sss"].eval(si, active))

        def _enabled(self, ctx):
            return (ctx.is_enabled(mi.BSDFFlags.GlossyReflection, SPECULAR),
                    ctx.is_enabled(mi.BSDFFlags.GlossyReflection, SINGLE_SCATTERING),
                    ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, SUBSURFACE))

        def _lobe_probabilities(self, ctx, si, params):
            eta, rho_s, _, rho_ss, _, rho_sss = params
            cos_i = mi.Frame3f.cos_theta(si.wi)
            R_plus, _ = plus_minus(*fresnel_reflectance(cos_i, eta))
            T_plus, _ = plus_minus(*fresnel_transmittance(cos_i, eta))
            enabled = self._enabled(ctx)
            weights = [
                _mean_channel(rho_s) * R_plus if enabled[SPECULAR] else 0.0,
                _mean_channel(rho_ss) * R_plus if enabled[SINGLE_SCATTERING] else 0.0,
                _mean_channel(rho_sss) * T_plus if enabled[SUBSURFACE] else 0.0,
            ]
            total = weights[0] + weights[1] + weights[2]
            uniform = 1.0 / max(sum(enabled), 1)
            # All albedos may be zero: then pick the enabled lobes uniformly.
            return [dr.select(total > 0, weight / dr.maximum(total, 1e-20),
                              uniform if on else 0.0)
                    for on, weight in zip(enabled, weights)]

        # -- evaluation -------------------------------------------------
        def _eval(self, ctx, si, wo, params, active):
            eta, rho_s, alpha_s, rho_ss, alpha_ss, rho_sss = params
            cos_o = mi.Frame3f.cos_theta(wo)
            specular, single, subsurface = self._enabled(ctx)
            if mi.is_polarized:
                radiance = ctx.mode == mi.TransportMode.Radiance
                wo_hat = wo if radiance else si.wi
                wi_hat = si.wi if radiance else wo
                value = pbrdf_mueller(wi_hat, wo_hat, eta, rho_s, alpha_s, rho_ss, alpha_ss,
                                      rho_sss, Matrix=mi.Spectrum, specular=specular,
                                      single_scattering=single, subsurface=subsurface)
                value = mi.Spectrum(value) * cos_o
            else:
                h = dr.normalize(si.wi + wo)
                zero = mi.UnpolarizedSpectrum(0.0)
                value = pbrdf_intensity(
                    mi.Frame3f.cos_theta(si.wi), cos_o, mi.Frame3f.cos_theta(h), dr.dot(wo, h),
                    eta, rho_s if specular else zero, alpha_s, rho_ss if single else zero,
                    alpha_ss, rho_sss if subsurface else zero) * cos_o
                value = mi.Spectrum(value)
            valid = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (cos_o > 0)
            return dr.select(valid, value, 0.0)

        def _pdf(self, ctx, si, wo, params, active):
            _, _, alpha_s, _, alpha_ss, _ = params
            probabilities = self._lobe_probabilities(ctx, si, params)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            h = dr.normalize(si.wi + wo)
            cos_h, cos_ih, cos_oh = mi.Frame3f.cos_theta(h), dr.dot(si.wi, h), dr.dot(wo, h)

            def visible_normal_pdf(alpha):
                # pdf of wo under visible-normal sampling: D G1(wi) / (4 cos_i)
                pdf = ggx_distribution(cos_h, alpha) * smith_g1_ggx(cos_i, cos_ih, alpha) \
                    / (4.0 * cos_i)
                return dr.select((cos_ih > 0) & (cos_oh > 0), pdf, 0.0)

            pdf = (probabilities[SPECULAR] * visible_normal_pdf(alpha_s)
                   + probabilities[SINGLE_SCATTERING] * visible_normal_pdf(alpha_ss)
                   + probabilities[SUBSURFACE] * mi.warp.square_to_cosine_hemisphere_pdf(wo))
            return dr.select(active & (cos_i > 0) & (cos_o > 0), pdf, 0.0)

        def eval(self, ctx, si, wo, active=True):
            params = self._parameters(si, active)
            return self._eval(ctx, si, wo, params, active)

        def pdf(self, ctx, si, wo, active=True):
            params = self._parameters(si, active)
            return self._pdf(ctx, si, wo, params, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            params = self._parameters(si, active)
            return self._eval(ctx, si, wo, params, active), self._pdf(ctx, si, wo, params, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            params = self._parameters(si, active)
            _, _, alpha_s, _, alpha_ss, _ = params
            cos_i = mi.Frame3f.cos_theta(si.wi)
            active = mi.Bool(active) & (cos_i > 0)
            p = self._lobe_probabilities(ctx, si, params)
            # Comparisons rather than `~`, which is integer negation on scalar-variant bools.
            threshold = p[SPECULAR] + p[SINGLE_SCATTERING]
            pick_specular = sample1 < p[SPECULAR]
            pick_single = (sample1 >= p[SPECULAR]) & (sample1 < threshold)
            pick_subsurface = sample1 >= threshold

            alpha = dr.select(pick_specular, alpha_s, alpha_ss)
            distribution = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
            m, _ = distribution.sample(si.wi, sample2)
            wo_glossy = mi.reflect(si.wi, m)
            wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)

            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = dr.select(pick_subsurface, wo_diffuse, wo_glossy)
            bs.eta = 1.0
            bs.sampled_component = dr.select(
                pick_specular, mi.UInt32(SPECULAR),
                dr.select(pick_single, mi.UInt32(SINGLE_SCATTERING), mi.UInt32(SUBSURFACE)))
            bs.sampled_type = dr.select(pick_subsurface, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                        mi.UInt32(+mi.BSDFFlags.GlossyReflection))
            value = self._eval(ctx, si, bs.wo, params, active)
            bs.pdf = self._pdf(ctx, si, bs.wo, params, active)
            active &= bs.pdf > 0
            weight = value / dr.select(active, bs.pdf, 1.0)
            return bs, dr.select(active, weight, 0.0)

        def to_string(self):
            lines = [f"  {name} = {texture}" for name, texture in self.textures.items()]
            return "PolarimetricBSSRDF[\n" + ",\n".join(lines) + "\n]"

    PolarimetricBSSRDF.__name__ = f"PolarimetricBSSRDF_{variant}"
    return PolarimetricBSSRDF


def make_class():
    """The ``pbssrdf`` BSDF class for the active Mitsuba variant."""
    return _class_for_variant(mi.variant())
