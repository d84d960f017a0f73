"""Inversion of the two-layer skin model (supplement eq. 41): reflectance
spectra or per-band values -> (C_m, beta_m, C_h_out, C_h_in), vectorized
over texels.

Method: a lookup table of model outputs over a (C_m, beta_m, C_h_out,
C_h_in) grid gives each texel a nearest-neighbour start (scipy cKDTree on
the model outputs); then a few Levenberg-Marquardt steps run on all texels
at once, on a working set compacted as texels converge. The model depends on
the four parameters only through sigma_a of the two layers per sample
((bi)linear in them), and per sample the epidermis totals depend on the
epidermis sigma_a only and the dermis reflectance on the dermis sigma_a
only: the LM steps read them from 1-D cubic Hermite tables over ln sigma_a
(values and derivatives; see :class:`_Model`) and combine them with eq. 47
and the chain rule. Parameters are clipped to their bounds after every
step. gamma, thickness and eta are held fixed (scalars). Band values are
modelled as a spectral quadrature's nodes combined by its weights
(:mod:`.quadrature`), so the tables are per node. The reported
prediction and RMSE use the exact model.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..spectral.bands import Band
from .chromophores import DEFAULT_REFRACTIVE_INDEX, check_wavelengths
from .layers import blood_from_basis, chromophore_basis
from .model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM
from .quadrature import spectral_quadrature
from .twolayer import (
    boundary_terms,
    dermis_reflectance_kernel,
    epidermis_totals_kernel,
    two_layer_total_kernel,
)

PARAMETER_NAMES = ("C_m", "beta_m", "C_h_out", "C_h_in")
#: Nodes per sample of the ln sigma_a Hermite tables of the LM steps (see _Model).
TABLE_NODES = 1024
#: Further starts (next-nearest table entries) for texels that fit far worse than the median.
RESTARTS = 3
RESTART_COST_RATIO = 10.0
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
    """Eq. 47 on a fixed set of samples (wavelengths or bands).

    ``__call__`` is the exact closed-form model. :meth:`value_and_jacobian`,
    used by the Levenberg-Marquardt steps, reads the layer totals from
    per-sample tables instead: for each sample the four epidermis totals
    depend on sigma_a of the epidermis only and the dermis reflectance on
    sigma_a of the dermis only, so 1-D cubic Hermite tables over
    ln sigma_a (:data:`TABLE_NODES` nodes spanning every sigma_a the
    parameter bounds allow, node derivatives by central differences) give
    the values and exact derivatives of the interpolant; eq. 47 and its
    derivatives then combine them. Interpolation error < 1e-9 in reflectance
    (tests/skin/test_skin_inversion.py), far below any noise; the final
    prediction and RMSE use the exact model."""

    def __init__(self, basis: dict, gamma: float, thickness_mm: float, eta: float, projection=None):
        self.basis = {k: np.asarray(v, dtype=float) for k, v in basis.items()}
        self.basis["blood"] = blood_from_basis(self.basis, gamma)
        self.d = float(thickness_mm)
        self.terms = {k: float(v) for k, v in boundary_terms(eta).items()}
        # (n_outputs, n_samples) weights of a spectral quadrature, or None: outputs are the samples
        self.projection = None if projection is None else np.asarray(projection, dtype=float)
        self._tables = None

    def _project(self, values, jacobian=None):
        if self.projection is None:
            return values if jacobian is None else (values, jacobian)
        values = values @ self.projection.T
        if jacobian is None:
            return values
        return values, np.einsum("nsi,bs->nbi", jacobian, self.projection)

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
        return self._project(self.totals(*self.absorption(p)))

    def on_grid(self, axes, chunk=8192):
        """The model (M, n_outputs) on the tensor grid of ``axes`` (C_m, beta_m, C_h_out,
        C_h_in values), in the order of ``np.meshgrid(*axes, indexing="ij")`` flattened: what
        ``self(grid)`` gives, with the epidermis evaluated once per (C_m, beta_m, C_h_out) and
        the dermis once per C_h_in (the layers' separation of the class docstring), which cut a
        default table's build from 46 ms to a few (bench/RESULTS.md); projected in blocks of
        ``chunk`` rows."""
        upper = np.stack(np.meshgrid(*axes[:3], np.zeros(1), indexing="ij"), axis=-1).reshape(-1, 4)
        lower = np.stack([np.zeros(len(axes[3]))] * 3 + [np.asarray(axes[3], dtype=float)], axis=-1)
        sa_out, _ = self.absorption(upper)
        _, sa_in = self.absorption(lower)
        b = self.basis
        R_f, T_f, R_b, T_b = (x[:, None] for x in epidermis_totals_kernel(
            sa_out, b["scattering_epidermis"], self.d, self.terms))
        R_in = dermis_reflectance_kernel(sa_in, b["scattering_dermis"], self.terms)[None]
        totals = (R_f + T_f * R_in * T_b / (1.0 - R_b * R_in)).reshape(-1, sa_out.shape[-1])
        return np.concatenate([self._project(totals[i:i + chunk]) for i in range(0, len(totals), chunk)])

    def _layers(self, sa_out, sa_in):
        b = self.basis
        epi = epidermis_totals_kernel(sa_out, b["scattering_epidermis"], self.d, self.terms)
        return np.stack(epi, axis=-1), dermis_reflectance_kernel(sa_in, b["scattering_dermis"], self.terms)

    def tables(self):
        """Per layer: u0 and 1/h of the ln sigma_a grid of each sample and, per
        quantity, the cubic Hermite coefficients in t of every cell (from the
        node values f and slopes m = df/d ln sigma_a), flat over (sample, cell)."""
        if self._tables is None:
            corners = np.array(np.meshgrid(*[BOUNDS[n] for n in PARAMETER_NAMES], indexing="ij")).reshape(4, -1).T
            sa_out, sa_in = self.absorption(corners)
            grids = []
            for sa in (sa_out, sa_in):
                u0 = np.log(sa.min(axis=0) * 0.99)
                u1 = np.log(sa.max(axis=0) * 1.01)
                h = (u1 - u0) / (TABLE_NODES - 1)
                grids.append((u0, h, u0[None, :] + h[None, :] * np.arange(TABLE_NODES)[:, None]))  # (N, S)
            (u0_o, h_o, u_o), (u0_i, h_i, u_i) = grids
            delta = 1e-5
            f_o, f_i = self._layers(np.exp(u_o), np.exp(u_i))
            fp_o, fp_i = self._layers(np.exp(u_o + delta), np.exp(u_i + delta))
            fm_o, fm_i = self._layers(np.exp(u_o - delta), np.exp(u_i - delta))
            m_o = (fp_o - fm_o) / (2.0 * delta)  # (N, S, 4)
            m_i = (fp_i - fm_i) / (2.0 * delta)  # (N, S)

            def cells(f, m, h):
                """Cubic coefficients (a0, a1, a2, a3) in t per cell, one table per quantity."""
                f = np.moveaxis(f, 0, 1)  # (S, N[, q])
                m = np.moveaxis(m, 0, 1) * h.reshape((-1,) + (1,) * (m.ndim - 1))
                if f.ndim == 2:
                    f, m = f[..., None], m[..., None]
                f0, f1, m0, m1 = f[:, :-1], f[:, 1:], m[:, :-1], m[:, 1:]
                coef = (f0, m0, 3.0 * (f1 - f0) - 2.0 * m0 - m1, 2.0 * (f0 - f1) + m0 + m1)
                # per quantity, the four coefficients as flat contiguous arrays over (sample, cell)
                return [[np.ascontiguousarray(c[:, :, j]).ravel() for c in coef] for j in range(f.shape[2])]

            self._tables = ((u0_o, 1.0 / h_o, cells(f_o, m_o, h_o)), (u0_i, 1.0 / h_i, cells(f_i, m_i, h_i)))
        return self._tables

    @staticmethod
    def _hermite(sa, u0, inv_h, tables):
        """Values and d/d sigma_a of the tabulated quantities at sa (n, S):
        two lists with one (n, S) array per quantity (np.take on flat
        per-coefficient tables: contiguous operands, ~3x faster than
        gathering coefficient rows)."""
        x = (np.log(sa) - u0) * inv_h
        cell = x.astype(np.int64)
        np.clip(cell, 0, TABLE_NODES - 2, out=cell)
        t = x - cell
        cell += np.arange(sa.shape[-1]) * (TABLE_NODES - 1)
        scale = inv_h / sa
        values, slopes = [], []
        for coefficients in tables:
            a0, a1, a2, a3 = (np.take(c, cell) for c in coefficients)
            values.append(a0 + t * (a1 + t * (a2 + t * a3)))
            slopes.append((a1 + t * (2.0 * a2 + 3.0 * t * a3)) * scale)
        return values, slopes

    def value_and_jacobian(self, p):
        """Model (n, S) and Jacobian (n, S, 4) w.r.t. the four parameters, from
        the Hermite tables (see the class docstring) and the chain rule."""
        b = self.basis
        (u0_o, ih_o, tab_o), (u0_i, ih_i, tab_i) = self.tables()
        sa_out, sa_in = self.absorption(p)
        (R_f, T_f, R_b, T_b), d_epi = self._hermite(sa_out, u0_o, ih_o, tab_o)
        (R_in,), (dR_in,) = self._hermite(sa_in, u0_i, ih_i, tab_i)
        q = 1.0 / (1.0 - R_b * R_in)
        through = T_f * T_b * q
        value = R_f + through * R_in
        d_out = (d_epi[0] + R_in * q * (T_b * d_epi[1] + T_f * d_epi[3])
                 + through * R_in * R_in * q * d_epi[2])
        d_in = through * q * dR_in
        cm, bm = p[:, 0:1], p[:, 1:2]
        melanin = bm * b["eumelanin"] + (1.0 - bm) * b["pheomelanin"]
        jac = np.stack([
            d_out * (melanin - b["baseline"]),
            d_out * cm * (b["eumelanin"] - b["pheomelanin"]),
            d_out * (b["blood"] - b["baseline"]),
            d_in * (b["blood"] - b["baseline"]),
        ], axis=-1)
        return self._project(value, jac)

    def finite_difference_jacobian(self, p, h=1e-7):
        """Central differences of the exact model in the four parameters (reference for tests)."""
        cols = []
        for i in range(4):
            step = np.zeros(4)
            step[i] = h
            cols.append((self(p + step) - self(p - step)) / (2.0 * h))
        return np.stack(cols, axis=-1)


def _grid_axes(size: str = "default"):
    n = {"small": (10, 6, 7, 8), "default": (18, 11, 13, 16), "large": (28, 21, 19, 24)}[size]
    return (
        np.geomspace(*BOUNDS["C_m"], n[0]),
        np.linspace(*BOUNDS["beta_m"], n[1]),
        np.linspace(*BOUNDS["C_h_out"], n[2]),
        np.geomspace(*BOUNDS["C_h_in"], n[3]),
    )


def _table(key, size: str):
    """(parameter grid (M, 4), (mean, projection) of the outputs, KD-tree over
    the projected outputs); cached per model and size (module-level LRUs).

    The biophysical fit inverts block means in bins of the index
    (:func:`~polarbssrdf.inverse.biophysical.start.block_inversion`) at several skin values,
    about 50 tables of the small and default sizes per fit (1-5 MB each): 64 of them are
    kept, so fits of one face at the same skin values in one process (a fit repeated with
    other settings) build them once, where 8 were rebuilt by every fit (a second fit of a
    128^2 face: 27.0 -> 24.5 s, bench/RESULTS.md). The large tables
    (268,128 entries, about 27 MB each) keep 8."""
    return (_large_table if size == "large" else _small_table)(key, size)


def _build_table(key, size: str):
    """The uncached :func:`_table`."""
    model = _MODELS[key]
    axes = _grid_axes(size)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 4)
    values = model.on_grid(axes)
    # Nearest neighbours in at most 8 principal components of the outputs
    # (a KD-tree is slow in many dimensions; spectra are smooth).
    mean = values.mean(axis=0)
    if values.shape[1] > 8:
        _, _, vt = np.linalg.svd(values[:: max(1, len(values) // 20000)] - mean, full_matrices=False)
        projection = vt[:8].T
    else:
        projection = np.eye(values.shape[1])
    from scipy.spatial import cKDTree  # imported here: scipy.spatial costs ~0.3 s to import

    return grid, (mean, projection), cKDTree((values - mean) @ projection)


_small_table = functools.lru_cache(maxsize=64)(_build_table)
_large_table = functools.lru_cache(maxsize=8)(_build_table)


_MODELS: dict = {}


def _model_key(basis: dict, gamma, thickness_mm, eta, projection=None):
    key = (tuple((k, np.asarray(v, dtype=float).tobytes()) for k, v in sorted(basis.items())), float(gamma),
           float(thickness_mm), float(eta), None if projection is None else np.asarray(projection).tobytes())
    if key not in _MODELS:
        if len(_MODELS) > 128:  # more than the tables cached (:func:`_table`)
            _MODELS.clear()
        _MODELS[key] = _Model(basis, gamma, thickness_mm, eta, projection)
    return key


def _levenberg_marquardt(model: _Model, observed, start, iterations: int, tolerance: float = 1e-6,
                         rmse_floor: float = 1e-7, step_tolerance: float = 1e-3, lam0: float = 1e-3,
                         lam_down: float = 0.3, lam_up: float = 10.0):
    """Batched LM with Marquardt scaling and bounds (BOUNDS).

    Model values and Jacobians come from the tables of
    :meth:`_Model.value_and_jacobian` (no finite differences). (Holding
    parameters on a bound fixed, a projected step, was tried: 10% faster
    with noise, but it leaves a few noise-free texels in a local minimum at
    beta_m = 1.) A texel leaves the active set once an accepted step lowers
    its cost by less than ``tolerance`` (relative), its RMSE is below ``rmse_floor``
    (reflectance units), it moves every parameter by less than
    ``step_tolerance`` of its bounds range, or its damping exceeds 1e4; the
    working arrays hold the active texels only and are compacted whenever
    some finish (no gather/scatter of the whole chunk per iteration)."""
    lo = np.array([BOUNDS[n][0] for n in PARAMETER_NAMES])
    hi = np.array([BOUNDS[n][1] for n in PARAMETER_NAMES])
    span = hi - lo
    p_out = start.copy()
    value_out = np.empty(observed.shape)
    # working set: the active texels only, compacted when some finish
    index = np.arange(len(start))
    obs = observed
    p = start.copy()
    value, jac = model.value_and_jacobian(p)
    resid = value - obs
    cost = np.einsum("ns,ns->n", resid, resid)
    lam = np.full(len(p), lam0)
    eye = np.eye(4)
    floor = rmse_floor**2 * observed.shape[-1]
    for iteration in range(iterations):
        jtj = np.einsum("nsi,nsj->nij", jac, jac)
        grad = np.einsum("nsi,ns->ni", jac, resid)
        diag = np.einsum("nii->ni", jtj) + 1e-12
        lhs = jtj + (lam[:, None] * diag)[:, :, None] * eye
        step = np.linalg.solve(lhs, -grad[..., None])[..., 0]
        trial = np.clip(p + step, lo, hi)
        t_value, t_jac = model.value_and_jacobian(trial)
        t_resid = t_value - obs
        t_cost = np.einsum("ns,ns->n", t_resid, t_resid)
        better = t_cost < cost
        moved = np.max(np.abs(trial - p) / span, axis=-1)
        done = (better & ((cost - t_cost <= tolerance * cost) | (t_cost < floor) | (moved < step_tolerance)))
        p[better], value[better], jac[better] = trial[better], t_value[better], t_jac[better]
        resid[better], cost[better] = t_resid[better], t_cost[better]
        lam = np.where(better, lam * lam_down, lam * lam_up)
        done |= lam > 1e4
        if iteration == iterations - 1:
            break
        if done.any():
            p_out[index[done]], value_out[index[done]] = p[done], value[done]
            keep = ~done
            if not keep.any():
                return p_out, value_out
            index, obs, p, value, jac, resid, cost, lam = (x[keep] for x in (index, obs, p, value, jac, resid, cost, lam))
    p_out[index], value_out[index] = p, value
    return p_out, value_out


def _invert(observed, basis, gamma, thickness_mm, eta, iterations, table_size, chunk, workers, projection=None):
    observed = np.asarray(observed, dtype=float)
    n_samples = np.asarray(basis["eumelanin"]).shape[-1] if projection is None else len(projection)
    if observed.shape[-1] != n_samples:
        raise ValueError(f"observations have {observed.shape[-1]} samples per texel, the model has {n_samples}")
    if not np.all(np.isfinite(observed)):
        raise ValueError("observations must be finite")
    lead = observed.shape[:-1]
    flat = observed.reshape(-1, n_samples)
    key = _model_key(basis, gamma, thickness_mm, eta, projection)
    model = _MODELS[key]
    grid, (mean, projection), tree = _table(key, table_size)
    params = np.empty((len(flat), 4))
    predicted = np.empty_like(flat)

    def run(start):
        obs = flat[start:start + chunk]
        _, index = tree.query((obs - mean) @ projection, k=1 + RESTARTS)
        p, value = _levenberg_marquardt(model, obs, grid[index[:, 0]], iterations)
        cost = np.sum((value - obs) ** 2, axis=-1)
        for restart in range(1, 1 + RESTARTS):
            # the band integral's landscape has a few local minima (about 1 texel in 2000 of
            # Table 2 skins without noise): texels that fit far worse than the typical one
            # start again from their next-nearest table entries, and keep the best
            stuck = np.flatnonzero(cost > RESTART_COST_RATIO * np.median(cost) + 1e-14)
            if stuck.size == 0:
                break
            q, q_value = _levenberg_marquardt(model, obs[stuck], grid[index[stuck, restart]], iterations)
            q_cost = np.sum((q_value - obs[stuck]) ** 2, axis=-1)
            better = q_cost < cost[stuck]
            p[stuck[better]], cost[stuck[better]] = q[better], q_cost[better]
        params[start:start + chunk] = p
        predicted[start:start + chunk] = model(p)  # the exact model (the LM used its tables)

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
                 chunk: int = 8192, workers: int = 2, method: str = "integral") -> InversionResult:
    """Fit the four parameters to per-band reflectance (..., n_bands) with the forward model of
    :func:`~.model.band_reflectance` of ``method``: the band integral a camera records
    (``"integral"``, default: the quadrature's nodes combined by its weights) or the
    band-effective approximation (``"effective"``)."""
    quadrature = spectral_quadrature(bands, method)
    projection = None if quadrature.kind == "effective" else quadrature.weights
    return _invert(band_values, quadrature.basis, gamma, thickness_mm, eta, iterations, table_size, chunk,
                   workers, projection)


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
