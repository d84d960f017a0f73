"""The face's blood oxygenation from the shape of its band albedo (supplement sec. 5.3, eq. 47).

The oxygen fraction ``gamma`` of the blood mixes the oxy- and deoxyhemoglobin spectra, whose
difference the bands between 530 and 605 nm see; no combination of the four chromophores
mimics it. A face whose ``gamma`` is off the model's is therefore not fitted by any
chromophores, and the residual of the per-block inversion of eq. 47 has a sharp minimum near
the face's ``gamma`` (forehead III, 128^2, thickness and index off the model's: 0.705 for
0.709 noise-free, 0.703 at 1% noise). Holding ``gamma`` at the population's 0.75 instead left
that face's ``C_h_in`` 20x the constant map's error (bench/RESULTS.md, issue 31). The
thickness has no such signature with six bands (it is nearly degenerate with the dermal
blood, docs/biophysical.md) and stays held.

:func:`face_oxygenation` finds where each block's residual is least (a parabola through the
block's three lowest of the residuals evaluated over the face: three evaluations moved until
they bracket the summed residual's minimum, then refined once) and takes the texel-weighted
mean of those block minima. The minimum of the summed residual instead weighs each block by
its curvature, i.e. by its blood: on a face whose oxygenation varies within it by 0.03 it was
0.024 off the face's mean (3.8 of its std), the mean of the block minima 0.004
(bench/RESULTS.md, 2026-12-04). Its uncertainty combines a delete-a-group jackknife over
stripes of blocks (the noise and what varies over the face), the shift a face thickness off
the model's by its hyperprior std would cause (the linearized band model,
:func:`~polarbssrdf.skin.band_information.albedo_jacobian`), and the distance between the two
weightings (how much the within-face variation matters), with the population hyperprior
``nuisance_mean["gamma"]``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from polarbssrdf.inverse.biophysical.model import PARAMETERS
from polarbssrdf.inverse.biophysical.start import FACE_MEAN_BLOCK_MM, block_inversion, block_mean
from polarbssrdf.skin.band_information import albedo_jacobian
from polarbssrdf.skin.quadrature import DESIGN_BOX

OXYGENATION_STEP = 0.05
"""Half-width of the first three-point stencil in ``gamma`` (fraction): the residual is close to
a parabola over +-0.05 around its minimum (measured on the issue 31 faces)."""

MAX_STENCIL_MOVES = 6
"""Moves of the stencil toward a minimum at its edge before the box's edge is taken."""

JACKKNIFE_GROUPS = 8
"""Stripes of blocks (equal counts, in texture rows) the jackknife leaves out in turn."""


@dataclasses.dataclass
class OxygenationEstimate:
    """The face's ``gamma`` and how well it is known.

    ``gamma`` the estimate after the hyperprior, ``std`` its standard deviation;
    ``profile_gamma`` the summed residual's minimum, ``block_gamma`` the mean of the blocks'
    minima (the estimate before the hyperprior); its error parts ``jackknife_std`` (the
    spread over the face), ``thickness_std`` (the shift per mm of thickness times the
    thickness hyperprior's std) and ``weighting_std`` (the distance between the two);
    ``evaluations`` the ``(gamma, residual)`` pairs computed."""

    gamma: float
    std: float
    profile_gamma: float
    jackknife_std: float
    thickness_std: float
    thickness_shift_per_mm: float
    evaluations: list
    block_gamma: float = float("nan")
    weighting_std: float = 0.0

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["evaluations"] = [[round(g, 5), float(s)] for g, s in self.evaluations]
        return out


def parabola_vertex(x, y):
    """``(vertex, curvature)`` of the parabola through three points ``(x_i, y_i)``; curvature is
    ``y''`` (<= 0 means no minimum between them)."""
    x0, x1, x2 = x
    y0, y1, y2 = y
    d01, d12, d02 = (y1 - y0) / (x1 - x0), (y2 - y1) / (x2 - x1), x2 - x0
    curvature = 2.0 * (d12 - d01) / d02
    if curvature <= 0:
        return float("nan"), float(curvature)
    # the slope at the midpoint of x0, x1 is d01; the vertex is where the slope is 0
    vertex = 0.5 * (x0 + x1) - d01 / curvature
    return float(vertex), float(curvature)


class _Profile:
    """Texel-weighted sum of squared relative residuals of the block inversion at ``gamma``."""

    def __init__(self, rbar, valid, atlas, bands, eta, config, thickness_mm):
        self.args = (rbar, valid, atlas, bands, eta, config, FACE_MEAN_BLOCK_MM)
        self.thickness_mm = thickness_mm
        self.values = {}
        self.blocks = {}

    def __call__(self, gamma):
        gamma = round(float(gamma), 5)
        if gamma not in self.values:
            rbar, valid = self.args[0], self.args[1]
            # the small start table: its build dominates an evaluation (one per index bin); with
            # the default one an evaluation took 3x as long and the issue 31 faces' estimates
            # moved by 0.0003-0.011, within 1.4 of their std (bench/RESULTS.md)
            maps, ok, factor = block_inversion(*self.args, thickness_mm=self.thickness_mm, gamma=gamma,
                                               table_size="small")
            texels = block_mean(valid.astype(np.float64), np.ones_like(valid, dtype=np.float64), factor)[0]
            weight = (texels * factor ** 2)[ok]
            residual = maps["residual"][:, ok]
            per_block = weight * np.sum(residual ** 2, axis=0)
            self.values[gamma] = float(np.sum(per_block))
            self.blocks[gamma] = (maps, ok, weight, per_block)
        return self.values[gamma]

    def nearest_blocks(self, gamma):
        """``(maps, ok, weight, per_block)`` of the block inversion evaluated nearest ``gamma``."""
        return self.blocks[min(self.blocks, key=lambda g: abs(g - gamma))]


def _bracketed_vertex(profile, centre, step, low, high):
    """The vertex of the parabola through ``centre - step, centre, centre + step`` once the middle
    point is the lowest (the stencil moves toward the lower side, inside ``[low, high]``)."""
    for _ in range(MAX_STENCIL_MOVES + 1):
        centre = float(np.clip(centre, low + step, high - step))
        xs = (centre - step, centre, centre + step)
        ys = [profile(x) for x in xs]
        lowest = int(np.argmin(ys))
        if lowest == 1:
            vertex, curvature = parabola_vertex(xs, ys)
            return float(np.clip(vertex, xs[0], xs[2])), curvature, xs
        moved = centre + (step if lowest == 2 else -step)
        if np.isclose(np.clip(moved, low + step, high - step), centre):
            return xs[lowest], float("nan"), xs  # the minimum is at the box's edge
        centre = moved
    return xs[int(np.argmin(ys))], float("nan"), xs


def block_minima(profile):
    """``(gamma (n,), weight (n,))`` per block: the vertex of the parabola through the block's
    three lowest residuals of those evaluated (clipped to them; the lowest evaluation where
    they curve down), and its texel weight. Blocks not inverted at every evaluation are left
    out."""
    gammas = np.array(sorted(profile.blocks))
    oks = np.stack([profile.blocks[g][1] for g in gammas])
    everywhere = np.all(oks, axis=0)
    residuals = np.stack([_dense(profile.blocks[g], everywhere) for g in gammas])  # (G, n)
    weight = _dense(profile.blocks[gammas[0]], everywhere, column=2)
    minima = np.empty(residuals.shape[1])
    for b in range(residuals.shape[1]):
        lowest = np.sort(np.argsort(residuals[:, b])[:3])
        vertex, _ = parabola_vertex(gammas[lowest], residuals[lowest, b])
        minima[b] = (np.clip(vertex, gammas[lowest[0]], gammas[lowest[-1]]) if np.isfinite(vertex)
                     else gammas[np.argmin(residuals[:, b])])
    return minima, weight


def _dense(entry, keep, column=3):
    """One of a profile entry's per-block arrays (over its inverted blocks) at the blocks ``keep``."""
    _, ok, _, _ = entry
    full = np.full(ok.shape, np.nan)
    full[ok] = entry[column]
    return full[keep]


def jackknife_std(values, weight, groups=JACKKNIFE_GROUPS):
    """Delete-a-group jackknife standard deviation of the ``weight``-ed mean of ``values``: the
    blocks (in texture-row order) split into ``groups`` stripes of equal count (fewer, of two
    blocks each, on a face of fewer than ``2 groups`` blocks), the mean without each stripe in
    turn. NaN where there are fewer than 4 blocks."""
    n = values.size
    groups = min(groups, n // 2)
    if groups < 2:
        return float("nan")
    stripe = np.arange(n) * groups // n  # block order is the texture's row-major order
    means = np.array([np.sum(weight[stripe != g] * values[stripe != g]) / np.sum(weight[stripe != g])
                      for g in range(groups)])
    return float(np.sqrt((groups - 1) / groups * np.sum((means - means.mean()) ** 2)))


def thickness_shift_per_mm(chromophores, eta, thickness_mm, gamma, bands):
    """How far an estimate of ``gamma`` (fitted beside the four chromophores, thickness held)
    moves per mm of error in the held thickness, at one skin (the face's mean chromophores):
    the ``gamma`` component of ``A^+ j_t``, with ``A`` the relative band Jacobian in the
    chromophores and ``gamma`` and ``j_t`` its thickness column (the linearized model)."""
    albedo, jacobian = albedo_jacobian(*(chromophores[n] for n in PARAMETERS), bands, eta, thickness_mm, gamma,
                                       nuisances=("gamma", "thickness_mm"))
    relative = jacobian / albedo[:, None]
    coefficients, *_ = np.linalg.lstsq(relative[:, :5], relative[:, 5], rcond=None)
    return float(coefficients[4])


def face_oxygenation(rbar, valid, atlas, bands, eta, config, thickness_mm) -> OxygenationEstimate:
    """The face's ``gamma`` (module docstring) from the skin model's flux ``rbar`` (n_bands, T, T)
    over the ``valid`` texels, the index map ``eta`` and the held ``thickness_mm``; the start
    and hyperprior are ``config.nuisance_mean["gamma"]``, the thickness hyperprior's std
    ``config.nuisance_mean["thickness_mm"][1]``."""
    low, high = DESIGN_BOX["gamma"]
    prior_mean, prior_std = config.nuisance_mean["gamma"]
    profile = _Profile(rbar, valid, atlas, bands, eta, config, thickness_mm)
    first, _, _ = _bracketed_vertex(profile, prior_mean, OXYGENATION_STEP, low, high)
    # the residual is not quite a parabola over +-0.05 (one bracket alone left a face 0.014 low,
    # three of its std): refine at half the step around the first vertex
    estimate, curvature, _ = _bracketed_vertex(profile, first, OXYGENATION_STEP / 2, low, high)
    # the parabola through the three lowest evaluations: the closest to the minimum of all
    # made, where the residual is most nearly quadratic (noise-free at 0.75, the refined
    # stencil's vertex alone was 0.7533, and a 0.003 error moved a face's dermal blood 12%)
    lowest = sorted(sorted(profile.values, key=profile.values.get)[:3])
    if np.isfinite(curvature) and profile.values[lowest[1]] == min(profile.values.values()):
        vertex, near_curvature = parabola_vertex(lowest, [profile.values[g] for g in lowest])
        if np.isfinite(vertex):
            estimate, curvature = float(np.clip(vertex, lowest[0], lowest[2])), near_curvature
    minima, weight = block_minima(profile)
    profile_gamma = estimate
    if np.isfinite(curvature):
        estimate = float(np.clip(np.sum(weight * minima) / np.sum(weight), low, high))
        spread = jackknife_std(minima, weight)
    else:
        spread = float("nan")
    if not np.isfinite(spread):  # no minimum inside the box, or too few blocks to tell
        spread = float(prior_std)
    weighting_std = abs(estimate - profile_gamma)

    maps, ok, block_weight, _ = profile.nearest_blocks(estimate)
    means = {n: float(np.sum(block_weight * maps[n][ok]) / np.sum(block_weight)) for n in PARAMETERS}
    face_eta = float(np.median(eta[valid]))
    shift = thickness_shift_per_mm(means, face_eta, thickness_mm, estimate, bands)
    thickness_std = abs(shift) * float(config.nuisance_mean["thickness_mm"][1])
    variance = spread ** 2 + thickness_std ** 2 + weighting_std ** 2
    precision = 1.0 / variance + 1.0 / prior_std ** 2
    gamma = (estimate / variance + prior_mean / prior_std ** 2) / precision
    return OxygenationEstimate(float(np.clip(gamma, low, high)), float(np.sqrt(1.0 / precision)),
                               float(profile_gamma), spread, thickness_std, shift, sorted(profile.values.items()),
                               block_gamma=float(estimate), weighting_std=float(weighting_std))


__all__ = ["OxygenationEstimate", "block_minima", "face_oxygenation", "jackknife_std", "parabola_vertex",
           "thickness_shift_per_mm"]
