"""Emitter ``ppoint``: a point light behind an ideal linear polarizer.

.. pluginparameters::

 * - position
   - |point| or |vector|
   - World-space position of the light, in mm. (Default: (0, 0, 0))
   - |exposed|
 * - intensity
   - |spectrum| or |float|
   - Radiant intensity leaving the polarizer (W/sr, i.e. the Stokes ``S0``
     of the emitted light per steradian). (Default: 1.0)
   - |exposed|, |differentiable|
 * - polarization_axis
   - |vector|
   - World-space transmission axis of the polarizer. Light emitted along a
     direction ``d`` is linearly polarized along the component of this axis
     perpendicular to ``d`` (the axis must not be parallel to any direction
     that is rendered). For a light next to a camera, pass the camera's right
     vector to get light polarized along image x. (Default: (1, 0, 0))
   - |exposed|
 * - polarizer_normal
   - |vector|
   - Optional normal of the polarizer sheet (the light's optical axis).
     When given, the polarizer is modelled as a dichroic sheet that absorbs
     the field along its absorption axis ``b = normal x polarization_axis``:
     light along ``d`` is polarized along ``d x b``, perpendicular to ``b``.
     This is the convention of Mitsuba's ``stokes`` sensor frame (x =
     ``d x up``), so a light beside a camera with ``polarization_axis`` =
     camera right and ``polarizer_normal`` = camera forward is polarized
     exactly along image x in every pixel, not only on the optical axis.
     Both models agree along the normal. (Default: none, projection model)
   - |exposed|

The light is fully linearly polarized in polarized variants; in unpolarized
variants it emits ``intensity``. It is a delta light: it works with
``direct``, ``path``, ``volpath`` and inside ``stokes``, like Mitsuba's
``point``.

.. tabs::
    .. code-tab:: xml

        <emitter type="ppoint">
            <point name="position" x="0" y="0" z="500"/>
            <float name="intensity" value="250000"/>
            <vector name="polarization_axis" x="1" y="0" z="0"/>
        </emitter>
"""

from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi

from polarbssrdf.optics.mueller import stokes_basis, stokes_basis_rotation_angle


def _vector_property(props, name, default):
    if name not in props:
        return mi.ScalarVector3f(default)
    value = props[name]
    try:
        vector = mi.ScalarVector3f(value)
    except (TypeError, RuntimeError) as error:
        raise ValueError(f"ppoint: '{name}' must be a 3-vector, got {value!r}") from error
    if not all(dr.isfinite(vector[i]) for i in range(3)):
        raise ValueError(f"ppoint: '{name}' must be finite, got {vector}")
    return vector


def polarization_direction(forward, axis, absorption_axis=None):
    """Unit field direction of light along ``forward`` behind a linear polarizer.

    Projection model: ``axis`` projected perpendicular to ``forward``.
    Dichroic-sheet model (``absorption_axis`` given): ``forward x absorption_axis``.
    """
    if absorption_axis is None:
        return dr.normalize(axis - dr.dot(axis, forward) * forward)
    return dr.normalize(dr.cross(forward, absorption_axis))


def linear_polarization_stokes(forward, field_direction):
    """``(S1, S2) / S0 = (cos 2t, sin 2t)`` of light along ``forward`` polarized along a direction.

    Expressed in Mitsuba's implicit basis ``stokes_basis(forward)``;
    ``field_direction`` must be a unit vector perpendicular to ``forward``.
    """
    angle = stokes_basis_rotation_angle(forward, field_direction, stokes_basis(forward))
    s, c = dr.sincos(2.0 * angle)
    # C(angle) applied to [1, 1, 0, 0]
    return c, -s


@functools.lru_cache(maxsize=None)
def _class_for_variant(variant):
    class PolarizedPointLight(mi.Emitter):
        """Mitsuba emitter ``ppoint``; see the module docstring."""

        def __init__(self, props):
            mi.Emitter.__init__(self, props)
            self.position = mi.Point3f(_vector_property(props, "position", [0.0, 0.0, 0.0]))
            axis = _vector_property(props, "polarization_axis", [1.0, 0.0, 0.0])
            if dr.norm(axis) == 0:
                raise ValueError("ppoint: 'polarization_axis' must be a non-zero vector")
            self.polarization_axis = mi.Vector3f(dr.normalize(axis))
            self.polarizer_normal = None
            if "polarizer_normal" in props:
                self.polarizer_normal = _vector_property(props, "polarizer_normal",
                                                         [0.0, 0.0, 1.0])
            self.absorption_axis = self._absorption_axis(dr.normalize(axis))
            self.intensity = props.get_emissive_texture("intensity", 1.0)
            if "intensity" in props and isinstance(props["intensity"], (int, float)) \
                    and props["intensity"] < 0:
                raise ValueError(f"ppoint: 'intensity' must be >= 0, got {props['intensity']}")
            self.m_flags = mi.EmitterFlags.DeltaPosition
            self.m_needs_sample_3 = False
            dr.make_opaque(self.position, self.polarization_axis)

        def traverse(self, callback):
            callback.put("position", self.position, mi.ParamFlags.NonDifferentiable)
            callback.put("polarization_axis", self.polarization_axis,
                         mi.ParamFlags.NonDifferentiable)
            callback.put("intensity", self.intensity, mi.ParamFlags.Differentiable)

        def _absorption_axis(self, axis):
            """Absorption axis of the dichroic sheet, or None for the projection model."""
            if self.polarizer_normal is None:
                return None
            absorption = dr.cross(self.polarizer_normal, mi.ScalarVector3f(axis))
            if dr.norm(absorption) < 1e-6:
                raise ValueError("ppoint: 'polarizer_normal' must not be parallel to "
                                 "'polarization_axis'")
            return mi.Vector3f(dr.normalize(absorption))

        def parameters_changed(self, keys):
            self.polarization_axis = dr.normalize(self.polarization_axis)
            if "polarization_axis" in keys or not keys:
                axis = [dr.ravel(self.polarization_axis[i])[0] if dr.is_jit_v(mi.Float)
                        else self.polarization_axis[i] for i in range(3)]
                self.absorption_axis = self._absorption_axis(axis)
            dr.make_opaque(self.position, self.polarization_axis)

        def _emission(self, forward, wavelengths, inv_dist2, active):
            """Emitted radiance weight travelling along ``forward`` (world space)."""
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wavelengths = wavelengths
            value = self.intensity.eval(si, active) * inv_dist2
            if not mi.is_polarized:
                return value
            field = polarization_direction(forward, self.polarization_axis, self.absorption_axis)
            cos_term, sin_term = linear_polarization_stokes(forward, field)
            return mi.Spectrum(value, 0, 0, 0,
                               value * cos_term, 0, 0, 0,
                               value * sin_term, 0, 0, 0,
                               0, 0, 0, 0)

        def sample_direction(self, it, sample, active=True):
            to_light = self.position - it.p
            dist2 = dr.squared_norm(to_light)
            dist = dr.sqrt(dist2)
            ds = mi.DirectionSample3f()  # dr.zeros() fails for it in scalar variants
            ds.p = self.position
            ds.n = mi.Normal3f(0.0)
            ds.uv = mi.Point2f(0.0)
            ds.d = to_light / dist
            ds.dist = dist
            ds.time = it.time
            ds.pdf = 1.0
            ds.delta = True
            ds.emitter = mi.EmitterPtr(self) if dr.is_jit_v(mi.Float) else self
            weight = self._emission(-ds.d, it.wavelengths, dr.rcp(dist2), active)
            return ds, dr.select(active, weight, 0.0)

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            dist2 = dr.squared_norm(self.position - it.p)
            return dr.select(active, self._emission(-ds.d, it.wavelengths, dr.rcp(dist2), active),
                             0.0)

        def sample_ray(self, time, wavelength_sample, spatial_sample, direction_sample,
                       active=True):
            wavelengths, spectrum_weight = self._sample_wavelengths(wavelength_sample, active)
            direction = mi.warp.square_to_uniform_sphere(direction_sample)
            ray = mi.Ray3f(self.position, direction, time, wavelengths)
            weight = self._emission(direction, wavelengths, 4.0 * dr.pi, active)
            if mi.is_spectral:
                si = dr.zeros(mi.SurfaceInteraction3f)
                si.wavelengths = wavelengths
                intensity = self.intensity.eval(si, active)
                scale = spectrum_weight / dr.select(intensity != 0, intensity, 1.0)
                weight = mi.Spectrum(scale) * weight if mi.is_polarized else weight * scale
            return ray, dr.select(active, weight, 0.0)

        def _sample_wavelengths(self, sample, active):
            si = dr.zeros(mi.SurfaceInteraction3f)
            if mi.is_spectral:
                return self.intensity.sample_spectrum(si, mi.math.sample_shifted(sample), active)
            return dr.zeros(mi.Wavelength), mi.UnpolarizedSpectrum(1.0)

        def sample_wavelengths(self, si, sample, active=True):
            return self.intensity.sample_spectrum(si, mi.math.sample_shifted(sample), active)

        def sample_position(self, time, sample, active=True):
            ps = mi.PositionSample3f()
            ps.p = self.position
            ps.n = mi.Normal3f(0.0)
            ps.uv = mi.Point2f(0.0)
            ps.time = time
            ps.pdf = 1.0
            ps.delta = True
            return ps, mi.Float(1.0)

        def pdf_position(self, ps, active=True):
            return mi.Float(0.0)

        def eval(self, si, active=True):
            return dr.zeros(mi.Spectrum)

        def bbox(self):
            p = mi.ScalarPoint3f(dr.slice(self.position) if dr.is_jit_v(mi.Float)
                                 else self.position)
            return mi.ScalarBoundingBox3f(p)

        def to_string(self):
            return (f"PolarizedPointLight[position={self.position}, "
                    f"polarization_axis={self.polarization_axis}, intensity={self.intensity}]")

    PolarizedPointLight.__name__ = f"PolarizedPointLight_{variant}"
    return PolarizedPointLight


def make_class():
    """The ``ppoint`` emitter class for the active Mitsuba variant."""
    return _class_for_variant(mi.variant())
