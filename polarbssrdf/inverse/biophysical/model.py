"""The forward model of the biophysical stage: four maps -> subsurface albedo per band (eq. 42, 46, 47).

Differentiable with Dr.Jit, and the same model the synthetic renderer uses:

* absorption of the two layers: :func:`polarbssrdf.skin.layers.layer_absorption`
  (the formulas of :func:`~polarbssrdf.skin.layers.absorption_from_basis`) with
  the band-effective chromophore basis of :mod:`polarbssrdf.skin.model`;
* per-texel layer totals (eq. 42): for a band, the four epidermis totals
  depend only on the epidermis sigma_a (and eta), the dermis reflectance only
  on the dermis sigma_a, so they are read from cubic Hermite tables over
  ``ln sigma_a`` (linear in eta) whose node values and slopes are computed by
  :func:`polarbssrdf.skin.twolayer.layer_totals`, the function
  :func:`polarbssrdf.render.subsurface.layer_totals_maps` (synth) calls. The
  tables are evaluated in Dr.Jit, so the totals have exact derivatives of the
  interpolant (interpolation error < 1e-6 in reflectance, tested);
* eq. 46: :func:`polarbssrdf.render.subsurface.layered_exitance` on Dr.Jit
  tensors under uniform unit irradiance, i.e. the texture-space blur synth
  renders with;
* the lobe albedo ``rho_sss = M / c(eta)``
  (:func:`~polarbssrdf.render.subsurface.subsurface_exit_fraction`, see
  docs/biophysical.md).
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.render.subsurface import layered_exitance, subsurface_exit_fraction
from polarbssrdf.skin.inversion import BOUNDS as INVERSION_BOUNDS
from polarbssrdf.skin.layers import layer_absorption
from polarbssrdf.skin.model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM, band_chromophore_basis
from polarbssrdf.skin.twolayer import LayerTotals, layer_totals

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
TABLE_NODES = 512
ETA_STEP = 0.005
_SLOPE_STEP = 1e-4


def jit_types():
    """(Float, UInt32, TensorXf) of the LLVM AD backend."""

    return dr.llvm.ad.Float, dr.llvm.ad.UInt32, dr.llvm.ad.TensorXf


class _Table:
    """Cubic Hermite cells over ln sigma_a (uniform), rows = eta nodes; one set per quantity."""

    def __init__(self, u0, h, coefficients):
        Float, _, _ = jit_types()
        # the origin and step differ per band, table and run (they follow the bounds and
        # the eta range): kernel inputs, not literals, so one kernel serves every table
        self.u0, self.inv_h = dr.opaque(Float, float(u0)), dr.opaque(Float, 1.0 / float(h))
        self.cells = coefficients[0][0].shape[-1]
        # per quantity, per coefficient: flat (eta row, cell)
        self.coefficients = [[to_jit(Float, np.ravel(c), np.float32) for c in quantity]
                             for quantity in coefficients]

    def __call__(self, u, row):
        """Values of every quantity at ``u`` (Dr.Jit Float) in eta row ``row`` (UInt32)."""

        Float, UInt32, _ = jit_types()
        x = (u - self.u0) * self.inv_h
        cell = dr.clip(dr.floor(dr.detach(x)), 0, self.cells - 1)
        t = x - cell
        index = row * self.cells + UInt32(cell)
        out = []
        for a0, a1, a2, a3 in self.coefficients:
            g = [dr.gather(Float, c, index) for c in (a0, a1, a2, a3)]
            out.append(g[0] + t * (g[1] + t * (g[2] + t * g[3])))
        return out


def _hermite_coefficients(f, m, h):
    """(a0, a1, a2, a3) per cell from node values f (..., N) and slopes df/du m (..., N)."""
    m = m * h
    f0, f1, m0, m1 = f[..., :-1], f[..., 1:], m[..., :-1], m[..., 1:]
    return (f0, m0, 3.0 * (f1 - f0) - 2.0 * m0 - m1, 2.0 * (f0 - f1) + m0 + m1)


def absorption_range(basis, band, bounds):
    """(min, max) of sigma_a (1/mm) of the epidermis and of the dermis in ``band`` over the box ``bounds``."""
    corners = np.array(np.meshgrid(*[bounds[n] for n in PARAMETERS], indexing="ij")).reshape(4, -1)
    epi, der = layer_absorption(basis["eumelanin"][band], basis["pheomelanin"][band], basis["blood"][band],
                                basis["baseline"][band], *corners)
    return (epi.min(), epi.max()), (der.min(), der.max())


class BiophysicalModel:
    """Eq. 46 rendering of the lobe albedo from the four maps, in Dr.Jit (see the module docstring).

    Parameters
    ----------
    bands : list of Band
    atlas : TexelAtlas
        Texel sizes and the surface mask (the blur's domain).
    eta : float or (T, T) array
        Refractive index per texel (held fixed).
    thickness_mm : float
        Epidermis thickness.
    bounds : dict
        ``name -> (low, high)`` of the four parameters: the tables cover every
        sigma_a they allow.
    """

    def __init__(self, bands, atlas, eta=1.4, thickness_mm=DEFAULT_THICKNESS_MM, bounds=None,
                 table_nodes=TABLE_NODES):
        Float, UInt32, TensorXf = jit_types()
        self.bands = list(bands)
        self.atlas = atlas
        self.shape = atlas.valid.shape
        self.thickness_mm = float(thickness_mm)
        self.bounds = dict(bounds or INVERSION_BOUNDS)
        self.basis = band_chromophore_basis(self.bands, DEFAULT_GAMMA)
        eta = np.broadcast_to(np.asarray(eta, dtype=np.float64), self.shape)
        if not np.all(np.isfinite(eta) & (eta > 1.0)):
            raise ValueError("eta must be finite and > 1 at every texel")
        self.eta = np.array(eta)
        lo, hi = float(eta.min()), float(eta.max())
        count = 1 if hi - lo < 1e-7 else max(2, int(np.ceil((hi - lo) / ETA_STEP)) + 1)
        self.eta_nodes = np.linspace(lo, hi, count) if count > 1 else np.array([lo])
        if count > 1:
            position = (eta.ravel() - lo) / (self.eta_nodes[1] - self.eta_nodes[0])
            row = np.clip(np.floor(position), 0, count - 2)
            self._row = to_jit(UInt32, row, np.uint32)
            self._frac = to_jit(Float, position - row, np.float32)
        else:
            self._row, self._frac = to_jit(UInt32, np.zeros(eta.size), np.uint32), None
        self.inverse_exit_fraction = to_jit(Float, (1.0 / subsurface_exit_fraction(eta)).ravel(), np.float32)
        self.irradiance = to_jit(TensorXf, atlas.valid, np.float32)
        self.tables = [self._band_tables(b, table_nodes) for b in range(len(self.bands))]
        # per band, the chromophore basis as kernel inputs: the bands then share kernels
        self._absorption_basis = [tuple(dr.opaque(Float, float(self.basis[key][b]))
                                        for key in ("eumelanin", "pheomelanin", "blood", "baseline"))
                                  for b in range(len(self.bands))]

    def _band_tables(self, band, nodes):
        basis = self.basis
        ss_out, ss_in = basis["scattering_epidermis"][band], basis["scattering_dermis"][band]
        (eo_lo, eo_hi), (ed_lo, ed_hi) = absorption_range(basis, band, self.bounds)
        tables = []
        for which, (low, high) in (("epidermis", (eo_lo, eo_hi)), ("dermis", (ed_lo, ed_hi))):
            u0, u1 = np.log(low * 0.99), np.log(high * 1.01)
            h = (u1 - u0) / (nodes - 1)
            u = u0 + h * np.arange(nodes)

            def quantities(shift):
                sa = np.exp(u + shift)[None, :]
                if which == "epidermis":
                    t = layer_totals(sa, ss_out, np.full_like(sa, 1.0), ss_in, self.thickness_mm,
                                     self.eta_nodes[:, None])
                    return np.stack([t.R_out_f, t.T_out_f, t.R_out_b, t.T_out_b])  # (4, eta, N)
                t = layer_totals(np.full_like(sa, 1.0), ss_out, sa, ss_in, self.thickness_mm, self.eta_nodes[:1, None])
                return np.asarray(t.R_in)[None]  # (1, 1, N): independent of eta (index-matched inner face)

            f = quantities(0.0)
            slope = (quantities(_SLOPE_STEP) - quantities(-_SLOPE_STEP)) / (2.0 * _SLOPE_STEP)
            coefficients = [_hermite_coefficients(f[q], slope[q], h) for q in range(f.shape[0])]
            tables.append(_Table(u0, h, coefficients))
        return tables

    def absorption(self, band, params):
        """(sigma_a epidermis, sigma_a dermis) of ``band`` for Dr.Jit parameter arrays."""
        return layer_absorption(*self._absorption_basis[band], *(params[n] for n in PARAMETERS))

    def layer_totals(self, band, params):
        """The five layer totals (flat Dr.Jit Floats) of ``band`` at every texel."""

        sa_out, sa_in = self.absorption(band, params)
        epidermis, dermis = self.tables[band]
        u_out = dr.log(sa_out)
        values = epidermis(u_out, self._row)
        if self._frac is not None:
            upper = epidermis(u_out, self._row + 1)
            values = [a + self._frac * (c - a) for a, c in zip(values, upper)]
        (R_in,) = dermis(dr.log(sa_in), self._row * 0)
        return values + [R_in]

    def render(self, params, band, tolerance=1e-4):
        """Lobe albedo ``rho_sss`` of ``band`` (flat Dr.Jit Float): eq. 46 under unit irradiance / c(eta).

        ``params``: ``name -> flat Dr.Jit Float`` (T*T) of the four maps."""
        _, _, TensorXf = jit_types()
        totals = LayerTotals(*(TensorXf(x, self.shape) for x in self.layer_totals(band, params)))
        exitance = layered_exitance(self.irradiance, totals, self.kernels[band], self.atlas, tolerance=tolerance)
        return exitance.array * self.inverse_exit_fraction

    def local_albedo(self, params, band):
        """Lobe albedo of ``band`` without the blur (flat Dr.Jit Float): eq. 47 / c(eta).

        ``R_bar = R_of + T_of R_in T_ob / (1 - R_in R_ob)`` per texel: what
        :meth:`render` gives for maps that are constant over the blur's reach.
        The fit's Gauss-Newton steps use its Jacobian (the blur mixes texels
        but does not change this per-texel sensitivity for smooth maps)."""
        R_of, T_of, R_ob, T_ob, R_in = self.layer_totals(band, params)
        return (R_of + T_of * R_in * T_ob / (1.0 - R_in * R_ob)) * self.inverse_exit_fraction

    kernels: list = None
    """Per band, the normalized SoG kernels of the layer profiles (set by the fit)."""

    def render_numpy(self, maps, kernels=None):
        """(n_bands, T, T) float32 lobe albedo of NumPy maps (no autodiff)."""

        Float, _, _ = jit_types()
        if kernels is not None:
            self.kernels = kernels
        params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS}
        out = []
        for band in range(len(self.bands)):
            value = self.render(params, band)
            dr.eval(value)
            out.append(np.array(value, dtype=np.float32).reshape(self.shape))
        return np.stack(out)
