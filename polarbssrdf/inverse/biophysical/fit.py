"""The biophysical stage: melanin and hemoglobin maps from subsurface albedo maps (supplement sec. 5.3).

``fit_biophysical(albedo_maps, bands, atlas)`` recovers ``C_m, beta_m,
C_h_out, C_h_in`` per texel by the paper's coordinate descent (eq. 40-47):

a. a start per texel from the fast per-texel inversion
   (:func:`polarbssrdf.skin.invert_bands`, eq. 47) on block-averaged maps
   (blocks of about ``start_texel_mm``, where the blur is negligible),
   upsampled bilinearly;
b. the sum-of-Gaussians kernels of the five layer profiles (eq. 40, 43) fitted
   at the parameters of the median-intensity texel
   (:func:`polarbssrdf.render.subsurface.layer_profile_kernels`, the kernels
   synth renders with), homogeneous over the face (eq. 45);
c. at full resolution, damped Gauss-Newton steps (or Adam, ``drjit.opt``; the
   config's ``method``) on the four maps so that the eq. 46 rendering (:class:`~polarbssrdf.inverse.biophysical.model.BiophysicalModel`:
   the texture-space layered blur of synth, differentiable) matches the input
   (eq. 41), with an optional smoothness prior; clamped to the bounds after
   every step;
d. (b) and (c) repeated until the kernels change by less than
   ``kernel_tolerance``.

Input albedos are lobe albedos (``rho_sss`` of eq. 19, what the static stage
recovers and synth's truth maps hold); the skin model's flux ``R_bar`` is
``c(eta) rho_sss`` (docs/biophysical.md). Texels whose input is not finite,
outside [0, 1] or of confidence 0 in any band do not enter the data term,
take values filled in from their valid neighbours and are flagged.
"""

from __future__ import annotations

import dataclasses
import time

import drjit as dr
import drjit.opt
import numpy as np
from scipy import sparse
from scipy.ndimage import zoom
from scipy.sparse.linalg import LinearOperator, cg

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.biophysical.config import BiophysicalConfig
from polarbssrdf.inverse.biophysical.model import PARAMETERS, BiophysicalModel, jit_types
from polarbssrdf.inverse.results.fill import fill_from_neighbours as fill
from polarbssrdf.render.subsurface import layer_profile_kernels, subsurface_exit_fraction
from polarbssrdf.skin.inversion import invert_bands
from polarbssrdf.skin.parameters import SkinParameters

START_ETA_STEP = 0.02
"""Texels of the start's inversion share one eta per bin of this width."""


@dataclasses.dataclass
class BiophysicalResult:
    """Maps (T, T float32) of the fit and what it did.

    ``residual`` is the RMS over bands of rendered minus input albedo (0 at
    flagged texels), ``flagged`` marks surface texels whose input was invalid
    (their parameters are filled from neighbours). ``history`` has one entry per
    round: loss before/after, kernel change, seconds."""

    maps: dict
    residual: np.ndarray
    flagged: np.ndarray
    kernels: list
    history: list
    predicted: np.ndarray
    start: dict
    seconds: float

    def channels(self):
        """Channels of the stage's map file: ``C_m, beta_m, C_h_out, C_h_in, residual, flagged``."""
        out = {name: np.ascontiguousarray(self.maps[name], dtype=np.float32) for name in PARAMETERS}
        out["residual"] = np.ascontiguousarray(self.residual, dtype=np.float32)
        out["flagged"] = self.flagged.astype(np.float32)
        return out


def albedo_stack(albedo_maps, bands, shape):
    """(n_bands, T, T) float64 of ``rho_sss.<band>`` (or ``<band>``) channels; clear errors."""
    if len(bands) < 4:
        raise ValueError(f"need at least 4 bands to fit 4 parameters, got {len(bands)}")
    stack = []
    for band in bands:
        key = next((k for k in (f"rho_sss.{band.name}", band.name) if k in albedo_maps), None)
        if key is None:
            raise ValueError(f"missing subsurface albedo map 'rho_sss.{band.name}' (have: "
                             f"{', '.join(sorted(albedo_maps)) or 'none'})")
        value = np.asarray(albedo_maps[key], dtype=np.float64)
        if value.shape != tuple(shape):
            raise ValueError(f"map {key!r} is {value.shape}, the atlas is {tuple(shape)}")
        stack.append(value)
    return np.stack(stack)


def fill_from_neighbours(values, known, domain):
    """``values`` with texels of ``domain`` not ``known`` replaced by a normalized Gaussian
    average of known neighbours (radius doubling until every one is filled); off
    ``domain`` too, so the map is finite everywhere."""

    known = known & np.isfinite(np.asarray(values, dtype=np.float64))
    if not known.any():
        raise ValueError("no texel with valid input to fill from")
    return fill(values, known)


def _block_mean(values, weight, factor):
    """Weighted means over factor x factor blocks (edge padded)."""
    T = values.shape[-1]
    n = -(-T // factor)
    pad = n * factor - T
    v = np.pad(values * weight, [(0, 0)] * (values.ndim - 2) + [(0, pad), (0, pad)])
    w = np.pad(weight.astype(np.float64), [(0, pad), (0, pad)])
    shape = v.shape[:-2] + (n, factor, n, factor)
    ws = w.reshape(n, factor, n, factor).sum(axis=(1, 3))
    vs = v.reshape(shape).sum(axis=(-3, -1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return vs / ws, ws > 0


def start_maps(rbar, valid, atlas, bands, eta, config):
    """Step (a): the per-texel inversion of eq. 47 on block means, upsampled; (T, T) maps."""

    T = valid.shape[0]
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    factor = max(1, int(round(config.start_texel_mm / max(texel, 1e-9)))) if config.start_texel_mm > 0 else 1
    factor = min(factor, T)
    means, ok = _block_mean(rbar, valid, factor)
    eta_means, _ = _block_mean(eta, valid, factor)
    # invert_bands takes one eta: invert texels in bins of START_ETA_STEP
    bins = np.round(eta_means / START_ETA_STEP) * START_ETA_STEP
    coarse_maps = {name: np.full(ok.shape, np.nan) for name in PARAMETERS}
    for value in np.unique(bins[ok]):
        members = ok & (bins == value)
        result = invert_bands(np.moveaxis(means[:, members], 0, -1), bands, thickness_mm=config.thickness_mm,
                              eta=float(value), table_size="default")
        for name in PARAMETERS:
            coarse_maps[name][members] = getattr(result, name)
    out = {}
    for name in PARAMETERS:
        coarse = coarse_maps[name]
        coarse = fill_from_neighbours(coarse, ok, np.ones_like(ok))
        if factor > 1:
            # block centres -> texel centres
            fine = zoom(coarse, factor, order=1, mode="nearest", grid_mode=True)[:T, :T]
        else:
            fine = coarse
        low, high = config.bounds[name]
        out[name] = np.clip(fine, low, high)
    return out, factor


def median_intensity_texel(observed, valid):
    """Flat index of the valid texel of median mean-over-bands albedo."""
    intensity = observed.mean(axis=0).ravel()
    index = np.flatnonzero(valid.ravel())
    order = np.argsort(intensity[index])
    return int(index[order[len(order) // 2]])


def fit_kernels(maps, texel, bands, eta, config):
    """Step (b): the layer kernels at the parameters of one texel (eq. 40, 43, 45)."""

    values = {name: float(np.ravel(maps[name])[texel]) for name in PARAMETERS}
    skin = SkinParameters(**values, thickness_mm=config.thickness_mm, eta=float(np.ravel(eta)[texel]))
    return layer_profile_kernels(bands, skin)


def kernel_change(old, new):
    """Largest absolute change of a normalized SoG weight over bands and profiles."""
    return max(float(np.max(np.abs(np.asarray(o[name][0]) - np.asarray(n[name][0]))))
               for o, n in zip(old, new) for name in o)


class FitLoss:
    """The loss of step (c) (eq. 41 + smoothness prior) over Dr.Jit parameter arrays."""

    def __init__(self, model, observed, weight, config):
        Float, UInt32, _ = jit_types()
        self.model = model
        self.config = config
        T = model.shape[0]
        count = max(int(weight.sum()), 1) * len(model.bands)
        scale = 1.0 / (config.albedo_noise * np.maximum(observed, 1e-3))
        self.observed = [to_jit(Float, observed[b].ravel(), np.float32) for b in range(len(model.bands))]
        self.scale = [to_jit(Float, (scale[b] * weight).ravel(), np.float32) for b in range(len(model.bands))]
        self.norm = 1.0 / count
        surface = model.atlas.valid
        index = np.arange(T * T).reshape(T, T)
        pairs = []
        for a, b in ((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])):
            both = surface.ravel()[a.ravel()] & surface.ravel()[b.ravel()]
            pairs.append((a.ravel()[both], b.ravel()[both]))
        first = np.concatenate([p[0] for p in pairs])
        second = np.concatenate([p[1] for p in pairs])
        # centre distance of each pair, mm: along u for row neighbours, along v for column ones
        sizes = model.atlas.texel_size_mm.reshape(T * T, 2)
        along = np.concatenate([np.zeros(len(pairs[0][0]), int), np.ones(len(pairs[1][0]), int)])
        distance = 0.5 * (sizes[first, along] + sizes[second, along])
        inverse_distance = 1.0 / np.maximum(distance, 1e-6)
        self.pairs = (to_jit(UInt32, first, np.uint32), to_jit(UInt32, second, np.uint32))
        self.pair_arrays = (first, second, inverse_distance)
        self.inverse_distance = to_jit(Float, inverse_distance, np.float32)
        self.pair_norm = 1.0 / max(len(first), 1)
        self.smoothness = config.smoothness_weights()
        # scalars that vary with the data and the config enter the kernels as inputs, not
        # literals, so that other faces and configs reuse the compiled kernels
        self._norm_jit = dr.opaque(Float, self.norm)
        self._pair_norm_jit = dr.opaque(Float, self.pair_norm)
        self._smoothness_jit = {name: (dr.opaque(Float, weight),
                                       dr.opaque(Float, config.bounds[name][1] - config.bounds[name][0]))
                                for name, weight in self.smoothness.items() if weight > 0}
        # what the Gauss-Newton curvature needs: per band and texel the weight of the
        # squared residual
        self.data_weight = np.stack([(scale[b] * weight).ravel() ** 2 * self.norm
                                     for b in range(len(model.bands))])

    def data_terms(self, params):
        """Per band, the rendered albedo (flat Float)."""
        return [self.model.render(params, b) for b in range(len(self.model.bands))]

    def __call__(self, params, predicted=None):

        Float, _, _ = jit_types()
        predicted = predicted or self.data_terms(params)
        loss = Float(0.0)
        for b, value in enumerate(predicted):
            r = (value - self.observed[b]) * self.scale[b]
            loss += dr.sum(r * r) * self._norm_jit
        for name in PARAMETERS:
            if name in self._smoothness_jit:
                weight, span = self._smoothness_jit[name]
                x = params[name]
                # the map's gradient in bounds ranges per mm, whatever the texel size
                slope = ((dr.gather(Float, x, self.pairs[0]) - dr.gather(Float, x, self.pairs[1]))
                         * self.inverse_distance / span)
                loss += weight * dr.sum(slope * slope) * self._pair_norm_jit
        return loss


def local_jacobian(model, maps, names):
    """``(n_texels, n_bands, len(names))`` d(unblurred lobe albedo)/d(map), by Dr.Jit forward mode."""

    Float, _, _ = jit_types()
    columns = []
    for name in names:
        params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS}
        dr.enable_grad(params[name])
        values = [model.local_albedo(params, b) for b in range(len(model.bands))]
        dr.forward(params[name])
        columns.append(np.stack([np.array(dr.grad(v), dtype=np.float64) for v in values], axis=-1))
    return np.stack(columns, axis=-1)


def _evaluate(loss_fn, maps, names, fixed):
    """The loss at NumPy maps with the free maps' gradients enabled: ``(loss, params, value)``.

    :func:`_gradient` then runs the reverse pass only if the point is kept.
    """

    Float, _, _ = jit_types()
    params = dict(fixed)
    for n in names:
        params[n] = to_jit(Float, np.ravel(maps[n]), np.float32)
        dr.enable_grad(params[n])
    value = loss_fn(params)
    return float(value[0]), params, value


def _gradient(evaluated, names):
    """(n_texels, len(names)) gradient of an :func:`_evaluate` d loss, through the blur."""

    _, params, value = evaluated
    dr.backward(value)
    return np.stack([np.array(dr.grad(params[n]), dtype=np.float64) for n in names], axis=-1)


def _prior_laplacian(loss_fn, movable):
    """The prior's pair graph over the movable texels: sparse ``sum w (e_a - e_b)(e_a - e_b)^T``
    with ``w`` the pair's squared inverse distance (a pair with a held texel adds its
    diagonal only)."""

    first, second, inverse_distance = loss_fn.pair_arrays
    index = np.full(movable.size, -1)
    index[movable] = np.arange(int(movable.sum()))
    a, b, w = index[first], index[second], inverse_distance ** 2
    n = int(movable.sum())
    both = (a >= 0) & (b >= 0)
    diagonal = (np.bincount(a[a >= 0], weights=w[a >= 0], minlength=n)
                + np.bincount(b[b >= 0], weights=w[b >= 0], minlength=n))
    off = sparse.coo_matrix((-w[both], (a[both], b[both])), shape=(n, n))
    return (off + off.T + sparse.diags(diagonal)).tocsr()


def _solve_step(blocks, laplacian, prior, rhs, max_iterations=40, rtol=1e-2):
    """``delta`` of ``(blocks + prior_k L) delta = rhs`` by block-Jacobi preconditioned CG.

    ``blocks``: (n, k, k) per-texel curvature; ``laplacian``: (n, n) sparse;
    ``prior``: (k,) weight of the Laplacian per map; ``rhs``: (n, k).
    """

    n, k = rhs.shape
    diagonal = laplacian.diagonal()
    jacobi = blocks + (prior[None, :] * diagonal[:, None])[:, :, None] * np.eye(k)
    inverse = np.linalg.inv(jacobi)

    def apply(x):
        x = x.reshape(n, k)
        return (np.einsum("nij,nj->ni", blocks, x) + (laplacian @ x) * prior[None, :]).ravel()

    def precondition(x):
        return np.einsum("nij,nj->ni", inverse, x.reshape(n, k)).ravel()

    if not np.any(prior > 0):
        return np.einsum("nij,nj->ni", inverse, rhs)
    operator = LinearOperator((n * k, n * k), matvec=apply, dtype=np.float64)
    solution, _ = cg(operator, rhs.ravel(), x0=precondition(rhs.ravel()), rtol=rtol,
                     maxiter=max_iterations,
                     M=LinearOperator((n * k, n * k), matvec=precondition, dtype=np.float64))
    return solution.reshape(n, k)


def _gauss_newton(loss_fn, maps, held, config, frozen):
    """Step (c) by damped Gauss-Newton on the free maps; returns maps, first/last loss, losses.

    The step solves ``(C + mu diag(C) + P) delta = -g`` with ``g`` the exact
    gradient, ``C`` per texel ``2 sum_b w_b J_b J_b^T`` (``J_b`` the Jacobian of
    the unblurred model, :func:`local_jacobian`; ``w_b`` the data term's
    weights) and ``P`` the smoothness prior's exact Hessian, a graph Laplacian
    that couples neighbours (:func:`_solve_step`, conjugate gradients). The
    blur only averages neighbouring texels' sensitivities (a normalized blur has
    gain <= 1), so ``C`` bounds the data term's curvature from above and
    undamped steps do not overshoot it; ``mu`` grows when a step does not lower
    the loss.
    """
    Float, _, _ = jit_types()
    names = [n for n in PARAMETERS if n not in held]
    fixed = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS if n in held}
    flat = {n: np.asarray(maps[n], np.float64).ravel().copy() for n in PARAMETERS}
    movable = frozen.ravel().astype(bool)
    ranges = np.array([config.bounds[n][1] - config.bounds[n][0] for n in names])
    weights = np.array([loss_fn.smoothness[n] for n in names])
    laplacian = _prior_laplacian(loss_fn, movable)
    prior = 2.0 * weights * loss_fn.pair_norm / ranges ** 2  # per map, times the Laplacian
    evaluated = _evaluate(loss_fn, flat, names, fixed)
    loss, gradient = evaluated[0], _gradient(evaluated, names)
    first = loss
    losses = [loss]
    mu = 1e-3
    identity = np.eye(len(names))
    for _ in range(int(config.iterations)):
        J = local_jacobian(loss_fn.model, flat, names)  # (N, bands, k)
        curvature = 2.0 * np.einsum("nbi,bn,nbj->nij", J[movable], loss_fn.data_weight[:, movable],
                                    J[movable])
        diagonal = np.einsum("nii->ni", curvature)
        accepted = False
        while mu < 1e8:
            blocks = curvature + mu * (diagonal[:, :, None] * identity + 1e-12 * identity)
            step = _solve_step(blocks, laplacian, prior, -gradient[movable])
            trial = {n: v.copy() for n, v in flat.items()}
            for k, n in enumerate(names):
                low, high = config.bounds[n]
                trial[n][movable] = np.clip(flat[n][movable] + step[:, k], low, high)
            evaluated = _evaluate(loss_fn, trial, names, fixed)
            trial_loss = evaluated[0]
            if np.isfinite(trial_loss) and trial_loss < loss:
                accepted = True
                break
            mu *= 4.0
        if not accepted:
            break
        mu = max(mu / 3.0, 1e-6)
        decrease = (loss - trial_loss) / max(loss, 1e-30)
        flat = trial
        loss = trial_loss
        losses.append(loss)
        if decrease < config.tolerance:
            break
        gradient = _gradient(evaluated, names)
    out = dict(maps)
    for n in names:
        out[n] = flat[n].reshape(maps[n].shape)
    return out, first, loss, losses


def _optimize(loss_fn, maps, held, config, frozen):
    """Step (c) with the configured method; returns maps and the first and last loss."""
    if config.method == "gauss_newton":
        return _gauss_newton(loss_fn, maps, held, config, frozen)
    return _adam(loss_fn, maps, held, config, frozen)


def _adam(loss_fn, maps, held, config, frozen):
    """Step (c): Adam on the four maps (flat), clamped after every step; returns maps and losses."""

    Float, _, _ = jit_types()
    names = [n for n in PARAMETERS if n not in held]
    fixed = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS if n in held}
    opt = dr.opt.Adam(lr=1e-3)
    freeze = to_jit(Float, frozen.ravel(), np.float32)  # 1 where a texel may move
    for n in names:
        opt[n] = to_jit(Float, np.ravel(maps[n]), np.float32)
    steps = int(config.iterations)
    decay = config.final_lr_fraction ** (1.0 / max(steps - 1, 1))
    first = None
    last = None
    for step in range(steps):
        for n in names:
            opt.set_learning_rate({n: config.learning_rates[n] * decay**step})
        params = {**fixed, **{n: opt[n] for n in names}}
        loss = loss_fn(params)
        dr.backward(loss)
        for n in names:
            grad = dr.grad(opt[n])
            dr.set_grad(opt[n], grad * freeze)
        value = float(loss[0])
        first = value if first is None else first
        last = value
        opt.step()
        for n in names:
            low, high = config.bounds[n]
            opt[n] = dr.clip(opt[n], low, high)
    out = dict(maps)
    for n in names:
        out[n] = np.array(opt[n], dtype=np.float64).reshape(maps[n].shape)
    return out, first, last, []


def fit_biophysical(albedo_maps, bands, atlas, config=None, start=None, held=None, progress=None):
    """Biophysical maps from subsurface albedo maps (see the module docstring).

    Parameters
    ----------
    albedo_maps : dict
        ``rho_sss.<band>`` (T, T) lobe albedo maps for every band (result or
        truth channel names); optional ``eta`` (T, T) refractive index map
        (else ``config.eta``) and ``confidence`` (texels with 0 are flagged).
    bands : list of Band
    atlas : TexelAtlas
        The mesh's texel atlas at the maps' resolution (texel sizes in mm).
    config : BiophysicalConfig, optional
    start : dict, optional
        Start maps of the four parameters (replaces step a), e.g. the static
        biophysical maps for a dynamic frame.
    held : dict, optional
        Maps held fixed (not optimized), e.g. ``C_m`` and ``beta_m`` of the
        static frame.
    progress : callable, optional
        Called with a message per round.

    Returns
    -------
    BiophysicalResult
    """
    t0 = time.perf_counter()
    config = config or BiophysicalConfig()
    held = dict(held or {})
    shape = atlas.valid.shape
    for name in held:
        if name not in PARAMETERS:
            raise ValueError(f"held: unknown map {name!r}; known: {list(PARAMETERS)}")
    observed = albedo_stack(albedo_maps, bands, shape)
    if "eta" in albedo_maps:
        eta = np.asarray(albedo_maps["eta"], dtype=np.float64)
        if eta.shape != tuple(shape):
            raise ValueError(f"map 'eta' is {eta.shape}, the atlas is {tuple(shape)}")
        eta_ok = np.isfinite(eta) & (eta > 1.0) & (eta < 3.0)
    else:
        eta = np.full(shape, float(config.eta))
        eta_ok = np.ones(shape, bool)
    confidence = np.asarray(albedo_maps.get("confidence", np.ones(shape)), dtype=np.float64)
    if confidence.shape != tuple(shape):
        raise ValueError(f"map 'confidence' is {confidence.shape}, the atlas is {tuple(shape)}")
    surface = np.asarray(atlas.valid, bool)
    good = (surface & eta_ok & np.all(np.isfinite(observed), axis=0) & np.all((observed >= 0) & (observed <= 1), axis=0)
            & (np.nan_to_num(confidence) > 0))
    if not good.any():
        raise ValueError("no texel has valid subsurface albedo in every band (finite, in [0, 1], confidence > 0)")
    flagged = surface & ~good
    eta = fill_from_neighbours(np.where(eta_ok, eta, np.nan), eta_ok & surface, surface)
    observed = np.stack([fill_from_neighbours(o, good, surface) for o in observed])
    observed = np.clip(observed, 1e-4, 1.0)

    rbar = observed * subsurface_exit_fraction(eta)[None]

    for name, value in list(held.items()) + list((start or {}).items()):
        if np.asarray(value).shape != tuple(shape):
            raise ValueError(f"map {name!r} is {np.asarray(value).shape}, the atlas is {tuple(shape)}")
    if start is None:
        maps, _ = start_maps(rbar, good, atlas, bands, eta, config)
    else:
        missing = [n for n in PARAMETERS if n not in start and n not in held]
        if missing:
            raise ValueError(f"start lacks {missing}")
        maps = {n: np.asarray(start[n], np.float64) for n in PARAMETERS if n in start}
    for name, value in held.items():
        maps[name] = np.asarray(value, np.float64)
    for name in PARAMETERS:
        low, high = config.bounds[name]
        maps[name] = np.clip(fill_from_neighbours(maps[name], good & np.isfinite(maps[name]), surface), low, high)
    start_copy = {n: maps[n].astype(np.float32) for n in PARAMETERS}

    model = BiophysicalModel(bands, atlas, eta, config.thickness_mm, config.bounds)
    loss_fn = FitLoss(model, observed, good, config)
    texel = median_intensity_texel(observed, good)
    kernels = fit_kernels(maps, texel, bands, eta, config)
    history = []
    for round_index in range(config.rounds):
        t_round = time.perf_counter()
        model.kernels = kernels
        maps, before, after, losses = _optimize(loss_fn, maps, held, config, surface)
        for name in PARAMETERS:
            if name not in held and flagged.any():
                maps[name] = fill_from_neighbours(maps[name], good, surface)
        new_kernels = fit_kernels(maps, texel, bands, eta, config)
        change = kernel_change(kernels, new_kernels)
        history.append({"round": round_index, "loss_start": before, "loss_end": after,
                        "losses": [float(v) for v in losses],
                        "kernel_change": change, "seconds": time.perf_counter() - t_round})
        if progress:
            progress(f"bio round {round_index}: loss {before} -> {after}, kernel change {change:.4f}")
        kernels = new_kernels
        if change < config.kernel_tolerance:
            break
    model.kernels = kernels
    predicted = model.render_numpy(maps)
    residual = np.sqrt(np.mean((predicted - observed) ** 2, axis=0))
    residual = np.where(good, residual, 0.0)
    out = {n: maps[n].astype(np.float32) for n in PARAMETERS}
    return BiophysicalResult(out, residual.astype(np.float32), flagged, kernels, history,
                             predicted, start_copy, time.perf_counter() - t0)
