"""Emitter ``pexitance``: subsurface light leaving a surface, from a diffused exitance map.

Texture-space subsurface scattering (supplement eq. 13, 44-46) computes, per
texel, the power that entered the skin, was diffused below it and now
leaves. This area emitter turns that map into radiance: light leaves through
Fresnel transmission, partially polarized parallel to the plane of emission,

    L_o = M(x) [T+(theta_o), T-(theta_o), 0, 0] / pi

in the frame of the normal's plane of emission, i.e. the exit factor of
``pbssrdf``'s subsurface lobe
(:func:`polarbssrdf.optics.pbrdf.subsurface_exit_stokes_column`). Attach it
to the same shape as a ``pbssrdf`` whose ``rho_sss`` is 0 (its glossy lobes
still reflect the lights); with a map computed without blur the two
together reproduce ``pbssrdf`` with its local subsurface lobe.

.. pluginparameters::

 * - exitance
   - |texture|
   - Diffused, albedo-weighted, Fresnel-transmitted irradiance ``M`` below
     the surface (W/mm^2 for lights in W/sr and lengths in mm), looked up at
     the surface's UV. (Default: 0)
   - |exposed|, |differentiable|
 * - eta
   - |float| or |texture|
   - Relative refractive index of the surface (> 1), as given to the
     ``pbssrdf`` of the same shape. (Default: 1.4)
   - |exposed|, |differentiable|
"""

from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi

from polarbssrdf.optics.pbrdf import subsurface_exit_stokes_column


@functools.lru_cache(maxsize=None)
def _class_for_variant(variant):
    class PolarizedExitance(mi.Emitter):
        """Mitsuba emitter ``pexitance``; see the module docstring."""

        def __init__(self, props):
            # Light leaving the surface is found by rays that hit it; excluding
            # it from emitter sampling keeps direct lighting from the stage's
            # lights from losing samples to it.
            if "sampling_weight" not in props:
                props["sampling_weight"] = 0.0
            mi.Emitter.__init__(self, props)
            self.exitance = props.get_texture("exitance", 0.0)
            self.eta = props.get_texture("eta", 1.4)
            if "eta" in props and isinstance(props["eta"], (int, float)) and props["eta"] <= 1:
                raise ValueError(f"pexitance: 'eta' must be > 1, got {props['eta']}")
            self.m_flags = mi.EmitterFlags.Surface | mi.EmitterFlags.SpatiallyVarying

        def traverse(self, callback):
            callback.put("exitance", self.exitance, mi.ParamFlags.Differentiable)
            callback.put("eta", self.eta, mi.ParamFlags.Differentiable)

        def eval(self, si, active=True):
            cos_theta = mi.Frame3f.cos_theta(si.wi)
            active = mi.Bool(active) & (cos_theta > 0)
            exitance = self.exitance.eval_1(si, active)
            column = subsurface_exit_stokes_column(si.wi, self.eta.eval_1(si, active))
            if not mi.is_polarized:
                return dr.select(active, mi.Spectrum(exitance * column[0]), 0.0)
            stokes = mi.Spectrum(exitance * column[0], 0, 0, 0,
                                 exitance * column[1], 0, 0, 0,
                                 exitance * column[2], 0, 0, 0,
                                 0, 0, 0, 0)
            # Only the first column is set, so only the exitant basis matters.
            stokes = si.to_world_mueller(stokes, -si.wi, si.wi)
            return dr.select(active, stokes, 0.0)

        # Not importance-sampled (sampling weight 0): camera rays find it, and
        # other surfaces see it through BSDF sampling.
        def sample_direction(self, it, sample, active=True):
            return dr.zeros(mi.DirectionSample3f), dr.zeros(mi.Spectrum)

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return dr.zeros(mi.Spectrum)

        def sample_ray(self, time, wavelength_sample, spatial_sample, direction_sample,
                       active=True):
            return dr.zeros(mi.Ray3f), dr.zeros(mi.Spectrum)

        def sample_position(self, time, sample, active=True):
            return dr.zeros(mi.PositionSample3f), mi.Float(0.0)

        def pdf_position(self, ps, active=True):
            return mi.Float(0.0)

        def sample_wavelengths(self, si, sample, active=True):
            return self.exitance.sample_spectrum(si, mi.math.sample_shifted(sample), active)

        def bbox(self):
            shape = self.get_shape()
            return shape.bbox() if shape is not None else mi.ScalarBoundingBox3f()

        def to_string(self):
            return f"PolarizedExitance[exitance={self.exitance}, eta={self.eta}]"

    PolarizedExitance.__name__ = f"PolarizedExitance_{variant}"
    return PolarizedExitance


def make_class():
    """The ``pexitance`` emitter class for the active Mitsuba variant."""
    return _class_for_variant(mi.variant())
