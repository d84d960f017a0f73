"""Band integrals of the skin model by a spectral quadrature: what a camera behind a filter records.

A sensor behind a band's filter integrates the spectral reflectance,
``R_b = int R(l) B(l) dl / int B(l) dl``. Evaluating eq. 47 once with the band's
mean absorption and scattering (the "band-effective" reflectance) is not that
integral: hemoglobin's absorption changes by orders of magnitude across a
40-100 nm band, and the default bands' effective reflectance is 10-19% off the
integral in BA, RA and RB (DESIGN.md, "Synthetic captures record what a camera
records").

:func:`band_integral_quadrature` finds a few wavelengths (nodes) shared by all
bands and per band non-negative weights so that ``R_b ~ sum_q w_bq R(l_q)`` for
every skin in a design box (:data:`DESIGN_BOX`: Table 2's chromophore ranges
widened by one range on either side, epidermal thickness, oxygenation and index
over the literature's spans) to a stated relative error against the 1 nm
integral (:func:`reference_band_reflectance`). This is empirical cubature
(An, Kim and James, "Optimizing cubature for efficient integration of subspace
deformations", ACM TOG 27(5), 2008): nodes are added greedily, each the
candidate that most lowers the largest relative error on the training skins, and
the weights of every band are the non-negative least-squares solution with a
soft constraint that they sum to 1 (a flat spectrum is integrated exactly).

Every model of the band images evaluates its nodes: synth diffuses each node
with its own layer profiles (:mod:`polarbssrdf.render.subsurface`), the
biophysical fit renders the same nodes with the same blur, the per-texel
inversion and the band report combine the same nodes. The band-effective form
is :func:`band_effective_quadrature` (one node per band, the band averages of
the coefficients, identity weights): a named approximation, fast, never the
default of a scored capture.

Units: wavelengths in nm, coefficients in 1/mm, reflectance unitless.
"""

from __future__ import annotations

import dataclasses
import numpy as np
from scipy.optimize import nnls

from .._threads import one_blas_thread
from ..spectral.bands import band_weights_matrix
from .chromophores import check_wavelengths, hemoglobin_wavelength_range
from .layers import chromophore_basis
from .parameters import table2_ranges
from .reflectance import reflectance_from_basis

REFERENCE_STEP_NM = 1.0
"""Spacing of the reference integral and of the quadrature's candidate wavelengths (nm)."""

DEFAULT_TOLERANCE = 5e-4
"""Largest relative error of a band integral on the training skins at which node selection stops."""

TRAINING_SKINS = 600
"""Skins drawn from :data:`DESIGN_BOX` to choose nodes and weights (a fixed seed: a numerical
method, deterministic for given bands)."""

SUM_WEIGHT = 1e3
"""Weight of the soft constraint ``sum_q w_bq = 1`` against the relative errors."""

MAX_NODES = 64

WEIGHT_FLOOR = 1e-3
"""A band's share below this fraction of its peak weight is outside its support (no node there)."""


def _design_box():
    ranges = table2_ranges()
    box = {}
    for name, (low, high) in ranges.items():
        span = high - low
        box[name] = (max(low - span, 0.002), high + span)
    box.update({"thickness_mm": (0.10, 0.40), "gamma": (0.5, 0.95), "eta": (1.30, 1.60)})
    return box


DESIGN_BOX = _design_box()
"""``name -> (low, high)`` of the skins the quadrature is made for: the four chromophores over
Table 2's range of means widened by that range on each side (at least 0.002), epidermal
thickness 0.10-0.40 mm, blood oxygen fraction 0.5-0.95 and index 1.30-1.60
(:mod:`polarbssrdf.synth.truth` draws its faces inside this box)."""


@dataclasses.dataclass(frozen=True)
class SpectralQuadrature:
    """Nodes and per-band weights that turn node reflectances into band values.

    Attributes
    ----------
    bands : tuple of Band
    wavelengths_nm : (Q,) array
        The nodes' wavelengths (for the band-effective form, each band's centroid).
    weights : (n_bands, Q) array
        ``R_b = sum_q weights[b, q] R_q`` (non-negative, rows sum to about 1).
    basis : dict
        The chromophore basis (:func:`~.layers.chromophore_basis`) at the nodes,
        ``name -> (Q,)`` in 1/mm; for the band-effective form, band averages.
    kind : str
        ``"integral"`` (:func:`band_integral_quadrature`) or ``"effective"``
        (:func:`band_effective_quadrature`).
    max_error : float
        Largest relative error of a band value against the 1 nm integral on skins of
        :data:`DESIGN_BOX` drawn apart from the training skins (measured when made).
    """

    bands: tuple
    wavelengths_nm: np.ndarray
    weights: np.ndarray
    basis: dict
    kind: str
    max_error: float

    @property
    def nodes(self) -> int:
        return int(self.wavelengths_nm.size)

    def band_values(self, node_values):
        """``(..., n_bands)`` band values from ``(..., Q)`` node values."""
        return np.asarray(node_values) @ self.weights.T

    def describe(self) -> dict:
        """A JSON-ready record: kind, nodes (nm), weights per band, the measured error."""
        return {"kind": self.kind, "nodes_nm": [round(float(x), 3) for x in self.wavelengths_nm],
                "weights": {band.name: [round(float(w), 6) for w in row]
                            for band, row in zip(self.bands, self.weights)},
                "max_relative_error": float(self.max_error)}


def reference_grid(step_nm=REFERENCE_STEP_NM):
    """The wavelengths of the reference integral: the hemoglobin table's range every ``step_nm``."""
    low, high = hemoglobin_wavelength_range()
    return np.arange(low, high + 0.5 * step_nm, step_nm)


def sample_design_skins(count, rng, box=None):
    """``count`` skins uniform in ``box`` (:data:`DESIGN_BOX`): ``name -> (count,)`` arrays."""
    box = DESIGN_BOX if box is None else box
    return {name: rng.uniform(low, high, count) for name, (low, high) in box.items()}


def spectral_reflectance(skins, wavelengths_nm):
    """``(n, n_wavelengths)`` total diffuse reflectance (eq. 47) of skins (``name -> (n,)``
    arrays of the four chromophores, ``thickness_mm``, ``gamma``, ``eta``) at every wavelength."""

    basis = chromophore_basis(check_wavelengths(np.asarray(wavelengths_nm, dtype=float)))
    return reflectance_from_basis(basis, skins["C_m"], skins["beta_m"], skins["C_h_out"], skins["C_h_in"],
                                  skins["thickness_mm"], skins["eta"], gamma=skins["gamma"])


def reference_band_reflectance(skins, bands, step_nm=REFERENCE_STEP_NM):
    """``(n, n_bands)`` band integrals of the spectral reflectance on a ``step_nm`` grid: the
    reference a quadrature is measured against (band weights linearly interpolated,
    trapezoid rule, :func:`~polarbssrdf.spectral.bands.band_weights_matrix`)."""
    grid = reference_grid(step_nm)
    return spectral_reflectance(skins, grid) @ band_weights_matrix(list(bands), grid).T


def _band_weights(relative, selected):
    """NNLS weights of one band on the selected columns of ``relative`` (node / band values)."""
    matrix = np.vstack([relative[:, selected], np.full(len(selected), SUM_WEIGHT)])
    target = np.concatenate([np.ones(relative.shape[0]), [SUM_WEIGHT]])
    weights, _ = nnls(matrix, target, maxiter=50 * max(len(selected), 10))
    return weights


def _errors(relative, selected):
    """(rms, largest) relative error of one band's NNLS fit on the selected columns."""
    residual = relative[:, selected] @ _band_weights(relative, selected) - 1.0
    return float(np.sqrt(np.mean(residual ** 2))), float(np.max(np.abs(residual)))


def _select_nodes(relative, support, tolerance, max_nodes):
    """Greedy joint node selection (see the module docstring): returns the node columns and per
    band (its node columns, weights).

    Each step adds the candidate that most lowers the summed RMS error of the bands whose
    largest error is still above ``tolerance`` (the RMS is a smoother guide than the largest
    error, which chased single skins and took twice the nodes on narrow bands)."""
    n_bands = len(relative)
    selected: list[int] = []
    largest = np.ones(n_bands)
    while largest.max() > tolerance and len(selected) < max_nodes:
        open_bands = largest > tolerance
        best = None
        for candidate in range(support.shape[1]):
            if candidate in selected or not support[open_bands, candidate].any():
                continue
            score, trial = 0.0, largest.copy()
            for b in np.flatnonzero(open_bands):
                columns = [c for c in selected + [candidate] if support[b, c]]
                if not columns:
                    score += 1.0
                    continue
                rms, trial[b] = _errors(relative[b], columns)
                score += rms
            if best is None or score < best[0]:
                best = (score, candidate, trial)
        if best is None:
            break
        selected.append(best[1])
        # a new node can also serve a band already within the tolerance: its weights are refitted
        largest = best[2]
        for b in np.flatnonzero(~open_bands & support[:, best[1]]):
            largest[b] = _errors(relative[b], [c for c in selected if support[b, c]])[1]
    per_band = []
    for b in range(n_bands):
        columns = sorted(c for c in selected if support[b, c])
        per_band.append((columns, _band_weights(relative[b], columns) if columns else np.zeros(0)))
    return sorted(selected), per_band


def _bands_key(bands):
    return tuple((b.name, b.wavelengths_nm.tobytes(), b.weights.tobytes()) for b in bands)


def band_integral_quadrature(bands, tolerance=DEFAULT_TOLERANCE, max_nodes=MAX_NODES) -> SpectralQuadrature:
    """The empirical quadrature of the band integrals (module docstring), cached per bands.

    Parameters
    ----------
    bands : list of Band
        Their weights must lie within the hemoglobin table (400-700 nm).
    tolerance : float
        Stop adding nodes once every band's largest relative error on the training skins is
        below this (default 5e-4; the error on other skins is measured and kept in
        ``max_error``).
    max_nodes : int
        A cap on the shared nodes.
    """
    bands = tuple(bands)
    if not bands:
        raise ValueError("a quadrature needs at least one band")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be > 0, got {tolerance!r}")
    return _cached(("integral", _bands_key(bands), float(tolerance), int(max_nodes)),
                   lambda: _integral_quadrature(bands, float(tolerance), int(max_nodes)))


_CACHE: dict = {}
_CACHE_SIZE = 8


def _cached(key, make):
    """One quadrature per bands and settings per process (bands hold arrays: keyed by their bytes).

    Made with BLAS on one thread: the greedy selection's least squares otherwise give other
    last bits in a process with more BLAS threads than a Dask worker has, and every fit that
    reads the cached quadrature then differs (:mod:`polarbssrdf._threads`)."""
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        with one_blas_thread():
            _CACHE[key] = make()
    return _CACHE[key]


def _integral_quadrature(bands, tolerance, max_nodes):
    grid = reference_grid()
    matrix = band_weights_matrix(list(bands), grid)  # (B, L), rows sum to 1
    support = matrix > WEIGHT_FLOOR * matrix.max(axis=1, keepdims=True)
    rng = np.random.default_rng(20261203)
    training = sample_design_skins(TRAINING_SKINS, rng)
    spectra = spectral_reflectance(training, grid)  # (N, L)
    reference = spectra @ matrix.T  # (N, B)
    relative = [spectra / reference[:, b:b + 1] for b in range(len(bands))]
    selected, per_band = _select_nodes(relative, support, tolerance, max_nodes)
    weights = np.zeros((len(bands), len(selected)))
    for b, (columns, band_weights) in enumerate(per_band):
        for column, weight in zip(columns, band_weights):
            weights[b, selected.index(column)] = weight
    wavelengths = grid[selected]
    basis = chromophore_basis(wavelengths)
    validation = sample_design_skins(TRAINING_SKINS, np.random.default_rng(7))
    truth = reference_band_reflectance(validation, bands)
    estimate = spectral_reflectance(validation, wavelengths) @ weights.T
    error = float(np.max(np.abs(estimate / truth - 1.0)))
    return SpectralQuadrature(bands, wavelengths, weights, basis, "integral", error)


def band_effective_quadrature(bands) -> SpectralQuadrature:
    """The band-effective approximation as a quadrature: one node per band whose coefficients are
    the band averages of the chromophore basis (exact for the absorption, which is linear in
    them; not for the reflectance), identity weights. Its ``max_error`` against the band
    integral is measured on the design box like :func:`band_integral_quadrature`'s."""
    bands = tuple(bands)
    return _cached(("effective", _bands_key(bands)), lambda: _effective_quadrature(bands))


def _effective_quadrature(bands):
    grid = np.unique(np.concatenate([b.wavelengths_nm for b in bands]))
    spectra = chromophore_basis(check_wavelengths(grid))
    matrix = band_weights_matrix(list(bands), grid)
    basis = {name: matrix @ values for name, values in spectra.items()}
    centroids = np.array([band.centroid_nm for band in bands])
    quadrature = SpectralQuadrature(bands, centroids, np.eye(len(bands)), basis, "effective", np.nan)
    validation = sample_design_skins(TRAINING_SKINS, np.random.default_rng(7))
    truth = reference_band_reflectance(validation, bands)
    estimate = quadrature_reflectance(quadrature, validation["C_m"], validation["beta_m"], validation["C_h_out"],
                                      validation["C_h_in"], validation["gamma"], validation["thickness_mm"],
                                      validation["eta"])
    return dataclasses.replace(quadrature, max_error=float(np.max(np.abs(estimate / truth - 1.0))))


SPECTRAL_METHODS = ("integral", "effective")


def spectral_quadrature(bands, method="integral") -> SpectralQuadrature:
    """The quadrature of ``method``: ``"integral"`` (the band integral a camera records, the
    default everywhere) or ``"effective"`` (the band-effective approximation)."""
    if method == "integral":
        return band_integral_quadrature(bands)
    if method == "effective":
        return band_effective_quadrature(bands)
    raise ValueError(f"spectral method must be one of {SPECTRAL_METHODS}, got {method!r}")


def as_quadrature(spectral) -> SpectralQuadrature:
    """``spectral`` itself if it is a quadrature, else (a list of bands) their band integral's."""
    if isinstance(spectral, SpectralQuadrature):
        return spectral
    return band_integral_quadrature(list(spectral))


def quadrature_reflectance(quadrature, C_m, beta_m, C_h_out, C_h_in, gamma, thickness_mm, eta):
    """Band values of the total diffuse reflectance (eq. 47), ``params + (n_bands,)``, from the
    quadrature's nodes. Parameters broadcast (maps or scalars)."""

    nodes = reflectance_from_basis(quadrature.basis, C_m, beta_m, C_h_out, C_h_in, thickness_mm, eta,
                                   gamma=gamma)
    return quadrature.band_values(nodes)


__all__ = ["SpectralQuadrature", "as_quadrature", "band_integral_quadrature", "band_effective_quadrature", "spectral_quadrature",
           "quadrature_reflectance", "reference_band_reflectance", "spectral_reflectance", "DESIGN_BOX"]
