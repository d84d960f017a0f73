"""Texture-space subsurface scattering: light into each texel, diffused, and out (eq. 13, 44).

1. :func:`transmitted_irradiance`: per texel, the irradiance of each polarized
   point light (``ppoint``) that crosses the surface, ``I / d^2 cos(theta_i)
   (T+ + T- cos 2 psi)`` with shadowing (the entry factor of ``pbssrdf``'s
   subsurface lobe, :func:`polarbssrdf.optics.pbrdf.subsurface_entry_stokes_row`,
   written in world space: ``psi`` is the angle between the light's field and
   the s axis of the plane of incidence).
2. :func:`diffused_exitance`: ``M = G * (rho_sss E)``, the albedo-weighted
   transmitted irradiance blurred by the normalized sum of Gaussians of the
   skin's reflectance profile (eq. 44-45; ``rho_sss`` is the total diffuse
   reflectance ``R_bar`` of eq. 47 at the entry point).
3. The ``pexitance`` emitter turns ``M`` into radiance leaving through Fresnel
   transmission (:mod:`polarbssrdf.plugins.pexitance`).

Without blur, ``M = rho_sss E`` and 1-3 reproduce ``pbssrdf``'s local
subsurface lobe exactly (up to texture interpolation).
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.optics.fresnel import fresnel_transmittance, plus_minus
from polarbssrdf.render.texture_diffusion import blur_sum_of_gaussians


def _ppoint_lights(scene):
    """The ``ppoint`` emitters of a scene, as (position, intensity, axis, absorption axis)."""
    import drjit as dr
    import mitsuba as mi

    lights = []
    for emitter in scene.emitters():
        if not hasattr(emitter, "polarization_axis"):
            continue
        si = dr.zeros(mi.SurfaceInteraction3f)
        if mi.is_spectral:
            raise ValueError("transmitted_irradiance: render bands in a mono variant "
                             "(band-integrated parameters); spectral variants are not supported")
        intensity = float(dr.ravel(emitter.intensity.eval(si)[0])[0])

        def vector(value):
            return None if value is None else np.array([dr.ravel(value[i])[0] for i in range(3)])

        lights.append((vector(emitter.position), intensity, vector(emitter.polarization_axis),
                       vector(emitter.absorption_axis)))
    if not lights:
        raise ValueError("transmitted_irradiance: the scene has no 'ppoint' light")
    return lights


def _polarization_field(direction, axis, absorption_axis):
    """Unit field direction(s) of light travelling along ``direction`` (N x 3) behind a polarizer."""
    if absorption_axis is None:
        field = axis[None, :] - np.sum(direction * axis, axis=1, keepdims=True) * direction
    else:
        field = np.cross(direction, absorption_axis[None, :])
    return field / np.maximum(np.linalg.norm(field, axis=1, keepdims=True), 1e-30)


def transmitted_irradiance(scene, atlas, eta, shadow_epsilon_mm=1e-3):
    """Irradiance transmitted into the surface at each texel, summed over the scene's ``ppoint`` lights.

    Parameters
    ----------
    scene : mitsuba.Scene
        Holds the lights and the occluders (the shape of the atlas included).
    atlas : TexelAtlas
        Texel positions and normals.
    eta : float or (T, T) array
        Relative refractive index per texel.

    Returns
    -------
    (T, T) float32 array, W/mm^2 for intensities in W/sr.
    """
    import mitsuba as mi

    valid = atlas.valid.ravel()
    p = atlas.position.reshape(-1, 3).astype(np.float64)[valid]
    n = atlas.normal.reshape(-1, 3).astype(np.float64)[valid]
    eta_texels = np.broadcast_to(np.asarray(eta, dtype=np.float64), atlas.valid.shape).ravel()[valid]
    total = np.zeros(len(p))
    for position, intensity, axis, absorption in _ppoint_lights(scene):
        to_light = position[None, :] - p
        distance = np.linalg.norm(to_light, axis=1)
        d = to_light / distance[:, None]
        cos_i = np.sum(n * d, axis=1)
        facing = cos_i > 0
        origin = p + n * shadow_epsilon_mm
        rays = mi.Ray3f(mi.Point3f(origin.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)),
                        mi.Float((distance - 2 * shadow_epsilon_mm).astype(np.float32)))
        visible = ~np.array(scene.ray_test(rays)) & facing
        T_plus, T_minus = plus_minus(*fresnel_transmittance(np.clip(cos_i, 0, 1), eta_texels))
        s_axis = np.cross(n, d)
        s_norm = np.linalg.norm(s_axis, axis=1, keepdims=True)
        s_axis = np.where(s_norm > 1e-9, s_axis / np.maximum(s_norm, 1e-30), 0.0)
        field = _polarization_field(-d, axis, absorption)
        cos_2psi = 2 * np.sum(field * s_axis, axis=1) ** 2 - 1
        entry = T_plus + np.where(s_norm[:, 0] > 1e-9, T_minus * cos_2psi, 0.0)
        total += np.where(visible, intensity / distance**2 * cos_i * entry, 0.0)
    out = np.zeros(atlas.valid.size)
    out[valid] = total
    return out.reshape(atlas.valid.shape).astype(np.float32)


def diffused_exitance(irradiance, rho_sss, atlas, sog_weights=(1.0,), sog_variances_mm2=(1e-6,)):
    """``M = G_Rbar * (rho_sss E)``: the exitance below the surface after diffusion; eq. 44-45.

    Parameters
    ----------
    irradiance : (T, T) array or TensorXf
        Transmitted irradiance ``E`` (:func:`transmitted_irradiance`).
    rho_sss : float, (T, T) array or TensorXf
        Total diffuse reflectance of the skin at each texel (the subsurface albedo).
    atlas : TexelAtlas
        Texel extents and validity.
    sog_weights, sog_variances_mm2 : sequences of float
        The normalized sum of Gaussians of the reflectance profile (weights
        summing to 1, variances in mm^2); the default is a 1 micrometre
        Gaussian, i.e. no blur.
    """
    return blur_sum_of_gaussians(irradiance * rho_sss, sog_weights, sog_variances_mm2,
                                 atlas.texel_size_mm, atlas.valid)
