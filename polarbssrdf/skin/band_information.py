"""What a band set can tell: Cramér-Rao bounds of the four chromophores from per-band albedo,
and a search for band sets (or comb-filter pairs) that lower them.

The biophysical stage fits the lobe albedo of each band, ``rho_b = R_bar_b(theta) / c(eta)``
(eq. 47 integrated over each band by its spectral quadrature, :func:`~.model.band_reflectance`;
docs/biophysical.md), to ``theta = (C_m, beta_m, C_h_out, C_h_in)``. For an albedo error of
band covariance ``S`` (Gaussian), the Fisher information of one texel is

    F = J^T S^-1 J,     J_bj = d rho_b / d theta_j,

and no unbiased estimator has a smaller covariance than the Cramér-Rao bound ``F^-1``
(Pera et al. 2018 use it to design SFDI wavelengths). With a Gaussian prior of standard
deviations ``s_j`` the Bayesian (Van Trees) bound is ``(F + diag(1 / s_j^2))^-1``.

The skin's other unknowns (:data:`~.nuisances.NUISANCES`: epidermal thickness, oxygen
fraction, index) are not known on a real face. Given as ``nuisances`` (name -> prior std),
they join ``theta`` in ``J`` and are marginalized: the chromophores keep the information

    F_eff = F_cc - F_cn (F_nn + diag(1 / s_n^2))^-1 F_nc        (:func:`marginal_information`)

(the inverse of the top-left block of the joint posterior precision), so a nuisance the bands
cannot tell from a chromophore widens that chromophore's bound.

* ``J`` is central differences of the skin model (the model of the fit and of synth, never a
  second copy), step :data:`JACOBIAN_STEP`;
* the bound is computed in units of each chromophore's Table 2 range
  (:func:`~.parameters.table2_ranges`), so the condition number compares like with like; an
  eigenvalue of that information below :data:`SINGULAR_TOLERANCE` times the largest is a
  direction the bands cannot see: the bound of every chromophore with a share of it is
  reported as infinite (``identifiable`` false), never an error;
* noise models (:class:`NoiseModel`): relative (``sigma x albedo`` per band, the fit's
  ``albedo_noise``, plus an optional band-common part ``common x albedo``, the fit's
  ``common_noise``: a gain or shading error every band shares), white absolute (lobe-albedo
  units), or a full band covariance of relative errors read from JSON
  (``S = diag(rho) C diag(rho)``).

The design mode (:func:`design_bands`, :func:`design_comb_pair`) minimizes a stated
criterion (:data:`CRITERIA`) over Table 2's eight rows.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np

from .model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM, band_reflectance
from .nuisances import NUISANCES, nuisance_prior_std
from .parameters import TABLE2, TABLE2_STD, table2_ranges, table2_spread_across_rows

PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")

JACOBIAN_STEP = 1e-6
"""Central-difference step (absolute volume fraction). The parameters are 0.02-0.1 and the
model varies on that scale, so the truncation error is about (1e-6 / 0.02)^2 / 6 ~ 4e-10 of
the derivative, while float64 rounding of the model (about 1e-15) contributes
1e-15 / 1e-6 = 1e-9: the two balance near this step. Measured against a Richardson
extrapolation (steps 1e-6 and 2e-6) at the eight Table 2 rows: within 3e-10 of the largest
entry at six rows, 3e-8 at forehead IV and 2e-6 at cheek I, where the model is not smooth
on that scale and no step does better; tests/skin/test_skin_band_information.py compares J
with the analytic Jacobian of the inversion's tables (within 5e-5)."""

SINGULAR_TOLERANCE = 1e-10
"""An eigenvalue of the range-scaled information below this fraction of the largest is taken as
zero: the bands do not constrain that direction (float64 differences carry about 9 digits)."""

CRITERIA = {
    "mean": "mean over the Table 2 rows and the four chromophores of the bound (standard "
            "deviation) as a fraction of the chromophore's Table 2 range",
    "worst": "largest over the Table 2 rows and the four chromophores of the bound as a "
             "fraction of the chromophore's Table 2 range",
}
"""Design criteria: :func:`criterion_value`."""

EXHAUSTIVE_LIMIT = 2_000_000
"""Most subsets :func:`design_bands` evaluates in an exhaustive search."""

REPORT_SCHEMA = "polarbssrdf.band_report"
REPORT_SCHEMA_VERSION = 1


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Band covariance of the lobe-albedo error.

    Attributes
    ----------
    kind : {"relative", "absolute", "covariance"}
        ``relative``: independent bands, standard deviation ``sigma x albedo``;
        ``absolute``: independent bands, standard deviation ``sigma`` (albedo units);
        ``covariance``: ``S = diag(albedo) matrix diag(albedo)``, ``matrix`` the band x
        band covariance of relative errors.
    sigma : float
        For the white models (> 0).
    common : float
        For ``relative``: the standard deviation of a relative error all bands share (>= 0;
        ``S = diag(rho) (sigma^2 I + common^2 1 1^T) diag(rho)``). 0: independent bands.
    matrix : (n, n) array
        For ``covariance``: symmetric positive definite.
    band_names : tuple of str
        For ``covariance``: the bands of the matrix's rows, if the file names them.
    source : str
        Where the matrix came from (a file), for the record.
    """

    kind: str
    sigma: float | None = None
    common: float = 0.0
    matrix: np.ndarray | None = None
    band_names: tuple | None = None
    source: str = ""

    def __post_init__(self):
        if self.kind in ("relative", "absolute"):
            if not (isinstance(self.sigma, (int, float)) and math.isfinite(self.sigma) and self.sigma > 0):
                raise ValueError(f"the {self.kind} noise level must be a number > 0, got {self.sigma!r}")
            if not (isinstance(self.common, (int, float)) and math.isfinite(self.common) and self.common >= 0):
                raise ValueError(f"the band-common noise level must be a number >= 0, got {self.common!r}")
            if self.common > 0 and self.kind != "relative":
                raise ValueError("a band-common noise part is relative to the albedo: use the relative model")
        elif self.kind == "covariance":
            object.__setattr__(self, "matrix", check_covariance(self.matrix, self.source or "covariance"))
            if self.band_names is not None and len(self.band_names) != self.matrix.shape[0]:
                raise ValueError(f"{self.source or 'covariance'}: {len(self.band_names)} band names for a "
                                 f"{self.matrix.shape[0]} x {self.matrix.shape[0]} matrix")
        else:
            raise ValueError(f"noise kind must be 'relative', 'absolute' or 'covariance', got {self.kind!r}")

    @property
    def parametric(self) -> bool:
        """A parametric model (relative or absolute): the information of any band subset follows
        from per-band terms (:func:`_subset_information`), as the design mode needs."""
        return self.kind != "covariance"

    def for_bands(self, bands) -> "NoiseModel":
        """This model for ``bands``: a covariance matrix reordered to their order by its band
        names (``ValueError`` naming the bands that do not match), or checked for size."""
        if self.parametric:
            return self
        names = [band.name for band in bands]
        where = self.source or "covariance"
        if self.band_names is None:
            if self.matrix.shape[0] != len(names):
                raise ValueError(f"{where}: a {self.matrix.shape[0]} x {self.matrix.shape[0]} matrix for "
                                 f"{len(names)} bands")
            return self
        if sorted(self.band_names) != sorted(names):
            raise ValueError(f"{where}: the matrix is for bands {list(self.band_names)}, the band set "
                             f"has {names}")
        order = [list(self.band_names).index(name) for name in names]
        return dataclasses.replace(self, matrix=self.matrix[np.ix_(order, order)], band_names=tuple(names))

    def covariance(self, albedo) -> np.ndarray:
        """(..., n, n) covariance of the albedo error at albedo (..., n)."""
        albedo = np.asarray(albedo, dtype=np.float64)
        n = albedo.shape[-1]
        if self.kind == "absolute":
            return np.broadcast_to(self.sigma ** 2 * np.eye(n), albedo.shape[:-1] + (n, n)).copy()
        matrix = (self.sigma ** 2 * np.eye(n) + self.common ** 2 if self.kind == "relative" else self.matrix)
        if matrix.shape != (n, n):
            raise ValueError(f"the noise covariance is {matrix.shape[0]} x {matrix.shape[0]}, the band "
                             f"set has {n} bands")
        return albedo[..., :, None] * matrix * albedo[..., None, :]

    def to_json(self) -> dict:
        out = {"kind": self.kind}
        if self.parametric:
            out["sigma"] = self.sigma
            out["meaning"] = ("standard deviation relative to the albedo, independent bands"
                              if self.kind == "relative" else
                              "standard deviation in lobe-albedo units, independent bands")
            if self.common > 0:
                out["common"] = self.common
                out["meaning"] += "; common: a relative error shared by every band"
        else:
            out["matrix"] = self.matrix.tolist()
            out["bands"] = list(self.band_names) if self.band_names else None
            out["source"] = self.source
            out["meaning"] = "band covariance of relative albedo errors"
        return out


def check_covariance(matrix, where="covariance") -> np.ndarray:
    """``matrix`` as a float array if it is a finite, symmetric, positive definite square matrix;
    else ``ValueError`` naming ``where`` and the problem."""
    try:
        matrix = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: the covariance must be a square matrix of numbers") from None
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1] or matrix.shape[0] == 0:
        raise ValueError(f"{where}: the covariance must be a square matrix, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError(f"{where}: the covariance has a value that is not finite")
    scale = float(np.max(np.abs(matrix)))
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-9 * scale):
        raise ValueError(f"{where}: the covariance is not symmetric")
    smallest = float(np.linalg.eigvalsh(matrix)[0])
    if smallest <= 1e-12 * scale:
        raise ValueError(f"{where}: the covariance is not positive definite (smallest eigenvalue "
                         f"{smallest:.3g})")
    return 0.5 * (matrix + matrix.T)


def white_noise(sigma, relative=True, common=0.0) -> NoiseModel:
    """Independent bands with standard deviation ``sigma x albedo`` (relative) or ``sigma``, plus
    (relative only) a relative error ``common`` that every band shares."""
    return NoiseModel("relative" if relative else "absolute", sigma=sigma, common=common)


def read_covariance(path) -> NoiseModel:
    """A :class:`NoiseModel` from a JSON file ``{"bands": [names], "covariance": [[...]]}``
    (``bands`` optional: without it the rows follow the band set's order); the matrix is the
    band covariance of relative albedo errors (0.03^2 for a 3% rms error). Errors name the file."""
    from polarbssrdf.io.jsonfile import read_json_file

    path = Path(path)
    data = read_json_file(path, "covariance file")
    if not isinstance(data, dict) or "covariance" not in data:
        raise ValueError(f"{path}: a covariance file is a JSON object with key 'covariance' (a bands x "
                         "bands matrix of relative errors) and optionally 'bands' (their names)")
    unknown = sorted(set(data) - {"covariance", "bands", "description"})
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown}; known: ['bands', 'covariance', 'description']")
    names = data.get("bands")
    if names is not None:
        if not (isinstance(names, list) and all(isinstance(n, str) for n in names)) or len(set(names)) != len(names):
            raise ValueError(f"{path}: 'bands' must be a list of distinct band names")
        names = tuple(names)
    return NoiseModel("covariance", matrix=data["covariance"], band_names=names, source=str(path))


def albedo_jacobian(C_m, beta_m, C_h_out, C_h_in, bands, eta, thickness_mm=DEFAULT_THICKNESS_MM,
                    gamma=DEFAULT_GAMMA, exit_fraction=None, step=JACOBIAN_STEP, nuisances=()):
    """Per-band albedo (..., n) and its Jacobian (..., n, 4 + m) in (C_m, beta_m, C_h_out, C_h_in)
    and then the ``m`` nuisances named in ``nuisances`` (of :data:`~.nuisances.NUISANCES`).

    ``rho_b = R_bar_b / c(eta)`` with ``R_bar_b`` :func:`~.model.band_reflectance` (the band
    integral by the bands' spectral quadrature, the model of synth and of the biophysical fit) and ``c = exit_fraction(eta)`` (pass
    :func:`polarbssrdf.render.subsurface.subsurface_exit_fraction` for the lobe albedo of
    eq. 19; ``None`` gives the model's flux ``R_bar``, the same up to a per-texel factor, which
    relative noise does not see). Central differences of step ``step``; a chromophore closer than
    ``step`` to 0 or 1 is differenced about the nearest point ``step`` inside."""
    unknown = [n for n in nuisances if n not in NUISANCES]
    if unknown:
        raise ValueError(f"unknown nuisance(s) {unknown}; known: {list(NUISANCES)}")
    params = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in
                                   (C_m, beta_m, C_h_out, C_h_in, thickness_mm, gamma, eta)))
    names = PARAMETERS + tuple(nuisances)
    columns = [params[j] for j in range(4)] + [params[4 + NUISANCES.index(n)] for n in nuisances]
    theta = np.stack(columns, axis=-1)
    p = len(names)
    centre = theta.copy()
    centre[..., :4] = np.clip(theta[..., :4], step, 1.0 - step)
    # stencil: the point, then +step and -step in each unknown
    offsets = np.concatenate([step * np.eye(p), -step * np.eye(p)])
    points = np.concatenate([theta[..., None, :], centre[..., None, :] + offsets], axis=-2)
    value = {name: points[..., j] for j, name in enumerate(names)}
    held = {n: params[4 + j][..., None] for j, n in enumerate(NUISANCES) if n not in value}
    value.update(held)
    values = band_reflectance(*(value[n] for n in PARAMETERS), list(bands), eta=value["eta"],
                              thickness_mm=value["thickness_mm"], gamma=value["gamma"])
    if exit_fraction is not None:
        eta_points = np.broadcast_to(value["eta"], values.shape[:-1])
        values = values / np.asarray(exit_fraction(eta_points), dtype=np.float64)[..., None]
    albedo = values[..., 0, :]
    jacobian = (values[..., 1:1 + p, :] - values[..., 1 + p:, :]) / (2.0 * step)
    return albedo, np.swapaxes(jacobian, -1, -2)


def fisher_information(jacobian, covariance) -> np.ndarray:
    """``J^T S^-1 J``, (..., p, p), for J (..., n, p) and S (..., n, n)."""
    return np.swapaxes(jacobian, -1, -2) @ np.linalg.solve(covariance, jacobian)


def marginal_information(information, nuisance_prior_std) -> np.ndarray:
    """The chromophores' information (..., 4, 4) left when the last ``m`` unknowns of the joint
    information (..., 4 + m, 4 + m) are nuisances of Gaussian prior standard deviations
    ``nuisance_prior_std`` (m,), marginalized: the Schur complement
    ``F_cc - F_cn (F_nn + diag(1 / s^2))^-1 F_nc``, whose inverse is the chromophores' block of
    the joint posterior covariance. A prior std of 0 (or none given) is a known nuisance."""
    information = np.asarray(information, dtype=np.float64)
    s = np.asarray(nuisance_prior_std, dtype=np.float64)
    if s.size == 0:
        return information[..., :4, :4]
    if information.shape[-1] != 4 + s.size:
        raise ValueError(f"{s.size} nuisance prior(s) for a {information.shape[-1]} x {information.shape[-1]} "
                         "information matrix")
    if not np.all(np.isfinite(s) & (s >= 0)):
        raise ValueError(f"nuisance prior standard deviations must be finite and >= 0, got {s.tolist()}")
    known = s == 0
    if known.all():
        return information[..., :4, :4]
    keep = np.concatenate([np.ones(4, bool), ~known])
    information = information[..., keep, :][..., keep]
    s = s[~known]
    cc, cn, nn = information[..., :4, :4], information[..., :4, 4:], information[..., 4:, 4:]
    nn = nn + np.diag(1.0 / s ** 2)
    return cc - cn @ np.linalg.solve(nn, np.swapaxes(cn, -1, -2))


def bound_from_information(information, scale, prior_std=None):
    """The Cramér-Rao (or, with ``prior_std``, Bayesian) covariance of (..., 4, 4) information.

    Parameters
    ----------
    information : (..., 4, 4) array
        Fisher information in the parameters' own units.
    scale : (4,) array
        Units in which singularity is judged (the Table 2 ranges).
    prior_std : (..., 4) array, optional
        Standard deviations of a Gaussian prior (same units as the parameters).

    Returns
    -------
    covariance : (..., 4, 4) array, inf on the rows and columns of chromophores the bands
        cannot see
    std : (..., 4) array
    condition : (...,) array, largest over smallest eigenvalue of the scaled information (inf
        where singular)
    """
    scale = np.asarray(scale, dtype=np.float64)
    scaled = information * scale[:, None] * scale[None, :]
    if prior_std is not None:
        prior = np.broadcast_to(np.asarray(prior_std, dtype=np.float64) / scale, scaled.shape[:-1])
        scaled = scaled + np.einsum("...i,ij->...ij", 1.0 / prior ** 2, np.eye(4))
    values, vectors = np.linalg.eigh(0.5 * (scaled + np.swapaxes(scaled, -1, -2)))
    largest = values[..., -1:]
    seen = values > SINGULAR_TOLERANCE * np.maximum(largest, 1e-300)
    inverse = np.where(seen, 1.0 / np.where(seen, values, 1.0), 0.0)
    covariance = np.einsum("...ik,...k,...jk->...ij", vectors, inverse, vectors)
    # a chromophore with a share (beyond rounding) of an unseen direction is not identifiable
    hidden = np.einsum("...ik,...k->...i", vectors ** 2, (~seen).astype(np.float64)) > 1e-9
    covariance = np.where(hidden[..., :, None] | hidden[..., None, :], np.inf, covariance)
    covariance = covariance * scale[:, None] * scale[None, :]
    std = np.sqrt(np.diagonal(covariance, axis1=-2, axis2=-1))
    with np.errstate(divide="ignore"):
        condition = np.where(seen.all(axis=-1), largest[..., 0] / values[..., 0], np.inf)
    return covariance, std, condition


def table2_scale() -> np.ndarray:
    """The Table 2 range (max - min of the eight means) of each chromophore, (4,)."""
    ranges = table2_ranges()
    return np.array([ranges[n][1] - ranges[n][0] for n in PARAMETERS])


def prior_spreads(prior, rows):
    """(R, 4) prior standard deviations for ``rows`` of Table 2: ``None`` (no prior), ``"row"``
    (each row's own Table 2 "(std)"), ``"rows"`` (the spread of the eight Table 2 means), or a
    dict ``name -> std`` for all rows."""
    if prior is None:
        return None
    if prior == "row":
        return np.array([[TABLE2_STD[row][n] for n in PARAMETERS] for row in rows])
    if prior == "rows":
        across = table2_spread_across_rows()
        return np.tile([across[n] for n in PARAMETERS], (len(rows), 1))
    if isinstance(prior, dict):
        missing = [n for n in PARAMETERS if n not in prior]
        unknown = sorted(set(prior) - set(PARAMETERS))
        if missing or unknown:
            raise ValueError(f"a prior gives a standard deviation for each of {list(PARAMETERS)}; "
                             f"missing {missing}, unknown {unknown}")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in prior.values()):
            raise ValueError(f"prior standard deviations must be numbers > 0, got {prior}")
        return np.tile([float(prior[n]) for n in PARAMETERS], (len(rows), 1))
    raise ValueError(f"prior must be None, 'row', 'rows' or a dict of standard deviations, got {prior!r}")


@dataclasses.dataclass
class BandBounds:
    """Bounds of one band set at each skin (Table 2 row).

    ``std`` (R, 4) in volume fractions (inf where not identifiable), ``covariance``
    (R, 4, 4), ``albedo`` (R, n), ``jacobian`` (R, n, 4 + m: the chromophores, then the
    nuisances of ``nuisances``), ``information`` (R, 4, 4: the chromophores', nuisances
    marginalized), ``condition`` (R,); ``nuisances`` name -> prior std of the marginalized
    unknowns (empty: all held at their values)."""

    bands: list
    rows: list
    noise: NoiseModel
    prior: object
    albedo: np.ndarray
    jacobian: np.ndarray
    information: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    condition: np.ndarray
    nuisances: dict = dataclasses.field(default_factory=dict)

    @property
    def fraction_of_range(self) -> np.ndarray:
        """(R, 4) bound as a fraction of each chromophore's Table 2 range."""
        return self.std / table2_scale()

    @property
    def identifiable(self) -> np.ndarray:
        return np.isfinite(self.std)

    def criterion(self, kind="mean") -> float:
        return float(criterion_value(self.fraction_of_range, kind))

    def correlation(self) -> np.ndarray:
        """(R, 4, 4) correlation of the bound's errors (NaN where not identifiable)."""
        with np.errstate(invalid="ignore"):
            return self.covariance / (self.std[:, :, None] * self.std[:, None, :])


def criterion_value(fraction, kind="mean"):
    """:data:`CRITERIA` over the last two axes (rows, chromophores) of bound fractions."""
    if kind not in CRITERIA:
        raise ValueError(f"criterion must be one of {sorted(CRITERIA)}, got {kind!r}")
    fraction = np.asarray(fraction, dtype=np.float64)
    return fraction.mean(axis=(-2, -1)) if kind == "mean" else fraction.max(axis=(-2, -1))


def _row_arrays(rows):
    rows = list(TABLE2) if rows is None else [tuple(r) for r in rows]
    unknown = [r for r in rows if r not in TABLE2]
    if unknown:
        raise ValueError(f"unknown Table 2 row(s) {unknown}; known: {sorted(TABLE2)}")
    params = {n: np.array([getattr(TABLE2[r], n) for r in rows]) for n in PARAMETERS + ("eta",)}
    return rows, params


def check_nuisances(nuisances) -> dict:
    """``name -> prior std`` of the nuisances to marginalize: ``None`` or ``{}`` (all held),
    ``"default"`` (all of :data:`~.nuisances.NUISANCES` at :func:`~.nuisances.nuisance_prior_std`,
    the spreads the biophysical fit assumes), or a dict (std >= 0; 0 holds it)."""
    if nuisances is None:
        return {}
    if nuisances == "default":
        return {n: nuisance_prior_std(n) for n in NUISANCES}
    if not isinstance(nuisances, dict):
        raise ValueError(f"nuisances must be None, 'default' or a dict name -> prior std, got {nuisances!r}")
    unknown = sorted(set(nuisances) - set(NUISANCES))
    if unknown:
        raise ValueError(f"unknown nuisance(s) {unknown}; known: {list(NUISANCES)}")
    out = {}
    for name in NUISANCES:
        if name in nuisances:
            value = nuisances[name]
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"nuisance {name}: the prior std must be a number >= 0, got {value!r}")
            if value > 0:
                out[name] = float(value)
    return out


def band_bounds(bands, noise, rows=None, prior=None, thickness_mm=DEFAULT_THICKNESS_MM, gamma=DEFAULT_GAMMA,
                exit_fraction=None, nuisances=None) -> BandBounds:
    """Cramér-Rao bounds of the four chromophores for ``bands`` at Table 2 rows (all by default),
    each row at its own eta. ``prior``: see :func:`prior_spreads` (Bayesian bound).
    ``nuisances``: the skin's other unknowns to marginalize, see :func:`check_nuisances`."""
    bands = list(bands)
    if not bands:
        raise ValueError("the band set is empty")
    noise = noise.for_bands(bands)
    nuisances = check_nuisances(nuisances)
    rows, params = _row_arrays(rows)
    albedo, jacobian = albedo_jacobian(*(params[n] for n in PARAMETERS), bands, params["eta"], thickness_mm,
                                       gamma, exit_fraction, nuisances=tuple(nuisances))
    joint = fisher_information(jacobian, noise.covariance(albedo))
    information = marginal_information(joint, list(nuisances.values()))
    covariance, std, condition = bound_from_information(information, table2_scale(), prior_spreads(prior, rows))
    return BandBounds(bands, rows, noise, prior, albedo, jacobian, information, covariance, std, condition,
                      nuisances)


def band_pins(bounds: BandBounds, thickness_mm=DEFAULT_THICKNESS_MM, gamma=DEFAULT_GAMMA, exit_fraction=None):
    """(n_bands, R, 4) ratio of each chromophore's bound without band ``b`` to the bound with all
    bands (inf where removing the band makes it unidentifiable): the band "pins" the chromophore
    whose bound grows most without it. (``thickness_mm``, ``gamma``, ``exit_fraction``: those of
    ``bounds``, whose Jacobian is reused; kept for the callers.)"""
    out = []
    for b in range(len(bounds.bands)):
        keep = [i for i in range(len(bounds.bands)) if i != b]
        if not keep:
            out.append(np.full(bounds.std.shape, np.inf))
            continue
        noise = bounds.noise
        if not noise.parametric:
            names = noise.band_names or tuple(band.name for band in bounds.bands)
            order = [names.index(bounds.bands[i].name) for i in keep]
            noise = dataclasses.replace(noise, matrix=noise.matrix[np.ix_(order, order)],
                                        band_names=tuple(names[i] for i in order))
        # the same model's rows without band b (a subset's own quadrature would be another
        # model, up to its 0.05% error, and could seem to gain from a band's removal)
        albedo, jacobian = bounds.albedo[:, keep], bounds.jacobian[:, keep]
        joint = fisher_information(jacobian, noise.for_bands([bounds.bands[i] for i in keep]).covariance(albedo))
        information = marginal_information(joint, list(bounds.nuisances.values()))
        _, std, _ = bound_from_information(information, table2_scale(), prior_spreads(bounds.prior, bounds.rows))
        with np.errstate(invalid="ignore"):
            out.append(std / bounds.std)
    return np.stack(out)


@dataclasses.dataclass
class BandDesign:
    """Result of :func:`design_bands`: the chosen candidates (indices, in the order picked),
    the criterion's value, its value after the exhaustive start and each greedy pick
    (``history``), the search's name and how many band sets were scored."""

    candidates: list
    chosen: list
    value: float
    criterion: str
    search: str
    history: list
    evaluated: int

    @property
    def bands(self):
        return [self.candidates[i] for i in self.chosen]


def _per_band_terms(candidates, noise, rows, thickness_mm, gamma, exit_fraction, nuisances):
    """Per candidate band alone, in units of the noise: ``(outer, vector)`` with ``outer``
    (R, n, p, p) ``g g^T`` and ``vector`` (R, n, p) ``g``, where ``g = J_b / (sigma rho_b)``
    (relative noise) or ``J_b / sigma`` (absolute), p = 4 + the nuisances."""
    _, params = _row_arrays(rows)
    albedo, jacobian = albedo_jacobian(*(params[n] for n in PARAMETERS), candidates, params["eta"],
                                       thickness_mm, gamma, exit_fraction, nuisances=tuple(nuisances))
    deviation = noise.sigma * albedo if noise.kind == "relative" else np.full(albedo.shape, noise.sigma)
    g = jacobian / deviation[..., None]
    return np.einsum("rbi,rbj->rbij", g, g), g


def _subset_information(outer, vector, subsets, common_to_sigma):
    """(R, M, p, p) joint information of each subset (M, k) of candidates: the per-band terms
    summed, less the band-common noise's share. With relative covariance
    ``sigma^2 (I + c^2 1 1^T)`` (``c`` = ``common_to_sigma``), Sherman-Morrison gives
    ``F = sum g g^T - c^2 / (1 + k c^2) (sum g)(sum g)^T``."""
    information = outer[:, subsets].sum(axis=2)
    if common_to_sigma > 0:
        total = vector[:, subsets].sum(axis=2)  # (R, M, p)
        k = subsets.shape[1]
        information = information - (common_to_sigma ** 2 / (1.0 + k * common_to_sigma ** 2)) * np.einsum(
            "rmi,rmj->rmij", total, total)
    return information


def _subset_values(terms, subsets, prior_std, kind, nuisance_std, common_to_sigma, chunk=20000):
    """Criterion of each subset (M, k) of candidates (:func:`_per_band_terms`)."""
    scale = table2_scale()
    outer, vector = terms
    out = np.empty(len(subsets))
    for start in range(0, len(subsets), chunk):
        part = subsets[start:start + chunk]
        joint = _subset_information(outer, vector, part, common_to_sigma)  # (R, M, p, p)
        information = marginal_information(joint, nuisance_std)
        prior = None if prior_std is None else prior_std[:, None, :]
        _, std, _ = bound_from_information(information, scale, prior)
        out[start:start + len(part)] = criterion_value(np.moveaxis(std / scale, 0, 1), kind)
    return out


def design_bands(candidates, k, noise, criterion="mean", search="greedy", rows=None, prior=None,
                 thickness_mm=DEFAULT_THICKNESS_MM, gamma=DEFAULT_GAMMA, exit_fraction=None,
                 nuisances=None) -> BandDesign:
    """Pick ``k`` of ``candidates`` (bands) that minimize ``criterion`` (:data:`CRITERIA`) over
    Table 2 rows, under parametric ``noise`` (relative, with its band-common part, or absolute:
    the information of a set follows from its bands' terms, :func:`_subset_information`), with
    ``nuisances`` marginalized (:func:`check_nuisances`).

    ``search="exhaustive"`` evaluates every subset of size ``k`` (refused beyond
    :data:`EXHAUSTIVE_LIMIT` subsets); ``"greedy"`` starts from the exhaustive best set of
    ``min(k, 4)`` (four is the fewest that can pin four chromophores without a prior, so a
    greedy start from one band has nothing to compare) and then adds, one at a time, the
    candidate that lowers the criterion most."""
    candidates = list(candidates)
    if not noise.parametric:
        raise ValueError("the design mode needs a parametric noise model (relative or absolute): a "
                         "measured band covariance belongs to one band set")
    if not (isinstance(k, int) and 1 <= k <= len(candidates)):
        raise ValueError(f"k must be an integer in [1, {len(candidates)}] (the number of candidates), got {k!r}")
    if search not in ("greedy", "exhaustive"):
        raise ValueError(f"search must be 'greedy' or 'exhaustive', got {search!r}")
    criterion_value(np.zeros((1, 4)), criterion)  # validates the name
    rows, _ = _row_arrays(rows)
    prior_std = prior_spreads(prior, rows)
    nuisances = check_nuisances(nuisances)
    terms = _per_band_terms(candidates, noise, rows, thickness_mm, gamma, exit_fraction, nuisances)
    nuisance_std = list(nuisances.values())
    common_to_sigma = noise.common / noise.sigma
    n = len(candidates)

    def exhaustive(size):
        count = math.comb(n, size)
        if count > EXHAUSTIVE_LIMIT:
            raise ValueError(f"an exhaustive search of {size} of {n} candidates is {count} subsets "
                             f"(limit {EXHAUSTIVE_LIMIT}); use search='greedy'")
        subsets = np.array(list(itertools.combinations(range(n), size)), dtype=np.int64)
        values = _subset_values(terms, subsets, prior_std, criterion, nuisance_std, common_to_sigma)
        best = int(np.argmin(values))
        return list(subsets[best]), float(values[best]), count

    if search == "exhaustive":
        chosen, value, evaluated = exhaustive(k)
        return BandDesign(candidates, chosen, value, criterion, "exhaustive", [value], evaluated)
    chosen, value, evaluated = exhaustive(min(k, 4))
    history = [value]
    while len(chosen) < k:
        rest = [i for i in range(n) if i not in chosen]
        subsets = np.array([chosen + [i] for i in rest], dtype=np.int64)
        values = _subset_values(terms, subsets, prior_std, criterion, nuisance_std, common_to_sigma)
        evaluated += len(rest)
        best = int(np.argmin(values))
        chosen, value = chosen + [rest[best]], float(values[best])
        history.append(value)
    return BandDesign(candidates, chosen, value, criterion, "greedy", history, evaluated)


def design_comb_pair(periods_nm, phases_nm, noise, criterion="mean", rows=None, prior=None,
                     thickness_mm=DEFAULT_THICKNESS_MM, gamma=DEFAULT_GAMMA, exit_fraction=None, nuisances=None):
    """The comb-filter pair (period, phase in nm) whose 6 bands (the default camera's B, G, R
    behind the pair, :func:`polarbssrdf.spectral.comb_pair_bands`) minimize ``criterion``; a
    grid search. Returns ``(period, phase, value, grid)`` with ``grid`` a list of
    ``(period, phase, value)``."""
    from polarbssrdf.spectral import comb_pair_bands

    grid = []
    for period in periods_nm:
        for phase in phases_nm:
            bounds = band_bounds(comb_pair_bands(period, phase), noise, rows, prior, thickness_mm, gamma,
                                 exit_fraction, nuisances)
            grid.append((float(period), float(phase), bounds.criterion(criterion)))
    if not grid:
        raise ValueError("the comb-filter grid is empty")
    best = min(grid, key=lambda item: item[2])
    return best[0], best[1], best[2], grid


def _number(value):
    """JSON number, or None for an infinite / undefined bound."""
    value = float(value)
    return value if math.isfinite(value) else None


def report_json(bounds: BandBounds, pins=None) -> dict:
    """The band report as a JSON-ready dict (``schema: polarbssrdf.band_report``). Infinite
    bounds (not identifiable) are ``null``."""
    scale = table2_scale()
    rows = []
    correlation = bounds.correlation()
    for r, row in enumerate(bounds.rows):
        skin = TABLE2[row]
        rows.append({
            "region": row[0], "type": row[1],
            "parameters": {n: getattr(skin, n) for n in PARAMETERS + ("eta",)},
            "albedo": [float(a) for a in bounds.albedo[r]],
            "std": {n: _number(bounds.std[r, j]) for j, n in enumerate(PARAMETERS)},
            "fraction_of_range": {n: _number(bounds.std[r, j] / scale[j]) for j, n in enumerate(PARAMETERS)},
            "correlation": [[_number(x) for x in line] for line in correlation[r]],
            "condition_number": _number(bounds.condition[r]),
            "identifiable": {n: bool(bounds.identifiable[r, j]) for j, n in enumerate(PARAMETERS)},
        })
    out = {
        "schema": REPORT_SCHEMA, "schema_version": REPORT_SCHEMA_VERSION,
        "parameters": list(PARAMETERS),
        "units": {"std": "volume fraction", "fraction_of_range": "fraction of the Table 2 range",
                  "table2_range": dict(zip(PARAMETERS, scale.tolist()))},
        "bands": [{"name": b.name, "centroid_nm": round(b.centroid_nm, 2), "description": b.description}
                  for b in bounds.bands],
        "noise": bounds.noise.to_json(),
        "prior": bounds.prior,
        "nuisances": {"marginalized_prior_std": dict(bounds.nuisances),
                      "held": [n for n in NUISANCES if n not in bounds.nuisances],
                      "units": {"thickness_mm": "mm", "gamma": "fraction", "eta": "1"}},
        "bound": "bayesian" if bounds.prior is not None else "cramer-rao",
        "criteria": {kind: _number(bounds.criterion(kind)) for kind in CRITERIA},
        "criteria_meaning": dict(CRITERIA),
        "rows": rows,
    }
    if pins is not None:
        out["pins"] = pins_json(bounds, pins)
    return out


def pins_json(bounds: BandBounds, pins) -> list:
    """Per band: the geometric mean over rows of each chromophore's bound growth without it, and
    the chromophore it pins most."""
    out = []
    with np.errstate(divide="ignore", invalid="ignore"):
        growth = np.exp(np.log(pins).mean(axis=1))  # (n_bands, 4)
    for b, band in enumerate(bounds.bands):
        best = int(np.argmax(growth[b]))
        out.append({"band": band.name, "centroid_nm": round(band.centroid_nm, 2),
                    "bound_growth_without_it": {n: _number(growth[b, j]) for j, n in enumerate(PARAMETERS)},
                    "pins": PARAMETERS[best]})
    return out


def _cell(value, digits=4):
    return "inf" if not math.isfinite(value) else f"{value:.{digits}f}"


def format_report(bounds: BandBounds, pins=None) -> str:
    """A readable table: per Table 2 row the bound of each chromophore (volume fraction and % of
    its Table 2 range), then the criteria and what each band pins."""
    scale = table2_scale()
    lines = [f"bands: {', '.join(f'{b.name} ({b.centroid_nm:.0f} nm)' for b in bounds.bands)}",
             f"noise: {describe_noise(bounds.noise)}" + (f"; prior: {bounds.prior}" if bounds.prior else ""),
             f"skin's other unknowns: {describe_nuisances(bounds.nuisances)}",
             f"{'Bayesian' if bounds.prior is not None else 'Cramér-Rao'} bound, standard deviation "
             "(volume fraction) and % of the Table 2 range:",
             f"{'row':<14}" + "".join(f"{n:>18}" for n in PARAMETERS) + f"{'condition':>12}"]
    for r, row in enumerate(bounds.rows):
        cells = "".join(f"{_cell(bounds.std[r, j]):>9} {_cell(100 * bounds.std[r, j] / scale[j], 1):>6}% "
                        for j in range(4))
        lines.append(f"{row[0] + ' ' + row[1]:<14}{cells} {_cell(bounds.condition[r], 0):>10}")
    mean = 100 * bounds.fraction_of_range.mean(axis=0)
    lines.append(f"{'mean':<14}" + "".join(f"{'':>9} {_cell(m, 1):>6}% " for m in mean))
    lines.append("criteria: " + ", ".join(f"{k} {_cell(100 * bounds.criterion(k), 1)}% of the range"
                                          for k in CRITERIA))
    if pins is not None:
        lines.append("bound growth (geometric mean over rows) when a band is removed:")
        lines.append(f"{'band':<14}" + "".join(f"{n:>10}" for n in PARAMETERS) + "   pins")
        for item in pins_json(bounds, pins):
            growth = item["bound_growth_without_it"]
            lines.append(f"{item['band']:<14}" + "".join(
                f"{('inf' if growth[n] is None else f'{growth[n]:.2f}x'):>10}" for n in PARAMETERS)
                + f"   {item['pins']}")
    return "\n".join(lines) + "\n"


def describe_nuisances(nuisances: dict) -> str:
    """One line: which of :data:`~.nuisances.NUISANCES` are marginalized (with their prior std)
    and which are held at their values."""
    units = {"thickness_mm": " mm", "gamma": "", "eta": ""}
    parts = []
    if nuisances:
        parts.append("marginalized (prior std) " + ", ".join(f"{n} {v:.3g}{units[n]}" for n, v in nuisances.items()))
    held = [n for n in NUISANCES if n not in nuisances]
    if held:
        parts.append("held at their values: " + ", ".join(held))
    return "; ".join(parts)


def describe_noise(noise: NoiseModel) -> str:
    if noise.kind == "relative":
        common = f" + {100 * noise.common:g}% common to all bands" if noise.common > 0 else ""
        return f"white, {100 * noise.sigma:g}% of the albedo per band{common}"
    if noise.kind == "absolute":
        return f"white, {noise.sigma:g} albedo units per band"
    rms = np.sqrt(np.diag(noise.matrix))
    return (f"band covariance from {noise.source or 'a matrix'} (relative rms {100 * rms.min():.2g}-"
            f"{100 * rms.max():.2g}%)")


def write_report(path, data: dict, overwrite: bool = False) -> None:
    """Write the report JSON atomically (temporary file + rename); an existing file only
    with ``overwrite``."""
    from polarbssrdf.io.atomic import atomic_write_text

    atomic_write_text(Path(path), json.dumps(data, indent=1) + "\n", overwrite=overwrite)
