"""Predicted analyser images of texel-views through the pBRDF of :mod:`polarbssrdf.optics`.

The static and dynamic stages evaluate, per texel-view, exactly the Mueller
matrices the ``pbssrdf`` plugin evaluates inside Mitsuba
(:func:`polarbssrdf.optics.pbrdf.pbrdf_mueller`), with the real light
position (the light sits 5.7 degrees off the camera axis), the light's
polarization field and the camera's Stokes frame, on Dr.Jit arrays with
autodiff:

    S_camera = E cos(theta_light) C_cam M(wi, wo) C_light [1, 1, 0, 0]^T

``E = I / d^2`` is the irradiance of the ``ppoint`` light on a surface facing
it, ``[1, 1, 0, 0]`` the fully polarized light expressed in its field's
basis, ``C_light`` the rotation into Mitsuba's basis of the incident beam,
``M`` the pBRDF between Mitsuba's implicit bases (1/sr) and ``C_cam`` the
rotation into the image's Stokes frame (x = image right, y = image up, as
Mitsuba's ``stokes`` integrator writes it). The subsurface lobe is linear in
``rho_sss``, so it is returned per unit albedo and the per-band images are
``glossy + rho_sss[band] * subsurface``; this is what lets the stages solve
for ``rho_sss`` in closed form (:func:`polarbssrdf.inverse.polarimetric.optimize.solve_subsurface_albedo`).

Local albedo: the subsurface lobe here is the supplement's local
``rho_bar_sss`` (sec. 5.1), the apparent albedo of the diffused light at the
exit texel; the texture-space blur is the biophysical stage's business.

With ``coaxial=True`` the light direction is replaced by the view direction
(the approximation of the authors' code, kept for the ablation).
"""

from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.optics.mueller import coordinate_system, stokes_basis, stokes_basis_rotation_sincos
from polarbssrdf.optics.pbrdf import pbrdf_mueller
from polarbssrdf.optics.stokes import polarization_images

GLOSSY_PARAMETERS = ("eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss")
"""The per-texel parameters of the glossy lobes (the subsurface lobe adds ``rho_sss`` per band)."""


def jit_types():
    """``(Float, Array3f, UInt32, TensorXf)`` of the active Mitsuba variant (a JIT AD variant)."""

    if not mi.variant() or not dr.is_jit_v(mi.Float) or not dr.is_diff_v(mi.Float):
        raise RuntimeError("the inverse stages need a JIT autodiff Mitsuba variant such as "
                           f"llvm_ad_mono_polarized or cuda_ad_mono_polarized (active: {mi.variant()})")
    return mi.Float, mi.Vector3f, mi.UInt32, mi.TensorXf


@dataclasses.dataclass
class ViewGeometry:
    """Per texel-view geometry as Dr.Jit arrays (object space, unit vectors, mm).

    Attributes
    ----------
    to_camera, to_light : Array3f
        Directions from the texel to the camera centre and to the light.
    irradiance : Float
        ``I / d^2`` of the light at the texel, on a surface facing it (W/mm^2
        for intensities in W/sr).
    light_field : Array3f
        Electric-field direction of the incident light (perpendicular to ``to_light``).
    camera_basis : Array3f
        The image's Stokes x axis for this ray (perpendicular to ``to_camera``).
    """

    to_camera: object
    to_light: object
    irradiance: object
    light_field: object
    camera_basis: object

    @classmethod
    def from_texel_views(cls, views):
        """Geometry of :class:`polarbssrdf.inverse.observations.build.TexelViews` (NumPy) as Dr.Jit arrays."""
        Float, Array3f, _, _ = jit_types()

        def vector(values):
            values = np.asarray(values, dtype=np.float32)
            return Array3f(*[to_jit(Float, values[:, k]) for k in range(3)])

        irradiance = (np.asarray(views.light_intensity, np.float64)
                      / np.square(np.asarray(views.light_distance_mm, np.float64)))
        return cls(to_camera=vector(views.to_camera), to_light=vector(views.to_light),
                   irradiance=to_jit(Float, irradiance, np.float32),
                   light_field=vector(views.light_field), camera_basis=vector(views.camera_basis))


def _to_local(vector, frame):
    s, t, n = frame
    return type(vector)(dr.dot(vector, s), dr.dot(vector, t), dr.dot(vector, n))


def shading_frame(normal):
    """Orthonormal ``(s, t, n)`` of unit normals (Mitsuba's ``coordinate_system``)."""
    s, t = coordinate_system(normal)
    return s, t, normal


def _stokes_columns(M, irradiance, field_rotation, camera_rotation, cos_light):
    """Linear Stokes ``(S0, S1, S2)`` in the camera frame of light polarized along its field.

    ``C(camera) M C(field) [E, E, 0, 0] cos``: only the first two columns of
    ``M`` meet fully polarized light. The rotations are ``(sin 2 theta,
    cos 2 theta)`` pairs (:func:`polarbssrdf.optics.mueller.stokes_basis_rotation_sincos`).
    """
    s_in, c_in = field_rotation
    # incident Stokes in Mitsuba's basis of the incident beam: C(angle) [1, 1, 0, 0]
    incident = (1.0, c_in, -s_in)
    column = [M[row][0] * incident[0] + M[row][1] * incident[1] + M[row][2] * incident[2]
              for row in range(3)]
    s_out, c_out = camera_rotation
    scale = irradiance * dr.maximum(cos_light, 0.0)
    return (scale * column[0],
            scale * (c_out * column[1] + s_out * column[2]),
            scale * (-s_out * column[1] + c_out * column[2]))


@dataclasses.dataclass
class PredictedStokes:
    """``(S0, S1, S2)`` per texel-view in the camera frame: glossy lobes, and subsurface per unit albedo."""

    glossy: tuple
    subsurface: tuple

    def analyser_images(self, rho_sss):
        """``(I0, I45, I90, I135)`` for a subsurface albedo ``rho_sss`` (one band)."""
        S = tuple(g + rho_sss * s for g, s in zip(self.glossy, self.subsurface))
        return polarization_images(S + (0.0,))


def predict_stokes(geometry, normal, eta, rho_s, alpha_s, rho_ss, alpha_ss, coaxial=False):
    """Predicted Stokes vectors of every texel-view (see the module docstring).

    Parameters
    ----------
    geometry : ViewGeometry
    normal : Array3f
        Unit shading normal per texel-view (object space).
    eta, rho_s, alpha_s, rho_ss, alpha_ss : Float
        pBRDF parameters per texel-view.
    coaxial : bool
        Take the light direction equal to the view direction (ablation).

    Returns
    -------
    PredictedStokes
    """
    frame = shading_frame(normal)
    to_light = geometry.to_camera if coaxial else geometry.to_light
    light_field = geometry.light_field
    if coaxial:
        # keep the field perpendicular to the (now coaxial) beam
        light_field = dr.normalize(light_field - dr.dot(light_field, to_light) * to_light)
    wi = _to_local(geometry.to_camera, frame)  # leaves toward the camera
    wo = _to_local(to_light, frame)  # light arrives along -wo
    field = _to_local(light_field, frame)
    camera_basis = _to_local(geometry.camera_basis, frame)
    field_rotation = stokes_basis_rotation_sincos(-wo, field, stokes_basis(-wo))
    camera_rotation = stokes_basis_rotation_sincos(wi, stokes_basis(wi), camera_basis)
    glossy = pbrdf_mueller(wi, wo, eta, rho_s, alpha_s, rho_ss, alpha_ss, 0.0, subsurface=False)
    subsurface = pbrdf_mueller(wi, wo, eta, 0.0, 1.0, 0.0, 1.0, 1.0, specular=False,
                               single_scattering=False)
    return PredictedStokes(
        glossy=_stokes_columns(glossy, geometry.irradiance, field_rotation, camera_rotation, wo.z),
        subsurface=_stokes_columns(subsurface, geometry.irradiance, field_rotation, camera_rotation,
                                   wo.z))


def half_vector_cosine(geometry, normal):
    """``cos(theta_h)`` between the normal and the half vector of light and view."""
    h = dr.normalize(geometry.to_camera + geometry.to_light)
    return dr.dot(h, normal)
