"""Maps the views cannot tell apart from a constant fall back to the face's level (issue 33 item 4).

A fitted map ``x`` whose texels carry posterior variances ``v``
(:mod:`polarbssrdf.inverse.polarimetric.posterior`) holds the truth's spread
``tau^2`` and the fit's error: over the confident texels, ``var(x) = tau^2 +
mean(v)`` when the posterior is right and the error is independent of the
truth (the method-of-moments estimate of a random-effects model, as in
DerSimonian and Laird 1986). Where ``var(x) <= mean(v)`` the estimate of
``tau^2`` is 0: the views did not resolve any variation of that map over the
face, and its per-texel values are the error's. For a regularized map the
error is partly the detail the regularizer flattens, not only noise; the
test then errs toward holding, which costs a map its detail but never
makes it worse than a constant. (Comparing ``var(x)`` with the noise that
passes the smoothing alone kept the demo's ``alpha_ss``, whose spread
follows the noisy ``rho_ss`` it trades against, at 2.2 times the constant
map's error.) Such a map is replaced by one value for the whole face (a
constant on every texel), recorded as held: the scatter of a map the views
cannot resolve only adds ``mean(v)`` to its squared error.

The face's value is the fitted map's mean over the confident texels. Until
2026-12-07 it was a Gauss-Newton step on the constant whose gradient was
wrong (:func:`polarbssrdf.inverse.polarimetric.posterior.texel_information`
read a Jacobian where the residuals belong); with that fixed, the step (each
texel's slopes marginalized) and a Levenberg-Marquardt refit of the constant
(:func:`fit_face_levels`, the displacement and the other maps held) both made
the level worse: on a wrinkled 512^2 face (the fit started at the face
levels) they moved ``rho_s`` from 0.799 to 0.770 and 0.764, ``rho_ss`` from
0.304 to 0.338 and 0.334, for truths of 0.790 and 0.299 (the best constant
of a nonlinear model is not the mean of a varying truth; bench/RESULTS.md).
Its std becomes the fitted map's own spread, ``sqrt(var(x))``: an upper
bound on the truth's spread about the face's value, since the data could
not measure the spread itself.

On the demo face (bench/RESULTS.md) this holds ``rho_s``, ``rho_ss`` and
``alpha_ss`` and leaves ``eta`` and ``alpha_s``, whose fitted spread exceeds
the noise's.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.polarimetric.model import GLOSSY_PARAMETERS
from polarbssrdf.inverse.polarimetric.optimize import texel_view_terms
from polarbssrdf.inverse.polarimetric.posterior import (
    TANGENTS,
    prior_precisions,
    texel_information,
)

FALLBACK_MAPS = GLOSSY_PARAMETERS
"""Maps that may fall back to the face's level (``rho_sss`` and the displacement always vary)."""

START_DAMPING = 1e-3
"""Levenberg-Marquardt's first damping, relative to the information's diagonal (Marquardt 1963)."""

START_TOLERANCE = 1e-5
""":func:`fit_face_levels` stops when an accepted step lowers the chi-square by less than this
fraction."""


def resolved_spread(values, std):
    """``(var(x), mean(v), mean(x))`` of a map ``x`` over texels with a finite posterior std
    (``v`` its square)."""
    values = np.asarray(values, np.float64)
    std = np.asarray(std, np.float64)
    usable = np.isfinite(values) & np.isfinite(std)
    if not usable.any():
        return float("nan"), float("nan"), float("nan")
    x = values[usable]
    return float(np.var(x)), float(np.mean(np.square(std[usable]))), float(np.mean(x))


def unresolved_maps(channels, confident, maps=FALLBACK_MAPS):
    """The maps of ``maps`` whose spread over the ``confident`` texels the views did not resolve.

    ``channels`` holds ``<map>`` and ``<map>_std`` (T, T) for each map.
    Returns ``{map: {"mean", "spread", "noise_std"}}``: the fitted map's mean
    and spread and the root mean posterior variance they were compared with.
    """
    confident = np.asarray(confident, bool)
    held = {}
    for name in maps:
        std_name = f"{name}_std"
        if name not in channels or std_name not in channels or not confident.any():
            continue
        variance, noise, mean = resolved_spread(channels[name][confident],
                                                channels[std_name][confident])
        if np.isfinite(variance) and variance <= noise:
            held[name] = {"mean": mean, "spread": float(np.sqrt(variance)),
                          "noise_std": float(np.sqrt(noise))}
    return held


def set_constant_maps(params, values):
    """Set each map of ``values`` (``{map: float}``, physical units) to that value on every texel."""
    maps = params.to_numpy()
    for name, value in values.items():
        maps[name] = np.full_like(maps[name], value)
    variables = params.variables_of(maps)
    for name in values:
        params.optimizer[name] = to_jit(params.TensorXf, variables[name], np.float32)


def face_level_system(params, cache, patches, config, weights, noise, names, texels):
    """The data's chi-square, gradient and Gauss-Newton information about one value per map of
    ``names`` shared by the ``texels`` (T, T bool) of every patch.

    Each texel's ``rho_sss`` per band is marginalized (a Schur complement of its information,
    :func:`polarbssrdf.inverse.polarimetric.posterior.texel_information`); its other glossy
    maps and its slopes keep their current values. Each ``rho_sss`` carries its uniform
    prior (:func:`~polarbssrdf.inverse.polarimetric.posterior.prior_precisions`), a shared
    value its prior once. Returns ``(chi_square, gradient, information)``: a float,
    (len(names),) and (len(names), len(names)), the gradient that of half the chi-square.
    """
    held = [TANGENTS.index(name) for name in names]
    information = np.zeros((len(held), len(held)))
    gradient = np.zeros(len(held))
    chi_square = 0.0
    flat_texels = np.asarray(texels, bool).ravel()
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared) == 0:
            continue
        texel_info, texel_gradient, _, texel_chi_square = texel_information(
            params, prepared, config, weights, noise)
        interior = prepared.stencils.interior.ravel() > 0
        use = interior & flat_texels[prepared.window_index]
        if not use.any():
            continue
        chi_square += float(np.sum(texel_chi_square[use]))
        albedos = list(range(len(TANGENTS), texel_info.shape[1]))
        # a band's residuals read only its own albedo, so the albedos' block of each texel is
        # diagonal and its Schur complement a division
        m_aa = (np.diagonal(texel_info[use][:, albedos][:, :, albedos], axis1=1, axis2=2)
                + prior_precisions(config, len(prepared.observed))[albedos])
        m_ha = texel_info[use][:, held][:, :, albedos]
        vector = texel_gradient[use]
        information += np.sum(texel_info[use][:, held][:, :, held]
                              - np.einsum("nhk,njk->nhj", m_ha, m_ha / m_aa[:, None]), axis=0)
        gradient += np.sum(vector[:, held]
                           - np.einsum("nhk,nk->nh", m_ha, vector[:, albedos] / m_aa), axis=0)
    information += np.diag(prior_precisions(config, 0)[held])
    return chi_square, gradient, information


def solve_albedos(params, cache, patches, config):
    """Re-solve ``rho_sss`` on every patch in closed form for the current glossy maps (eq. 27)."""
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared):
            texel_view_terms(params, prepared, config, solve_albedo=True)


def fit_face_levels(params, cache, patches, config, weights, names, texels, evaluations,
                    progress=False, description="face levels"):
    """Levenberg-Marquardt on one value per map of ``names`` shared by the ``texels`` (T, T bool),
    ``rho_sss`` solved per texel and every other map held: the fit's coarsest level.

    From a constant start the per-texel RMSProp steps of the fit cross the
    valleys between ``eta``, the lobes' albedos and their roughnesses slowly
    and can settle in the wrong one: on a wrinkled 512^2 face (each texel 150
    steps) ``rho_ss`` ended at 0.37 for a truth of 0.30 and ``eta`` at 1.477 for
    1.422, 2-5 times the constant map's error; from this start they end at
    1.00-1.01 times it. (On the demo's 256^2 captures this start made
    ``rho_ss`` worse, 1.06 -> 1.56 and 1.07 -> 3.42 times: the fit runs it only
    when ``config.face_level_evaluations`` > 0.) Five numbers shared by the face
    are a small least-squares problem in which the Gauss-Newton model sees
    those valleys: each evaluation re-solves ``rho_sss`` (a variable
    projection, Golub and Pereyra 1973) and sums every texel's information
    about the shared values (:func:`face_level_system`; at the start the
    slopes are 0).
    Steps solve ``(H + lambda diag H) d = -g`` (Marquardt 1963), clipped to the
    bounds; a step that raises the chi-square is retried with ``lambda`` x10,
    an accepted one divides it by 3.

    ``evaluations`` bounds the passes over the patches (one per tried step);
    the iteration also stops when an accepted step gains less than
    :data:`START_TOLERANCE`. Leaves the maps at the best values, with their
    ``rho_sss``, and returns ``{"values", "chi_square", "evaluations"}``
    (``chi_square`` the accepted values' history, in units of
    ``config.photometric_noise``).
    """
    texels = np.asarray(texels, bool)
    current = params.to_numpy()
    values = {name: float(np.mean(current[name][texels])) for name in names}
    noise = config.photometric_noise

    def evaluate(candidate):
        set_constant_maps(params, candidate)
        solve_albedos(params, cache, patches, config)
        return face_level_system(params, cache, patches, config, weights, noise, names, texels)

    chi_square, gradient, information = evaluate(values)
    best_albedo = params.rho_sss.copy()
    history, used, damping = [chi_square], 1, START_DAMPING
    with tqdm(total=evaluations, initial=1, desc=description, unit="pass",
              disable=not progress) as bar:
        while used < evaluations:
            # the ridge keeps a value no texel sees (a zero row) from making the system singular
            ridge = 1e-12 * max(float(np.trace(information)), 1e-300)
            damped = (information + damping * np.diag(np.diag(information))
                      + ridge * np.eye(len(names)))
            step = -np.linalg.solve(damped, gradient)
            candidate = {name: float(np.clip(values[name] + delta, *config.bounds[name]))
                         for name, delta in zip(names, step)}
            trial = evaluate(candidate)
            used += 1
            bar.update()
            if trial[0] < chi_square:
                gain = (chi_square - trial[0]) / max(chi_square, 1e-300)
                values, (chi_square, gradient, information) = candidate, trial
                best_albedo = params.rho_sss.copy()
                history.append(chi_square)
                damping /= 3.0
                if gain < START_TOLERANCE:
                    break
            else:
                damping *= 10.0
    set_constant_maps(params, values)
    params.rho_sss[...] = best_albedo
    return {"values": {name: round(value, 6) for name, value in values.items()},
            "chi_square": [round(value, 3) for value in history], "evaluations": used}


def hold_at_face_level(params, held):
    """Set the ``held`` maps (:func:`unresolved_maps`) to their fitted mean on every texel;
    records it as each map's ``level``."""
    set_constant_maps(params, {name: held[name]["mean"] for name in held})
    for name in held:
        held[name]["level"] = held[name]["mean"]
    return held


def held_std_channels(channels, held):
    """Set the std channel of each held map to its spread (in place); round the record."""
    for name, record in held.items():
        channels[f"{name}_std"] = np.full_like(channels[f"{name}_std"], record["spread"])
        for key, value in record.items():
            record[key] = round(float(value), 6)
    return held
