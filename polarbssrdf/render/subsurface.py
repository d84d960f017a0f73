"""Texture-space subsurface scattering: light into each texel, diffused, and out (eq. 13, 44).

1. :func:`transmitted_irradiance`: per texel, the irradiance of each polarized
   point light (``ppoint``) that crosses the surface, ``I / d^2 cos(theta_i)
   (T+ + T- cos 2 psi)`` with shadowing (the entry factor of ``pbssrdf``'s
   subsurface lobe, :func:`polarbssrdf.optics.pbrdf.subsurface_entry_stokes_row`,
   written in world space: ``psi`` is the angle between the light's field and
   the s axis of the plane of incidence).
2. :func:`diffused_exitance`: ``M = G * (rho_sss E)``, the albedo-weighted
   transmitted irradiance blurred by the normalized sum of Gaussians of the
   skin's reflectance profile (eq. 44-45; ``rho_sss`` is the lobe albedo of
   eq. 19).
3. The ``pexitance`` emitter turns ``M`` into radiance leaving through Fresnel
   transmission (:mod:`polarbssrdf.plugins.pexitance`).

Energy: ``pexitance`` emits ``M T+(theta_o) / pi``, whose hemispherical
integral is ``c(eta) M`` with ``c(eta) = int T+ cos / pi``
(:func:`subsurface_exit_fraction`, 0.92 at eta 1.42). The multipole totals
``R_bar`` (eq. 42, 47) already are the flux that leaves through the surface,
so the lobe albedo of a skin is ``rho_sss = R_bar / c(eta)``, and the
exitance of the layered model (:func:`layered_exitance`, flux ``R_bar E``)
is handed to ``pexitance`` as ``layered_exitance / c(eta)``
(:func:`emitted_exitance`); see docs/biophysical.md.

Without blur, ``M = rho_sss E`` and 1-3 reproduce ``pbssrdf``'s local
subsurface lobe exactly (up to texture interpolation).
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import to_jit
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
                        to_jit(mi.Float, distance - 2 * shadow_epsilon_mm, np.float32))
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


LAYER_PROFILES = ("R_out_f", "T_out_f", "R_out_b", "T_out_b", "R_in")
_DELTA_VARIANCE_MM2 = 1e-8  # a Gaussian far below any texel: the identity


def layer_totals_maps(maps, spectral):
    """Per quadrature node, the five layer totals (eq. 42) at every texel, from the biophysical maps.

    Parameters
    ----------
    maps : dict
        (T, T) maps ``C_m, beta_m, C_h_out, C_h_in`` and ``eta``; optional ``gamma``
        (the blood's oxygen fraction) and ``thickness_mm`` (the epidermis, mm) maps,
        else the model's defaults (0.75, 0.25 mm).
    spectral : SpectralQuadrature or list of Band
        The nodes (:func:`polarbssrdf.skin.quadrature.as_quadrature`: bands get the band
        integral's quadrature).

    Returns
    -------
    list of ``LayerTotals`` with (T, T) fields, one per node.
    """
    from polarbssrdf.skin.layers import absorption_from_basis
    from polarbssrdf.skin.model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM
    from polarbssrdf.skin.quadrature import as_quadrature
    from polarbssrdf.skin.twolayer import layer_totals

    basis = as_quadrature(spectral).basis
    gamma = maps.get("gamma", DEFAULT_GAMMA)
    thickness = maps.get("thickness_mm", DEFAULT_THICKNESS_MM)
    sigma_a_out, sigma_a_in = absorption_from_basis(basis, maps["C_m"], maps["beta_m"], maps["C_h_out"],
                                                    maps["C_h_in"], gamma)
    return [layer_totals(sigma_a_out[..., q], basis["scattering_epidermis"][q],
                         sigma_a_in[..., q], basis["scattering_dermis"][q], thickness, maps["eta"])
            for q in range(sigma_a_out.shape[-1])]


def layer_profile_kernels(spectral, skin):
    """Per quadrature node, ``name -> (weights, variances mm^2)``: normalized SoG of each layer
    profile (eq. 43) at that node's coefficients.

    Fitted at the base parameters ``skin`` (``SkinParameters``, its ``gamma``,
    ``thickness_mm`` and ``eta`` included), since the blur is taken as spatially
    homogeneous (eq. 45). The unscattered part of the epidermis transmittance, a delta
    at r = 0, enters as an identity term weighted by its share of the total.
    ``spectral``: a SpectralQuadrature or bands (their band integral's quadrature).
    """
    from polarbssrdf.skin.layers import absorption_from_basis
    from polarbssrdf.skin.multipole import ballistic_totals, slab_profiles
    from polarbssrdf.skin.quadrature import as_quadrature
    from polarbssrdf.skin.sog import fit_sog, variance_ladder
    from polarbssrdf.skin.twolayer import radial_energy

    basis = as_quadrature(spectral).basis
    sa_out, sa_in = absorption_from_basis(basis, skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in, skin.gamma)
    r = np.concatenate([[0.0], np.geomspace(1e-4, 30.0, 300)])
    ladder = variance_ladder()
    kernels = []
    for q in range(np.shape(sa_out)[-1]):
        ss_out, ss_in = basis["scattering_epidermis"][q], basis["scattering_dermis"][q]
        d, eta = skin.thickness_mm, skin.eta
        R_f, T_f = slab_profiles(r, sa_out[q], ss_out, d, eta, 1.0)
        R_b, T_b = slab_profiles(r, sa_out[q], ss_out, d, 1.0, eta, incidence="diffuse")
        R_in, _ = slab_profiles(r, sa_in[q], ss_in, np.inf, 1.0, 1.0)
        _, T_f_ball = ballistic_totals(sa_out[q], ss_out, d, eta, 1.0)
        _, T_b_ball = ballistic_totals(sa_out[q], ss_out, d, 1.0, eta, incidence="diffuse")
        profiles = {"R_out_f": (R_f, 0.0), "T_out_f": (T_f, T_f_ball), "R_out_b": (R_b, 0.0),
                    "T_out_b": (T_b, T_b_ball), "R_in": (R_in, 0.0)}
        node_kernels = {}
        for name, (profile, ballistic) in profiles.items():
            weights = np.clip(fit_sog(r, profile, ladder), 0.0, None)
            diffuse = radial_energy(r, profile)
            share = float(ballistic) / max(float(ballistic) + diffuse, 1e-30)
            weights = (1.0 - share) * weights / max(weights.sum(), 1e-30)
            node_kernels[name] = (np.concatenate([[share], weights]),
                                  np.concatenate([[_DELTA_VARIANCE_MM2], ladder]))
        kernels.append(node_kernels)
    return kernels


def band_exitances(irradiance, totals, kernels, weights, atlas, tolerance=1e-4, round_trips=None):
    """Per band, the exitance below the surface (eq. 46) integrated over the band: ``M_b = sum_q
    w_bq M_q`` with ``M_q`` the :func:`layered_exitance` of quadrature node ``q`` (its own
    layer totals and profiles; the diffusion depends on wavelength as the reflectance does).

    ``totals``, ``kernels``: per node (:func:`layer_totals_maps`, :func:`layer_profile_kernels`);
    ``weights``: the quadrature's (n_bands, Q). Each node is diffused once, whatever the
    bands that share it. NumPy or Dr.Jit inputs as :func:`layered_exitance` takes them
    (``tolerance``, ``round_trips``: its series)."""
    weights = np.asarray(weights, dtype=np.float64)
    used = np.flatnonzero(np.any(weights > 0, axis=0))
    nodes = {q: layered_exitance(irradiance, totals[q], kernels[q], atlas, tolerance, round_trips=round_trips)
             for q in used}

    def scaled(value, weight):
        if isinstance(value, np.ndarray):
            return value.astype(np.float64) * weight
        import drjit as dr

        # the weights follow the bands: kernel inputs, not literals
        return type(value)(value.array * dr.opaque(type(value.array), weight), value.shape)

    out = []
    for row in weights:
        total = None
        for q in used:
            if row[q] > 0:
                term = scaled(nodes[q], float(row[q]))
                total = term if total is None else total + term
        out.append(total.astype(np.float32) if isinstance(total, np.ndarray) else total)
    return out


def layered_exitance(irradiance, totals, kernels, atlas, tolerance=1e-4, max_interreflections=16,
                     round_trips=None):
    """Exitance below the surface from the two layers' profiles blurred in texture space; eq. 46.

    ``M = G_Rof * (R_of E) + G_Tob * (T_ob S)``, with ``S`` the light the
    dermis sends up, including the inter-reflections between the layers:
    ``S = sum_n (G_Rin * R_in  G_Rob * R_ob)^n  G_Rin * (R_in  G_Tof * (T_of E))``
    (each ``G * X`` a texture-space blur of the per-texel product ``X``). The
    series stops after the terms that keep the next below ``tolerance`` of the
    first, bounded by ``max(R_in) max(R_out_b)`` per round trip.
    Without blur this is ``R_bar E`` with ``R_bar`` of eq. 47: the flux that
    leaves the skin (divide by :func:`subsurface_exit_fraction` for the map
    ``pexitance`` takes, :func:`emitted_exitance`).

    Parameters
    ----------
    irradiance : (T, T) array or Dr.Jit TensorXf
        Transmitted irradiance ``E`` (:func:`transmitted_irradiance`).
    totals : LayerTotals
        Per-texel layer totals of one band (:func:`layer_totals_maps`), NumPy
        arrays, or Dr.Jit tensors (then the result is a TensorXf of the same
        backend, differentiable with respect to the totals and ``E``).
    kernels : dict
        That band's normalized kernels (:func:`layer_profile_kernels`).
    atlas : TexelAtlas
    tolerance, max_interreflections : float, int
        Where the series stops (see above).
    round_trips : int, optional
        An approximation (None, the default, sums the series): this many
        round trips between the layers are blurred, the rest of the series is
        closed per texel as the geometric tail ``u_N r / (1 - r)`` of the last
        term ``u_N``, with ``r = u_N / u_(N-1)`` the decay the last blurred
        round trip showed (``R_in R_out_b`` if none was blurred; exact for maps
        constant over the blurs' reach). The biophysical fit uses it; synth
        does not (error measured in the tests: the observed decay closes a face
        with freckles 4-10x closer than the local ``R_in R_out_b``).
    """
    from_numpy = isinstance(totals.R_out_f, np.ndarray) and isinstance(irradiance, np.ndarray)

    def blur(name, values):
        weights, variances = kernels[name]
        return blur_sum_of_gaussians(values, weights, variances, atlas.texel_size_mm, atlas.valid)

    def peak(values):
        if from_numpy:
            return float(np.abs(values).max())
        import drjit as dr

        return float(dr.max(dr.abs(dr.detach(values.array)), axis=None)[0])

    into_dermis = blur("T_out_f", totals.T_out_f * irradiance)
    upward = blur("R_in", totals.R_in * into_dermis)
    total_upward = upward
    # a normalized blur never raises a map's peak, so each round trip between the
    # layers shrinks the light by at least max(R_in) max(R_out_b): the terms that
    # keep every later one below ``tolerance`` of the first are known up front (one
    # read-back instead of one per term)
    if round_trips is None:
        ratio = peak(totals.R_in) * peak(totals.R_out_b)
        rounds = max_interreflections if ratio >= 1.0 else (
            0 if ratio <= 0.0 else min(max_interreflections,
                                       int(np.ceil(np.log(tolerance) / np.log(ratio)))))
    else:
        rounds = int(round_trips)
    previous = None
    for _ in range(rounds):
        previous = upward
        upward = blur("R_in", totals.R_in * blur("R_out_b", totals.R_out_b * upward))
        total_upward = total_upward + upward
    if round_trips is not None:
        if previous is None:  # no round trip blurred: the local ratio
            ratio = totals.R_in * totals.R_out_b
        else:  # the decay the last blurred round trip showed, per texel
            ratio = _clipped_ratio(upward, previous)
        total_upward = total_upward + upward * ratio / (1.0 - ratio)
    exitance = (blur("R_out_f", totals.R_out_f * irradiance)
                + blur("T_out_b", totals.T_out_b * total_upward))
    return exitance.astype(np.float32) if from_numpy else exitance


def _clipped_ratio(numerator, denominator, largest=0.95):
    """``numerator / denominator`` per texel in [0, largest] (0 where the denominator is 0)."""
    if isinstance(numerator, np.ndarray):
        safe = np.where(denominator > 0, denominator, 1.0)
        return np.clip(np.where(denominator > 0, numerator / safe, 0.0), 0.0, largest)
    import drjit as dr

    positive = denominator.array > 0
    ratio = dr.select(positive, numerator.array / dr.select(positive, denominator.array, 1.0), 0.0)
    return type(numerator)(dr.clip(ratio, 0.0, largest), numerator.shape)


_EXIT_QUADRATURE = 64
_EXIT_TABLE_NODES = 4096


def subsurface_exit_fraction(eta):
    """``c(eta) = int T+(theta) cos(theta) / pi dw`` over the hemisphere, unitless.

    The share of an exitance ``M`` that ``pexitance`` (and the subsurface lobe
    of eq. 19, ``rho_sss E T+(theta_o) / pi``) actually emits: its radiance
    ``M T+(theta_o) / pi`` integrates to ``c(eta) M``. ``T+`` is
    :func:`polarbssrdf.optics.fresnel.fresnel_transmittance` (the function the
    exit column uses) for light leaving a medium of relative index ``eta``
    (reciprocity: the same as entering it), integrated by 64-point
    Gauss-Legendre in ``cos(theta)``: 0.939, 0.920, 0.894 at eta 1.3, 1.42,
    1.6. Broadcasts over arrays of eta (> 0)."""
    eta = np.asarray(eta, dtype=np.float64)
    if not np.all(np.isfinite(eta) & (eta > 0)):
        raise ValueError("eta must be finite and > 0")
    x, w = np.polynomial.legendre.leggauss(_EXIT_QUADRATURE)
    mu, w = 0.5 * (x + 1.0), 0.5 * w
    flat = np.ravel(eta)

    def integral(values):
        T_plus, _ = plus_minus(*fresnel_transmittance(mu[None, :], values[:, None]))
        return 2.0 * np.asarray(T_plus, dtype=np.float64) @ (mu * w)

    if flat.size <= _EXIT_TABLE_NODES:
        return integral(flat).reshape(eta.shape)
    # a map: c(eta) is smooth, so a fine table interpolates it to < 1e-9
    low, high = float(flat.min()), float(flat.max())
    if high - low < 1e-12:
        return np.full(eta.shape, float(integral(np.array([low]))[0]))
    nodes = np.linspace(low, high, _EXIT_TABLE_NODES)
    return np.interp(flat, nodes, integral(nodes)).reshape(eta.shape)


def emitted_exitance(exitance, eta):
    """The map to hand ``pexitance`` so that it emits the flux ``exitance``: ``M / c(eta)``.

    ``exitance`` is a flux leaving the surface (:func:`layered_exitance`,
    ``R_bar E``); ``pexitance`` emits ``c(eta)`` of the map it gets
    (:func:`subsurface_exit_fraction`). float32 (T, T)."""
    return (np.asarray(exitance, dtype=np.float64) / subsurface_exit_fraction(eta)).astype(np.float32)
