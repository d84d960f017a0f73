"""The forward model of the biophysical stage: four maps -> subsurface albedo per band (eq. 42, 46, 47).

Differentiable with Dr.Jit, and the same model the synthetic renderer uses:

* the bands' spectral quadrature (:mod:`polarbssrdf.skin.quadrature`): every
  band value is a weighted sum over a few wavelengths (nodes) shared by the
  bands, the band integral a camera records (or, as a named approximation, one
  band-effective node per band);
* absorption of the two layers at each node: :func:`polarbssrdf.skin.layers.layer_absorption`
  (the formulas of :func:`~polarbssrdf.skin.layers.absorption_from_basis`) with
  the node's chromophore basis and the blood at the face's oxygen fraction;
* per-texel layer totals (eq. 42): for a node, the four epidermis totals
  depend only on the epidermis sigma_a (and eta), the dermis reflectance only
  on the dermis sigma_a, so they are read from cubic Hermite tables over
  ``ln sigma_a`` (linear in eta) whose node values and slopes are computed by
  :func:`polarbssrdf.skin.twolayer.layer_totals`, the function
  :func:`polarbssrdf.render.subsurface.layer_totals_maps` (synth) calls. The
  tables are evaluated in Dr.Jit, so the totals have exact derivatives of the
  interpolant (interpolation error < 1e-6 in reflectance, tested);
* eq. 46: :func:`polarbssrdf.render.subsurface.band_exitances` on Dr.Jit
  tensors under uniform unit irradiance, i.e. the per-node texture-space blur
  and band sum synth renders with;
* the lobe albedo ``rho_sss = M / c(eta)``
  (:func:`~polarbssrdf.render.subsurface.subsurface_exit_fraction`, see
  docs/biophysical.md).
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.render.subsurface import band_exitances, subsurface_exit_fraction
from polarbssrdf.skin.inversion import BOUNDS as INVERSION_BOUNDS
from polarbssrdf.skin.layers import blood_from_basis, layer_absorption
from polarbssrdf.skin.model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM
from polarbssrdf.skin.quadrature import DESIGN_BOX, as_quadrature
from polarbssrdf.skin.twolayer import LayerTotals, layer_totals

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
ROUND_TRIPS = 2
"""Round trips between the layers the fit blurs before closing the series per texel
(:func:`~polarbssrdf.render.subsurface.layered_exitance`'s ``round_trips``). On a 256^2
cheek IV face with 2 mm fields and freckles the closed exitance is within 1.3e-4 of the
full series at every texel (1.1e-3 after one round trip, at 700 nm), where the series
takes 4-7 round trips and a read-back per node (tests/render/test_texture_subsurface.py)."""
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

    def __call__(self, u, row, slopes=False):
        """``(values, slopes)``: every quantity at ``u`` (Dr.Jit Float) in eta row ``row``
        (UInt32), and with ``slopes`` their derivatives d/du of the interpolant (else an
        empty list)."""

        Float, UInt32, _ = jit_types()
        x = (u - self.u0) * self.inv_h
        cell = dr.clip(dr.floor(dr.detach(x)), 0, self.cells - 1)
        t = x - cell
        index = row * self.cells + UInt32(cell)
        out, derivatives = [], []
        for a0, a1, a2, a3 in self.coefficients:
            g = [dr.gather(Float, c, index) for c in (a0, a1, a2, a3)]
            out.append(g[0] + t * (g[1] + t * (g[2] + t * g[3])))
            if slopes:
                derivatives.append((g[1] + t * (2.0 * g[2] + 3.0 * t * g[3])) * self.inv_h)
        return out, derivatives


def _hermite_coefficients(f, m, h):
    """(a0, a1, a2, a3) per cell from node values f (..., N) and slopes df/du m (..., N)."""
    m = m * h
    f0, f1, m0, m1 = f[..., :-1], f[..., 1:], m[..., :-1], m[..., 1:]
    return (f0, m0, 3.0 * (f1 - f0) - 2.0 * m0 - m1, 2.0 * (f0 - f1) + m0 + m1)


GAMMA_RANGE = DESIGN_BOX["gamma"]
"""Oxygen fractions the tables cover: the face's oxygenation moves without rebuilding them."""


def absorption_range(basis, node, bounds, gammas=GAMMA_RANGE):
    """(min, max) of sigma_a (1/mm) of the epidermis and of the dermis at quadrature node ``node``
    over the box ``bounds`` and the oxygen fractions ``gammas``."""
    corners = np.array(np.meshgrid(*[bounds[n] for n in PARAMETERS], indexing="ij")).reshape(4, -1)
    epi, der = [], []
    for gamma in gammas:
        blood = float(blood_from_basis(basis, gamma)[node])
        e, d = layer_absorption(basis["eumelanin"][node], basis["pheomelanin"][node], blood,
                                basis["baseline"][node], *corners)
        epi.append(e)
        der.append(d)
    epi, der = np.concatenate(epi), np.concatenate(der)
    return (epi.min(), epi.max()), (der.min(), der.max())


class BiophysicalModel:
    """Eq. 46 rendering of the band-integrated lobe albedo from the four maps, in Dr.Jit (see the
    module docstring).

    Parameters
    ----------
    spectral : SpectralQuadrature or list of Band
        The bands' quadrature (:func:`polarbssrdf.skin.quadrature.as_quadrature`: bands
        get their band integral's).
    atlas : TexelAtlas
        Texel sizes and the surface mask (the blur's domain).
    eta : float or (T, T) array
        Refractive index per texel (held fixed).
    thickness_mm : float
        Epidermis thickness of the face (:meth:`set_skin` changes it).
    gamma : float
        Oxygen fraction of the face's blood (:meth:`set_skin` changes it).
    bounds : dict
        ``name -> (low, high)`` of the four parameters: the tables cover every
        sigma_a they allow at oxygen fractions in :data:`GAMMA_RANGE`.
    """

    def __init__(self, spectral, atlas, eta=1.4, thickness_mm=DEFAULT_THICKNESS_MM, bounds=None,
                 table_nodes=TABLE_NODES, gamma=DEFAULT_GAMMA):
        Float, UInt32, TensorXf = jit_types()
        self.quadrature = as_quadrature(spectral)
        self.bands = list(self.quadrature.bands)
        self.weights = np.asarray(self.quadrature.weights, dtype=np.float64)
        self.atlas = atlas
        self.shape = atlas.valid.shape
        self.bounds = dict(bounds or INVERSION_BOUNDS)
        self.basis = self.quadrature.basis
        self.table_nodes = int(table_nodes)
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
        self.inverse_exit_fraction_numpy = 1.0 / subsurface_exit_fraction(eta).ravel()
        self.inverse_exit_fraction = to_jit(Float, self.inverse_exit_fraction_numpy, np.float32)
        self.irradiance = to_jit(TensorXf, atlas.valid, np.float32)
        # the band weights change with the bands: kernel inputs, not literals
        self._weights_jit = [[dr.opaque(Float, float(w)) for w in row] for row in self.weights]
        self.thickness_mm = self.gamma = None
        self.set_skin(thickness_mm, gamma)

    @property
    def nodes(self):
        return self.quadrature.nodes

    def set_skin(self, thickness_mm=None, gamma=None):
        """Set the face's epidermal thickness (mm; rebuilds the epidermis tables) and oxygen fraction."""
        Float, _, _ = jit_types()
        if thickness_mm is not None and thickness_mm != self.thickness_mm:
            if not (np.isfinite(thickness_mm) and thickness_mm > 0):
                raise ValueError(f"thickness_mm must be > 0, got {thickness_mm!r}")
            self.thickness_mm = float(thickness_mm)
            self.tables = [self._node_tables(q, self.table_nodes) for q in range(self.nodes)]
        if gamma is not None and gamma != self.gamma:
            low, high = GAMMA_RANGE
            if not low <= gamma <= high:
                raise ValueError(f"gamma must be in [{low}, {high}] (the tables' range), got {gamma!r}")
            self.gamma = float(gamma)
            blood = blood_from_basis(self.basis, self.gamma)
            # per node, the chromophore basis as kernel inputs: the nodes then share kernels
            self._absorption_basis = [tuple(dr.opaque(Float, float(v)) for v in (
                self.basis["eumelanin"][q], self.basis["pheomelanin"][q], blood[q], self.basis["baseline"][q]))
                for q in range(self.nodes)]

    def _node_tables(self, node, nodes):
        basis = self.basis
        ss_out, ss_in = basis["scattering_epidermis"][node], basis["scattering_dermis"][node]
        (eo_lo, eo_hi), (ed_lo, ed_hi) = absorption_range(basis, node, self.bounds)
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

    def absorption(self, node, params):
        """(sigma_a epidermis, sigma_a dermis) at quadrature ``node`` for Dr.Jit parameter arrays."""
        return layer_absorption(*self._absorption_basis[node], *(params[n] for n in PARAMETERS))

    def layer_totals(self, node, params):
        """The five layer totals (flat Dr.Jit Floats, evaluated) at quadrature ``node`` at
        every texel.

        With autodiff enabled on the parameters, each total is its evaluated value ``T``
        plus ``T'(u) (u - detach(u))`` (``u = ln sigma_a`` of its layer, ``T'`` the
        interpolant's slope, evaluated with ``T``): the same value, and derivatives that
        reach the parameters through ``u`` alone. Traced through the tables instead, every
        derivative kernel re-ran every node's table lookups: 2,000-6,000 operations per
        kernel and 2-9 s of LLVM each (bench/RESULTS.md, 2026-12-08). One node's kernel
        serves every node (the nodes differ in kernel inputs only)."""

        sa_out, sa_in = self.absorption(node, params)
        u_out, u_in = dr.log(sa_out), dr.log(sa_in)
        tracked = dr.grad_enabled(u_out) or dr.grad_enabled(u_in)
        epidermis, dermis = self.tables[node]
        # the slopes only where a derivative will read them
        values, slopes = epidermis(dr.detach(u_out), self._row, slopes=tracked)
        if self._frac is not None:
            upper, upper_slopes = epidermis(dr.detach(u_out), self._row + 1, slopes=tracked)
            values = [a + self._frac * (c - a) for a, c in zip(values, upper)]
            slopes = [a + self._frac * (c - a) for a, c in zip(slopes, upper_slopes)]
        inner, inner_slopes = dermis(dr.detach(u_in), self._row * 0, slopes=tracked)
        values, slopes = values + inner, slopes + inner_slopes
        if not tracked:
            dr.eval(*values)
            return values
        steps = [u_out - dr.detach(u_out)] * 4 + [u_in - dr.detach(u_in)]
        totals = [value + slope * step for value, slope, step in zip(values, slopes, steps)]
        # one kernel: the slopes the derivatives read, and the totals' values, which the
        # blurs and the interreflection series read many times
        dr.eval(*slopes, *totals)
        return totals

    def _band_sums(self, node_values):
        """Per band, ``sum_q w_bq value_q`` of flat Dr.Jit Floats (nodes of weight 0 skipped)."""
        out = []
        for b, row in enumerate(self.weights):
            total = None
            for q in np.flatnonzero(row > 0):
                term = node_values[q] * self._weights_jit[b][q]
                total = term if total is None else total + term
            out.append(total)
        return out

    def render_bands(self, params):
        """Per band, the lobe albedo ``rho_sss`` (flat Dr.Jit Float): the band integral of eq. 46
        under unit irradiance (the layers' series closed after :data:`ROUND_TRIPS`), / c(eta).
        ``params``: ``name -> flat Dr.Jit Float`` (T*T) of the four maps."""
        _, _, TensorXf = jit_types()
        # each node's totals evaluated (layer_totals), so kept: left lazy, each blur and each
        # peak the interreflection series reads re-ran the table lookups (20 of a 512^2
        # frame's 82 s)
        flat = [self.layer_totals(q, params) for q in range(self.nodes)]
        totals = [LayerTotals(*(TensorXf(x, self.shape) for x in node)) for node in flat]
        exitances = band_exitances(self.irradiance, totals, self.kernels, self.weights, self.atlas,
                                   round_trips=ROUND_TRIPS)
        return [exitance.array * self.inverse_exit_fraction for exitance in exitances]

    def local_albedo_nodes(self, params):
        """Per quadrature node, ``R_bar = R_of + T_of R_in T_ob / (1 - R_in R_ob)`` (eq. 47;
        flat Dr.Jit Float): the layers' total reflectance at each texel without the blur.

        Each node's value is evaluated on its own: the nodes differ only in kernel inputs, so
        they share one compiled kernel (and so do their forward-mode derivatives, which
        :meth:`~polarbssrdf.inverse.biophysical.problem.DataTerm.local_jacobian` reads
        node by node). Left lazy, a band's nodes fused into one kernel of 2,000-6,000
        operations per band and per derivative, 2-9 s of LLVM each (bench/RESULTS.md,
        2026-12-08)."""
        nodes = []
        for q in self.used_nodes:
            R_of, T_of, R_ob, T_ob, R_in = self.layer_totals(q, params)
            value = R_of + T_of * R_in * T_ob / (1.0 - R_in * R_ob)
            dr.eval(value)
            nodes.append(value)
        return nodes

    @property
    def used_nodes(self):
        """The quadrature nodes some band weighs (the others are never evaluated)."""
        return [int(q) for q in np.flatnonzero(np.any(self.weights > 0, axis=0))]

    def band_sums_numpy(self, node_values):
        """``(n_bands, n_texels)`` float64 ``sum_q w_bq value_q / c(eta)`` of per-node values
        over :attr:`used_nodes` (NumPy arrays or flat Dr.Jit Floats)."""
        values = np.stack([np.asarray(v, dtype=np.float64) for v in node_values])
        return (self.weights[:, self.used_nodes] @ values) * self.inverse_exit_fraction_numpy

    def local_albedo_bands(self, params):
        """Per band, the lobe albedo without the blur (flat Dr.Jit Float): the band integral of
        eq. 47 / c(eta), :meth:`local_albedo_nodes` summed over the band's quadrature.

        What :meth:`render_bands` gives for maps that are constant over the blur's reach. The
        fit's Gauss-Newton steps use its Jacobian (the blur mixes texels but does not
        change this per-texel sensitivity for smooth maps)."""
        nodes = dict(zip(self.used_nodes, self.local_albedo_nodes(params)))
        values = [nodes.get(q) for q in range(self.nodes)]
        return [value * self.inverse_exit_fraction for value in self._band_sums(values)]

    kernels: list = None
    """Per quadrature node, the normalized SoG kernels of the layer profiles (set by the fit)."""

    def render_numpy(self, maps, kernels=None):
        """(n_bands, T, T) float32 lobe albedo of NumPy maps (no autodiff)."""

        Float, _, _ = jit_types()
        if kernels is not None:
            self.kernels = kernels
        params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS}
        values = self.render_bands(params)
        dr.eval(*values)
        return np.stack([np.array(value, dtype=np.float32).reshape(self.shape) for value in values])
