"""Two layers: epidermis slab over a semi-infinite dermis.

Per-pixel totals (supplement eq. 47) and the combined radial reflectance
profile (eq. 15) via Hankel transforms. Lengths in mm, coefficients 1/mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .multipole import ballistic_totals, diffuse_unscattered_fraction, slab_totals


@dataclass(frozen=True)
class LayerTotals:
    """Totals (or, at k > 0, Hankel transforms) of the five layer profiles:
    epidermis forward/backward reflectance and transmittance, dermis
    forward reflectance. Unitless arrays of a common shape."""

    R_out_f: np.ndarray
    T_out_f: np.ndarray
    R_out_b: np.ndarray
    T_out_b: np.ndarray
    R_in: np.ndarray


def layer_totals(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in=None, k=0.0) -> LayerTotals:
    """Closed-form multipole totals of the layers (eq. 42 with alpha'/2).

    sigma_* in 1/mm, thickness_mm the epidermis thickness (mm), eta_out the
    epidermis index (outside is air, n = 1), eta_in the dermis index
    (default eta_out: an index-matched inner boundary). k (1/mm) selects the
    Hankel transform instead of the total. The backward epidermis quantities
    swap its two boundaries and use diffuse incidence (the light the dermis
    sends back is diffuse; see :mod:`.multipole`); the dermis is
    semi-infinite (dipole limit of eq. 9, lit by the forward transmittance,
    which the model treats as collimated like eq. 11).
    """
    eta_out = np.asarray(eta_out, dtype=float)
    eta_in = eta_out if eta_in is None else np.asarray(eta_in, dtype=float)
    inner_relative = eta_out / eta_in  # epidermis relative to dermis
    R_f, T_f = slab_totals(sigma_a_out, sigma_s_out, thickness_mm, eta_out, inner_relative, k)
    R_b, T_b = slab_totals(sigma_a_out, sigma_s_out, thickness_mm, inner_relative, eta_out, k, incidence="diffuse")
    R_in, _ = slab_totals(sigma_a_in, sigma_s_in, np.inf, 1.0 / inner_relative, 1.0, k)
    return LayerTotals(R_f, T_f, R_b, T_b, R_in)


def two_layer_total(R_out_f, T_out_f, R_out_b, T_out_b, R_in):
    """Eq. 47 in closed form (geometric series of the inter-reflections):
    R = R_out_f + T_out_f R_in T_out_b / (1 - R_out_b R_in). Unitless.
    Also valid for Hankel transforms at one k (eq. 15 in frequency space)."""
    return R_out_f + T_out_f * R_in * T_out_b / (1.0 - R_out_b * R_in)


def two_layer_total_from_coefficients(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in=None):
    """Total diffuse reflectance of the two-layer skin (eq. 47), unitless."""
    t = layer_totals(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in)
    return two_layer_total(t.R_out_f, t.T_out_f, t.R_out_b, t.T_out_b, t.R_in)


def inverse_hankel(k, transform, r):
    """f(r) = 1/(2 pi) int F(k) J0(k r) k dk (1/mm^2) by the trapezoid rule
    on a uniform k grid starting at 0 (1/mm), with the Euler-Maclaurin end
    correction h^2 g'(0) / 12 for the integrand g(k) = k F(k) J0(k r)
    (g'(0) = F(0); without it the result is offset by -h^2 F(0) / (24 pi)).
    r in mm; F sampled at k and negligible at k[-1]."""
    k = np.asarray(k, dtype=float)
    h = k[1] - k[0]
    if k[0] != 0.0 or not np.allclose(np.diff(k), h, rtol=1e-6, atol=0.0):
        raise ValueError("inverse_hankel needs a uniform k grid starting at 0")
    weights = np.full_like(k, h)
    weights[0] = 0.5 * (k[1] - k[0])
    weights[-1] = 0.5 * (k[-1] - k[-2])
    kernel_weight = transform * k * weights / (2.0 * np.pi)
    from scipy.special import j0  # imported here: scipy.special is slow to import

    r = np.asarray(r, dtype=float)
    out = np.empty(r.shape)
    flat = r.ravel()
    out_flat = out.reshape(-1)
    for start in range(0, flat.size, 64):
        chunk = flat[start:start + 64]
        out_flat[start:start + 64] = j0(chunk[:, None] * k[None, :]) @ kernel_weight
    return out + h * h * float(np.ravel(transform)[0]) / (24.0 * np.pi)


def two_layer_profile(r, sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in=None,
                      r_max=None, k_max=None):
    """Combined reflectance profile R(r) (1/mm^2) of eq. 15 for scalar
    coefficients, r in mm.

    Each layer profile's Hankel transform is the multipole total with
    sigma_tr -> sqrt(sigma_tr^2 + k^2) (exact for the pole sums), so the
    convolutions and the inter-reflection series of eq. 15 become products
    and a geometric series per k; the result is transformed back
    numerically. The k grid spacing resolves r up to ``r_max`` (default
    max(r)), k_max defaults to 60 / (epidermis source depth). The unscattered
    beam reflected by a mismatched inner boundary (a delta at r = 0, zero when
    both layers share eta) is left out of the returned profile."""
    from .multipole import source_depth_and_strength

    r = np.asarray(r, dtype=float)
    if r_max is None:
        r_max = float(np.max(r))
    if k_max is None:
        z_s, _, _ = source_depth_and_strength(sigma_a_out, sigma_s_out, thickness_mm)
        k_max = 60.0 / float(z_s)
    dk = min(0.5 / max(r_max, 1e-3), k_max / 200.0)
    k = np.arange(0.0, k_max + dk, dk)
    t = layer_totals(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in, k=k)
    transform = two_layer_total(t.R_out_f, t.T_out_f, t.R_out_b, t.T_out_b, t.R_in)
    eta_in_ = eta_out if eta_in is None else eta_in
    delta, _ = ballistic_totals(sigma_a_out, sigma_s_out, thickness_mm, eta_out, float(eta_out) / float(eta_in_))
    return inverse_hankel(k, transform - delta, r)


def radial_energy(r, profile):
    """2 pi int R(r) r dr by the trapezoid rule on the (increasing) r grid."""
    r = np.asarray(r, dtype=float)
    return float(np.trapezoid(2.0 * np.pi * r * np.asarray(profile), r))


def boundary_terms(eta_out, eta_in=None) -> dict:
    """Boundary constants of the two-layer model for :func:`two_layer_total_kernel`:
    A and the exitance coefficients (C_phi, C_E) of the air / epidermis face
    and of both sides of the epidermis / dermis face (exact Fresnel moments,
    see :mod:`.multipole`), normal-incidence Fresnel and F_dr = 2 C_1."""
    from .multipole import (
        diffuse_fresnel_reflectance,
        exitance_coefficients,
        internal_reflection_parameter,
        normal_fresnel_reflectance,
    )

    eta_out = np.asarray(eta_out, dtype=float)
    eta_in = eta_out if eta_in is None else np.asarray(eta_in, dtype=float)
    inner = eta_out / eta_in
    cphi_top, ce_top = exitance_coefficients(eta_out)
    cphi_inner, ce_inner = exitance_coefficients(inner)
    cphi_dermis, ce_dermis = exitance_coefficients(1.0 / inner)
    return {
        "A_top": internal_reflection_parameter(eta_out),
        "A_inner": internal_reflection_parameter(inner),
        "A_dermis": internal_reflection_parameter(1.0 / inner),
        "Cphi_top": cphi_top, "CE_top": ce_top,
        "Cphi_inner": cphi_inner, "CE_inner": ce_inner,
        "Cphi_dermis": cphi_dermis, "CE_dermis": ce_dermis,
        "Rn_top": normal_fresnel_reflectance(eta_out),
        "Rn_inner": normal_fresnel_reflectance(inner),
        "F_top": diffuse_fresnel_reflectance(eta_out),
        "F_inner": diffuse_fresnel_reflectance(inner),
    }


def _face(near, s, D, zb, c_phi, c_e):
    """C_E (e^{-s z} + e^{-s (z + 2 z_b)}) + C_phi (e^{-s z} - e^{-s (z + 2 z_b)}) / (D s)."""
    e1 = np.exp(-s * near)
    g = -np.expm1(-2.0 * s * zb)
    return e1 * (c_e * (2.0 - g) + c_phi * g / (D * s))


def _slab_pair(strength, z_s, z_t, s, D, d, zb_in, zb_out, c_in, c_out):
    """Closed-form multipole (R, T) for a source at z_s (z_t for the exit face) with extrapolation
    distances zb_in (entry face) and zb_out (exit face) and the exitance
    coefficients c_in / c_out = (C_phi, C_E) of the faces, with the energy
    guard; see multipole.slab_totals."""
    length = d + zb_in + zb_out
    den = -np.expm1(-2.0 * s * length)
    half = 0.5 * strength / den
    refl = half * _face(z_s, s, D, zb_in, *c_in) * -np.expm1(-2.0 * s * (length - z_s - zb_in))
    trans = half * _face(d - z_t, s, D, zb_out, *c_out) * -np.expm1(-2.0 * s * (z_t + zb_in))
    total = refl + trans
    guard = np.where(total > strength, strength / np.where(total > 0, total, 1.0), 1.0)  # multipole.energy_guard
    return guard * refl, guard * trans


def _source_depths(rate, s, d, inv_s):
    """(z_R, z_T) of multipole.collimated_source_depths for a finite d and s > 0
    (the general-case branches left out; keeps the dtype)."""
    collided = -np.expm1(-rate * d)
    z_r = np.log((1.0 + s / rate) * collided / -np.expm1(-(rate + s) * d)) * inv_s
    wd = (rate - s) * d
    spread = np.where(np.abs(wd) > 1e-12, -np.expm1(-wd) / np.where(wd == 0, 1.0, rate - s), d)
    z_t = np.log(rate * spread / collided) * inv_s
    return z_r, z_t


def epidermis_totals_kernel(sigma_a_out, sigma_s_out, thickness_mm, b):
    """(R_out_f, T_out_f, R_out_b, T_out_b) of :func:`layer_totals` at k = 0,
    sub-expressions shared; pure array math for sigma_a > 0 and a finite
    thickness (keeps the dtype). ``b`` is :func:`boundary_terms`. The source
    depths are those of :mod:`.multipole` (per face, truncated extended
    source; collimated from the air, diffuse from the dermis)."""
    from .multipole import DIFFUSE_RATE

    d = thickness_mm
    st = sigma_a_out + sigma_s_out
    albedo = sigma_s_out / st
    s = np.sqrt(3.0 * sigma_a_out * st)
    inv_s = 1.0 / s
    tau = st * d
    D = 1.0 / (3.0 * st)
    zb_top = 2.0 * b["A_top"] * D
    zb_inner = 2.0 * b["A_inner"] * D
    c_top = (b["Cphi_top"], b["CE_top"])
    c_inner = (b["Cphi_inner"], b["CE_inner"])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        # forward: collimated from the air
        u_f = np.exp(-tau)
        z_f, zt_f = _source_depths(st, s, d, inv_s)
        R_f, T_f = _slab_pair(albedo * (1.0 - u_f), z_f, zt_f, s, D, d, zb_top, zb_inner, c_top, c_inner)
        bounce = 1.0 / (1.0 - b["Rn_top"] * b["Rn_inner"] * u_f * u_f)
        R_f = R_f + u_f * u_f * b["Rn_inner"] * (1.0 - b["Rn_top"]) * bounce
        T_f = T_f + u_f * (1.0 - b["Rn_inner"]) * bounce
        # backward: diffuse from the dermis
        u_b = diffuse_unscattered_fraction(tau)
        z_b, zt_b = _source_depths(DIFFUSE_RATE * st, s, d, inv_s)
        R_b, T_b = _slab_pair(albedo * (1.0 - u_b), z_b, zt_b, s, D, d, zb_inner, zb_top, c_inner, c_top)
    bounce = 1.0 / (1.0 - b["F_top"] * b["F_inner"] * u_b * u_b)
    R_b = R_b + u_b * u_b * b["F_top"] * (1.0 - b["F_inner"]) * bounce
    T_b = T_b + u_b * (1.0 - b["F_top"]) * bounce
    return R_f, T_f, R_b, T_b


def dermis_reflectance_kernel(sigma_a_in, sigma_s_in, b):
    """R_in of :func:`layer_totals` at k = 0: semi-infinite dipole with the
    extended-source depth, e^{-s z_e} = sigma_t' / (sigma_t' + s), and the
    fluence + flux exitance (:mod:`.multipole`)."""
    st_in = sigma_a_in + sigma_s_in
    s_in = np.sqrt(3.0 * sigma_a_in * st_in)
    D = 1.0 / (3.0 * st_in)
    g = -np.expm1(-2.0 * s_in * (2.0 * b["A_dermis"] * D))
    face = b["CE_dermis"] * (2.0 - g) + b["Cphi_dermis"] * g / (D * s_in)
    return 0.5 * sigma_s_in / (st_in + s_in) * face


def two_layer_total_kernel(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, b):
    """Eq. 47 with the closed-form layer totals of :func:`layer_totals`
    (same model, sub-expressions shared), pure array math. ``b`` is
    :func:`boundary_terms`. Reference: :func:`two_layer_total_from_coefficients`."""
    R_f, T_f, R_b, T_b = epidermis_totals_kernel(sigma_a_out, sigma_s_out, thickness_mm, b)
    return two_layer_total(R_f, T_f, R_b, T_b, dermis_reflectance_kernel(sigma_a_in, sigma_s_in, b))


def two_layer_total_fast(sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in, thickness_mm, eta_out, eta_in=None,
                         dtype=np.float64, chunk=1 << 16, workers=2):
    """Eq. 47 totals for large arrays: broadcasts the inputs, evaluates
    :func:`two_layer_total_kernel` in cache-sized chunks on ``workers``
    threads (NumPy releases the GIL), in ``dtype``. Returns the broadcast
    shape. Inputs are not modified."""
    from concurrent.futures import ThreadPoolExecutor

    terms = boundary_terms(eta_out, eta_in)
    names = list(terms)
    arrays = np.broadcast_arrays(*(np.asarray(x) for x in (sigma_a_out, sigma_s_out, sigma_a_in, sigma_s_in,
                                                           thickness_mm, *terms.values())))
    shape = arrays[0].shape
    flat = [np.ravel(x) for x in arrays]
    out = np.empty(int(np.prod(shape)), dtype=dtype)

    def run(start):
        stop = min(start + chunk, out.size)
        args = [x[start:stop].astype(dtype, copy=False) for x in flat]
        out[start:stop] = two_layer_total_kernel(*args[:5], dict(zip(names, args[5:])))

    starts = range(0, out.size, chunk)
    if workers > 1 and out.size > chunk:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(run, starts))
    else:
        for start in starts:
            run(start)
    return out.reshape(shape)
