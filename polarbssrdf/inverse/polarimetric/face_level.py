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

The face's value is not the mean of the scattered map: a map the views
barely see stays near the optimizer's start (on a 12-view sphere
``alpha_s`` ended at 0.35-0.37 from a start of 0.35 for a truth of 0.40).
It is a Gauss-Newton step on the constant (:func:`face_level_step`): the
data's information about one value shared by every confident texel is the
sum of each texel's, ``sum_i d_i``, large even where each ``d_i`` is small,
with each texel's other parameters marginalized (a Schur complement of its
information, :mod:`polarbssrdf.inverse.polarimetric.posterior`). Its std
becomes the fitted map's own spread, ``sqrt(var(x))``: an upper bound on the
truth's spread about the face's value, since the data could not measure
the spread itself.

On the demo face (bench/RESULTS.md) this holds ``rho_s``, ``rho_ss`` and
``alpha_ss`` and leaves ``eta`` and ``alpha_s``, whose fitted spread exceeds
the noise's.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.polarimetric.model import GLOSSY_PARAMETERS
from polarbssrdf.inverse.polarimetric.posterior import prior_precisions, texel_information

FALLBACK_MAPS = GLOSSY_PARAMETERS
"""Maps that may fall back to the face's level (``rho_sss`` and the displacement always vary)."""


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


def face_level_step(params, cache, patches, config, weights, noise, names, confident):
    """One Gauss-Newton step on the face's value of each map of ``names`` (held constant).

    Sums, over the ``confident`` texels (T, T) of every patch, each texel's
    information and gradient about the held values with its other
    parameters marginalized, and returns ``{map: new value}`` within the
    map's bounds.
    """
    held = [GLOSSY_PARAMETERS.index(name) for name in names]
    information = np.zeros((len(held), len(held)))
    gradient = np.zeros(len(held))
    flat_confident = np.asarray(confident, bool).ravel()
    for patch in patches:
        prepared = cache.get(patch)
        if len(prepared) == 0:
            continue
        texel_info, texel_gradient, _ = texel_information(params, prepared, config, weights,
                                                          noise)
        interior = prepared.stencils.interior.ravel() > 0
        use = interior & flat_confident[prepared.window_index]
        if not use.any():
            continue
        matrix = texel_info[use] + np.diag(prior_precisions(config, len(prepared.observed)))[None]
        vector = texel_gradient[use]
        others = [k for k in range(matrix.shape[1]) if k not in held]
        m_oo = matrix[:, others][:, :, others]
        m_ho = matrix[:, held][:, :, others]
        solved = np.linalg.solve(m_oo, np.concatenate(
            [np.swapaxes(m_ho, 1, 2), vector[:, others, None]], axis=2))
        information += np.sum(matrix[:, held][:, :, held]
                              - np.einsum("nhk,nkj->nhj", m_ho, solved[:, :, :len(held)]), axis=0)
        gradient += np.sum(vector[:, held] - np.einsum("nhk,nk->nh", m_ho, solved[:, :, -1]),
                           axis=0)
    step = -np.linalg.solve(information, gradient)
    current = params.to_numpy()
    values = {}
    for name, delta in zip(names, step):
        low, high = config.bounds[name]
        level = float(np.mean(current[name][np.asarray(confident, bool)]))
        values[name] = float(np.clip(level + delta, low, high))
    return values


def hold_at_face_level(params, cache, patches, config, weights, noise, held, confident, steps=1):
    """Set the ``held`` maps (:func:`unresolved_maps`) to the face's value: their mean, then
    ``steps`` Gauss-Newton steps (:func:`face_level_step`). Records each map's ``level``."""
    names = list(held)
    set_constant_maps(params, {name: held[name]["mean"] for name in names})
    for _ in range(steps):
        set_constant_maps(params, face_level_step(params, cache, patches, config, weights,
                                                  noise, names, confident))
    maps = params.to_numpy()
    for name in names:
        held[name]["level"] = float(maps[name].flat[0])
    return held


def held_std_channels(channels, held):
    """Set the std channel of each held map to its spread (in place); round the record."""
    for name, record in held.items():
        channels[f"{name}_std"] = np.full_like(channels[f"{name}_std"], record["spread"])
        for key, value in record.items():
            record[key] = round(float(value), 6)
    return held
