"""Inversion of the two-layer skin model (supplement eq. 41): reflectance
spectra or per-band values -> (C_m, beta_m, C_h_out, C_h_in), vectorized
over texels.

Method: a lookup table of model outputs over a (C_m, beta_m, C_h_out,
C_h_in) grid gives each texel a nearest-neighbour start (scipy cKDTree on
the model outputs); then a few Levenberg-Marquardt steps run on all texels
at once. The Jacobian is cheap: the model depends on the four parameters
only through sigma_a of the two layers per sample, which is (bi)linear in
them, so two finite differences in (sigma_a_out, sigma_a_in) and the chain
rule give all four columns. Parameters are clipped to their bounds after
every step. gamma, thickness and eta are held fixed (scalars).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..spectral.bands import Band
from .chromophores import DEFAULT_REFRACTIVE_INDEX, check_wavelengths
from .layers import chromophore_basis
from .model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM, band_chromophore_basis
from .twolayer import (
    boundary_terms,
    dermis_reflectance_kernel,
    epidermis_totals_kernel,
    two_layer_total,
    two_layer_total_kernel,
)

PARAMETER_NAMES = ("C_m", "beta_m", "C_h_out", "C_h_in")
#: Bounds of the search (generous around Table 2).
BOUNDS = {"C_m": (0.001, 0.5), "beta_m": (0.0, 1.0), "C_h_out": (0.0, 0.3), "C_h_in": (0.001, 0.3)}


@dataclass(frozen=True)
class InversionResult:
    """Recovered parameters (arrays of the input's leading shape), the
    per-texel residual RMSE (reflectance units) and the model prediction."""

    C_m: np.ndarray
    beta_m: np.ndarray
    C_h_out: np.ndarray
    C_h_in: np.ndarray
    rmse: np.ndarray
    predicted: np.ndarray

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name in PARAMETER_NAMES + ("rmse",)}


class _Model:
    """Eq. 47 on a fixed set of samples (wavelengths or bands)."""

    def __init__(self, basis: dict, gamma: float, thickness_mm: float, eta: float):
        self.basis = {k: np.asarray(v, dtype=float) for k, v in basis.items()}
        self.d = float(thickness_mm)
        self.terms = {k: float(v) for k, v in boundary_terms(eta).items()}
        b = self.basis

    def absorption(self, p):
        b = self.basis
        cm, bm, cho, chi = (p[:, i:i + 1] for i in range(4))
        epi = cm * (bm * b["eumelanin"] + (1.0 - bm) * b["pheomelanin"]) + cho * b["blood"] + (1.0 - cm - cho) * b["baseline"]
        der = chi * b["blood"] + (1.0 - chi) * b["baseline"]
        return epi, der

    def totals(self, sa_out, sa_in):
        b = self.basis
        return two_layer_total_kernel(sa_out, b["scattering_epidermis"], sa_in, b["scattering_dermis"], self.d,
                                      self.terms)

    def __call__(self, p):
        return self.totals(*self.absorption(p))

    def value_and_jacobian(self, p):
        """Model (n, S) and Jacobian (n, S, 4) w.r.t. the four parameters:
        forward differences in sigma_a of each layer (the epidermis and dermis
        parts are evaluated separately), then the chain rule."""
        b = self.basis
        sa_out, sa_in = self.absorption(p)
        h_out = 1e-6 * (1.0 + sa_out)
        h_in = 1e-6 * (1.0 + sa_in)
        epi = epidermis_totals_kernel(sa_out, b["scattering_epidermis"], self.d, self.terms)
        epi_h = epidermis_totals_kernel(sa_out + h_out, b["scattering_epidermis"], self.d, self.terms)
        der = dermis_reflectance_kernel(sa_in, b["scattering_dermis"], self.terms)
        der_h = dermis_reflectance_kernel(sa_in + h_in, b["scattering_dermis"], self.terms)
        value = two_layer_total(*epi, der)
        d_out = (two_layer_total(*epi_h, der) - value) / h_out
        d_in = (two_layer_total(*epi, der_h) - value) / h_in
        cm, bm = p[:, 0:1], p[:, 1:2]
        melanin = bm * b["eumelanin"] + (1.0 - bm) * b["pheomelanin"]
        jac = np.stack([
            d_out * (melanin - b["baseline"]),
            d_out * cm * (b["eumelanin"] - b["pheomelanin"]),
            d_out * (b["blood"] - b["baseline"]),
            d_in * (b["blood"] - b["baseline"]),
        ], axis=-1)
        return value, jac


def _grid_axes(size: str = "default"):
    n = {"small": (10, 6, 7, 8), "default": (18, 11, 13, 16), "large": (28, 21, 19, 24)}[size]
    return (
        np.geomspace(*BOUNDS["C_m"], n[0]),
        np.linspace(*BOUNDS["beta_m"], n[1]),
        np.linspace(*BOUNDS["C_h_out"], n[2]),
        np.geomspace(*BOUNDS["C_h_in"], n[3]),
    )


@functools.lru_cache(maxsize=8)
def _table(key, size: str):
    """(parameter grid (M, 4), (mean, projection) of the outputs, KD-tree over
    the projected outputs); cached per samples (module-level LRU)."""
    model = _MODELS[key]
    axes = _grid_axes(size)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 4)
    values = np.concatenate([model(grid[i:i + 8192]) for i in range(0, len(grid), 8192)])
    # Nearest neighbours in at most 8 principal components of the outputs
    # (a KD-tree is slow in many dimensions; spectra are smooth).
    mean = values.mean(axis=0)
    if values.shape[1] > 8:
        _, _, vt = np.linalg.svd(values[:: max(1, len(values) // 20000)] - mean, full_matrices=False)
        projection = vt[:8].T
    else:
        projection = np.eye(values.shape[1])
    return grid, (mean, projection), cKDTree((values - mean) @ projection)


_MODELS: dict = {}


def _model_key(basis: dict, gamma, thickness_mm, eta):
    key = (tuple((k, np.asarray(v, dtype=float).tobytes()) for k, v in sorted(basis.items())), float(gamma),
           float(thickness_mm), float(eta))
    if key not in _MODELS:
        _MODELS[key] = _Model(basis, gamma, thickness_mm, eta)
    return key


def _levenberg_marquardt(model: _Model, observed, start, iterations: int, tolerance: float = 1e-6,
                         rmse_floor: float = 1e-7, step_tolerance: float = 1e-4):
    """Batched LM with Marquardt scaling and clipping to BOUNDS. A texel
    leaves the active set once an accepted step lowers its cost by less than
    ``tolerance`` (relative), its RMSE is below ``rmse_floor`` (reflectance
    units), it moves every parameter by less than ``step_tolerance`` of its
    bounds range, or its damping exceeds 1e4, so the later of the
    ``iterations`` steps only touch the slow texels."""
    lo = np.array([BOUNDS[n][0] for n in PARAMETER_NAMES])
    hi = np.array([BOUNDS[n][1] for n in PARAMETER_NAMES])
    span = hi - lo
    p = start.copy()
    value, jac = model.value_and_jacobian(p)
    resid = value - observed
    cost = np.einsum("ns,ns->n", resid, resid)
    lam = np.full(len(p), 1e-3)
    eye = np.eye(4)
    active = np.arange(len(p))
    for _ in range(iterations):
        if active.size == 0:
            break
        J, r, c, lm = jac[active], resid[active], cost[active], lam[active]
        jtj = np.einsum("nsi,nsj->nij", J, J)
        jtr = np.einsum("nsi,ns->ni", J, r)
        diag = np.einsum("nii->ni", jtj) + 1e-12
        lhs = jtj + (lm[:, None] * diag)[:, :, None] * eye
        step = np.linalg.solve(lhs, -jtr[..., None])[..., 0]
        p_before = p[active]
        trial = np.clip(p_before + step, lo, hi)
        t_value, t_jac = model.value_and_jacobian(trial)
        t_resid = t_value - observed[active]
        t_cost = np.einsum("ns,ns->n", t_resid, t_resid)
        better = t_cost < c
        idx = active[better]
        p[idx], value[idx], jac[idx], resid[idx], cost[idx] = trial[better], t_value[better], t_jac[better], t_resid[better], t_cost[better]
        lam[active] = np.where(better, lm * 0.3, lm * 10.0)
        floor = rmse_floor**2 * observed.shape[-1]
        moved = np.max(np.abs(trial - p_before) / span, axis=-1)
        done = (better & ((c - t_cost <= tolerance * c) | (t_cost < floor) | (moved < step_tolerance))) | (lam[active] > 1e4)
        active = active[~done]
    return p, value


def _invert(observed, basis, gamma, thickness_mm, eta, iterations, table_size, chunk, workers):
    observed = np.asarray(observed, dtype=float)
    n_samples = np.asarray(basis["eumelanin"]).shape[-1]
    if observed.shape[-1] != n_samples:
        raise ValueError(f"observations have {observed.shape[-1]} samples per texel, the model has {n_samples}")
    if not np.all(np.isfinite(observed)):
        raise ValueError("observations must be finite")
    lead = observed.shape[:-1]
    flat = observed.reshape(-1, n_samples)
    key = _model_key(basis, gamma, thickness_mm, eta)
    model = _MODELS[key]
    grid, (mean, projection), tree = _table(key, table_size)
    params = np.empty((len(flat), 4))
    predicted = np.empty_like(flat)

    def run(start):
        obs = flat[start:start + chunk]
        _, index = tree.query((obs - mean) @ projection)
        p, value = _levenberg_marquardt(model, obs, grid[index], iterations)
        params[start:start + chunk] = p
        predicted[start:start + chunk] = value

    starts = range(0, len(flat), chunk)
    if workers > 1 and len(flat) > chunk:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(run, starts))
    else:
        for start in starts:
            run(start)
    rmse = np.sqrt(np.mean((predicted - flat) ** 2, axis=-1))
    return InversionResult(*(params[:, i].reshape(lead) for i in range(4)), rmse.reshape(lead),
                           predicted.reshape(observed.shape))


def invert_spectra(reflectance, wavelengths_nm, gamma=DEFAULT_GAMMA, thickness_mm=DEFAULT_THICKNESS_MM,
                   eta=DEFAULT_REFRACTIVE_INDEX, iterations: int = 40, table_size: str = "default",
                   chunk: int = 4096, workers: int = 2) -> InversionResult:
    """Fit (C_m, beta_m, C_h_out, C_h_in) to total diffuse reflectance spectra
    (eq. 41 with the eq. 47 forward model).

    reflectance: array (..., n_wavelengths), unitless; wavelengths in nm
    (400-700). Returns an :class:`InversionResult` with arrays of shape (...).
    """
    wl = check_wavelengths(np.atleast_1d(wavelengths_nm))
    if wl.ndim != 1:
        raise ValueError("wavelengths must be 1-D")
    return _invert(reflectance, chromophore_basis(wl, gamma), gamma, thickness_mm, eta, iterations, table_size,
                   chunk, workers)


def invert_bands(band_values, bands: list[Band], gamma=DEFAULT_GAMMA, thickness_mm=DEFAULT_THICKNESS_MM,
                 eta=DEFAULT_REFRACTIVE_INDEX, iterations: int = 40, table_size: str = "large",
                 chunk: int = 8192, workers: int = 2) -> InversionResult:
    """Fit the four parameters to per-band reflectance (..., n_bands), using the
    band-effective forward model of :func:`~.model.band_reflectance`
    (method="effective", the per-band renderer's model)."""
    return _invert(band_values, band_chromophore_basis(bands, gamma), gamma, thickness_mm, eta, iterations,
                   table_size, chunk, workers)


def fit_spectrum(wavelengths_nm, reflectance, gamma=DEFAULT_GAMMA, thickness_mm=DEFAULT_THICKNESS_MM,
                 eta=DEFAULT_REFRACTIVE_INDEX) -> dict:
    """Fit one reflectance spectrum; returns a JSON-ready dict with C_m,
    beta_m, C_h_out, C_h_in and the fit RMSE (reflectance units)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    refl = np.asarray(reflectance, dtype=float)
    if wl.ndim != 1 or refl.shape != wl.shape:
        raise ValueError("wavelengths and reflectance must be 1-D arrays of the same length")
    if wl.size < 4:
        raise ValueError(f"need at least 4 wavelengths to fit 4 parameters, got {wl.size}")
    result = invert_spectra(refl[None, :], wl, gamma, thickness_mm, eta)
    out = {name: float(getattr(result, name)[0]) for name in PARAMETER_NAMES}
    out["rmse"] = float(result.rmse[0])
    return out
