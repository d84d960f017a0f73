"""One optimizer step of the polarimetric stages on one patch (supplement eq. 26-35).

The maps being optimized are full-texture Dr.Jit tensors owned by a
``drjit.opt.RMSProp`` optimizer with ``mask_updates=True``: a patch step
gives gradients only to the patch's window, and texels elsewhere keep their
values *and* their RMSProp state, as if the patch were optimized alone.
With ``glossy_amplitudes`` the glossy albedos are optimized as lobe
amplitudes at normal incidence: the gradient steps move ``q = rho F0(eta) /
F0(eta_ref)`` (``F0`` the normal-incidence Fresnel reflectance, ``eta_ref``
the start value of ``eta``), and ``rho = q F0(eta_ref) / F0(eta)`` enters
the model. A glossy lobe's brightness is ``rho F(eta)``, so with ``rho``
itself as the variable (the default) ``eta`` and ``rho`` share a long
shallow valley along which a diagonal optimizer creeps: on a noise-free face
the final ``eta`` moved by -0.016 when only the start of ``rho_s`` changed
(0.5 -> 0.8). In ``q`` the valley is along an axis, but on a raw face the
noise then reaches ``eta`` (bench/RESULTS.md), hence off by default.
``rho_sss`` per band is linear given the rest: before each gradient step it
is solved per texel and band by least squares on ``L_sss``
(:func:`solve_subsurface_albedo`), then held.

Gradients (:func:`patch_gradients`): Dr.Jit's reverse pass differentiates
the data terms down to per texel-view leaves (:func:`patch_leaves`), whose
gradients each texel sums in a fixed order, so a step's gradient is the same
on any number of threads; the regularizers (eq. 33-35,
:mod:`polarbssrdf.inverse.polarimetric.regularizers`) and the dynamic stage's temporal
terms bring their own exact gradients, which are added to it. The global
gradient norm is clipped, and every map is clamped to its bounds after the
step.

Specular vs single scattering: both lobes are GGX lobes with the same
Fresnel term and differ only in roughness, so along the few view angles of a
texel they trade albedo against roughness. By default both learn from every
texel-view and stay apart through their disjoint roughness bounds; with
``separate_lobes`` (the authors' scheme) texel-views whose half vector is
close to the normal (``cos theta_h > specular_half_cosine``, 0.86) train the
specular lobe with the single-scattering lobe held, and the others the
single-scattering lobe with the specular lobe held. ``eta`` and the normals
learn from all of them either way.
"""

from __future__ import annotations

import dataclasses

import drjit as dr
import numpy as np

from polarbssrdf._arrays import masked_low_pass, to_jit
from polarbssrdf.geometry.height import (
    height_gradient,
    height_gradient_adjoint,
    normals_from_slopes,
)
from polarbssrdf.inverse.polarimetric.config import OPTIMIZED
from polarbssrdf.inverse.polarimetric.losses import DATA_TERMS, data_loss_terms
from polarbssrdf.inverse.polarimetric.model import half_vector_cosine, jit_types, predict_stokes
from polarbssrdf.inverse.polarimetric.preconditioning import sobolev_gradient
from polarbssrdf.inverse.polarimetric.regularizers import (
    displacement_laplacian,
    displacement_magnitude,
    neighbourhood_smoothness,
)
from polarbssrdf.optics.fresnel import normal_incidence_reflectance

GLOSSY_ALBEDOS = ("rho_s", "rho_ss")

TEMPORAL_TERMS = ("rho_s_temporal", "rho_ss_temporal", "rho_sss_temporal")
"""The dynamic stage's pulls toward the static maps (eq. 38-39)."""

REGULARIZER_TERMS = ("H_magnitude", "H_laplacian", "alpha_s_smoothness", "alpha_ss_smoothness",
                     "eta_smoothness")


class MapParameters:
    """The full-texture maps, their optimizer and the closed-form ``rho_sss`` maps.

    Parameters
    ----------
    maps : dict
        ``name -> (T, T)`` float32 start values for every name in
        :data:`polarbssrdf.inverse.polarimetric.config.OPTIMIZED`.
    rho_sss : (n_bands, T, T) array
        Start values of the subsurface albedo per band.
    learning_rates : dict
        Per map.
    optimized : sequence of str
        The maps that receive gradient steps (the others are held).
    optimizer : {"rmsprop", "adam"}
        ``drjit.opt.RMSProp`` or ``drjit.opt.Adam``, both with ``mask_updates``.
    reference_eta : float or None
        ``eta_ref`` of the amplitude variables (module docstring); None
        optimizes ``rho_s`` and ``rho_ss`` themselves.
    """

    def __init__(self, maps, rho_sss, learning_rates, optimized=OPTIMIZED, optimizer="rmsprop",
                 reference_eta=None):
        _, _, _, TensorXf = jit_types()
        self.TensorXf = TensorXf
        self.reference_eta = None if reference_eta is None else float(reference_eta)
        maps = self.variables_of(maps)
        self.resolution = int(np.asarray(maps["eta"]).shape[0])
        self.optimized = tuple(optimized)
        self.fixed = {name: to_jit(TensorXf, maps[name], np.float32)
                      for name in OPTIMIZED if name not in self.optimized}
        self.kind = optimizer
        if optimizer == "adam":
            self.optimizer = dr.opt.Adam(lr=1e-3, mask_updates=True)
        elif optimizer == "rmsprop":
            self.optimizer = dr.opt.RMSProp(lr=1e-3, mask_updates=True)
        else:
            raise ValueError(f"unknown optimizer {optimizer!r}; use 'rmsprop' or 'adam'")
        self.learning_rates = {name: float(learning_rates[name]) for name in self.optimized}
        for name in self.optimized:
            self.optimizer[name] = to_jit(TensorXf, maps[name], np.float32)
        self.scale_learning_rates(1.0)
        self.rho_sss = np.array(rho_sss, dtype=np.float32)
        self.reference = None
        """The dynamic stage's static maps (:meth:`set_reference`), or None."""

    def set_reference(self, maps, rho_sss, weights):
        """Pull ``rho_s``, ``rho_ss`` and ``rho_sss`` toward ``maps`` (supplement eq. 38-39).

        ``maps``: ``rho_s``, ``rho_ss`` (T, T); ``rho_sss``: (n_bands, T, T);
        ``weights``: ``{"rho_s_temporal", "rho_ss_temporal", "rho_sss_temporal"}``.
        """
        self.reference = {name: to_jit(self.TensorXf, maps[name], np.float32)
                          for name in GLOSSY_ALBEDOS}
        self.reference["rho_sss"] = np.array(rho_sss, np.float32).reshape(len(rho_sss), -1)
        self.reference_weights = {name: float(weights.get(name, 0.0)) for name in TEMPORAL_TERMS}

    def scale_learning_rates(self, factor):
        """Set every map's learning rate to ``factor`` times its start value."""
        self.optimizer.set_learning_rate({name: rate * float(factor)
                                          for name, rate in self.learning_rates.items()})

    def tensor(self, name):
        """The optimized variable of a map (a glossy albedo's amplitude variable, see above)."""
        return self.optimizer[name] if name in self.optimized else self.fixed[name]

    def amplitude_scale(self, eta):
        """``F0(eta_ref) / F0(eta)``: glossy albedo per unit amplitude variable (1 without)."""
        if self.reference_eta is None:
            return 1.0
        return normal_incidence_reflectance(self.reference_eta) / normal_incidence_reflectance(eta)

    def variables_of(self, maps):
        """The optimizer's variables from maps of physical values (NumPy)."""
        maps = dict(maps)
        if self.reference_eta is not None:
            scale = self.amplitude_scale(np.asarray(maps["eta"], np.float64))
            for name in GLOSSY_ALBEDOS:
                maps[name] = (np.asarray(maps[name], np.float64) / scale).astype(np.float32)
        return maps

    def variables_numpy(self):
        """``name -> (T, T) float32`` of every optimizer variable (detached)."""
        return {name: np.array(self.tensor(name), dtype=np.float32) for name in OPTIMIZED}

    def to_numpy(self):
        """``name -> (T, T) float32`` of every map in physical values (detached)."""
        maps = self.variables_numpy()
        if self.reference_eta is not None:
            scale = self.amplitude_scale(maps["eta"].astype(np.float64))
            for name in GLOSSY_ALBEDOS:
                maps[name] = (maps[name] * scale).astype(np.float32)
        return maps

    def state(self):
        """What a checkpoint stores: variables and the optimizer's moments, as NumPy."""
        state = {f"map.{name}": array for name, array in self.variables_numpy().items()}
        for name in self.optimized:
            extra = self.optimizer.state[name][3]
            if self.kind == "adam":
                # drjit.opt.Adam keeps (steps, first moment, second moment, AMSGrad max)
                state[f"adam_steps.{name}"] = np.array([int(np.array(extra[0]).ravel()[0])],
                                                       np.int64)
                state[f"adam_m.{name}"] = np.array(extra[1], dtype=np.float32)
                state[f"adam_v.{name}"] = np.array(extra[2], dtype=np.float32)
            else:
                state[f"rmsprop.{name}"] = np.array(extra, dtype=np.float32)
        state["rho_sss"] = self.rho_sss.copy()
        return state

    def restore(self, state):
        """Inverse of :meth:`state` (exactly: values, moments and ``rho_sss``)."""
        for name in OPTIMIZED:
            tensor = to_jit(self.TensorXf, state[f"map.{name}"], np.float32)
            if name in self.optimized:
                self.optimizer[name] = tensor
                value, promoted, lr, extra = self.optimizer.state[name]
                Float = type(value.array)

                def moment(key):
                    return to_jit(Float, np.ravel(state[key]), np.float32)

                if self.kind == "adam":
                    steps = type(extra[0])(int(state[f"adam_steps.{name}"][0]))
                    extra = (steps, moment(f"adam_m.{name}"), moment(f"adam_v.{name}"), None)
                else:
                    extra = moment(f"rmsprop.{name}")
                # drjit.opt keeps (value, promoted, lr, optimizer state) per parameter
                self.optimizer.state[name] = (value, promoted, lr, extra)
            else:
                self.fixed[name] = tensor
        self.rho_sss = np.array(state["rho_sss"], dtype=np.float32)

    def clamp(self, bounds):
        for name in self.optimized:
            low, high = bounds[name]
            self.optimizer[name] = dr.clip(self.optimizer[name], low, high)


def _window_values(tensor, prepared):
    """Flat Float of a map over the patch's window."""
    return dr.gather(type(tensor.array), tensor.array, prepared.window_index_jit)


def _per_view(values, prepared):
    return dr.gather(type(values), values, prepared.texel)


SLOPES = ("dH_du", "dH_dv")
"""The per texel-view leaves of the displacement: its slopes, from which eq. 25 builds the normal."""


def window_slopes(height_window, prepared):
    """``(dH/du, dH/dv)`` over the window (flat Float, detached) from its displacement."""
    _, _, _, TensorXf = jit_types()
    shape = prepared.window_valid.shape
    # off-mesh texels carry no surface: the frame's differences are one-sided there
    height = TensorXf(dr.detach(height_window) * prepared.window_valid_jit, shape)
    return tuple(slope.array for slope in height_gradient(height, prepared.height_frame))


def per_view_normals(dH_du, dH_dv, prepared):
    """Eq. 25 per texel-view from per texel-view slopes, in the texel's shading frame."""
    _, Array3f, _, _ = jit_types()
    frame = prepared.height_frame

    def gathered(maps):
        return [_per_view(component.array, prepared) for component in maps]

    return Array3f(*normals_from_slopes(dH_du, dH_dv, gathered(frame.normal),
                                        gathered(frame.tangent_u), gathered(frame.tangent_v),
                                        _per_view(frame.orientation.array, prepared)))


def patch_leaves(params, prepared, differentiable):
    """Window values of every map, and the per texel-view values the model reads.

    The reverse pass stops at the per texel-view values (its leaves): every
    map's value gathered to the texel-view, and the displacement's slopes.
    Their gradients are then summed per texel (:meth:`PreparedPatch.texel_sums`),
    not scatter-added inside Dr.Jit's kernels, so a step's gradient is the
    same however many threads run it.

    Returns ``(window, leaves)``: ``{map: Float}`` (detached) and
    ``{name: Float}``; with ``differentiable``, the leaves of the optimized maps
    have gradients enabled.
    """
    window = {name: dr.detach(_window_values(params.tensor(name), prepared)) for name in OPTIMIZED}
    leaves = {name: _per_view(window[name], prepared) for name in OPTIMIZED
              if name != "displacement"}
    for name, slope in zip(SLOPES, window_slopes(window["displacement"], prepared)):
        leaves[name] = _per_view(slope, prepared)
    if differentiable:
        for name, leaf in leaves.items():
            source = "displacement" if name in SLOPES else name
            if source in params.optimized:
                dr.enable_grad(leaf)
    return window, leaves


def predicted_patch(params, prepared, config, differentiable=False):
    """Per texel-view parameters, normals and the predicted Stokes components of a patch.

    Returns ``(stokes, window, normal, specular_views, leaves)``: ``window``
    and ``leaves`` as from :func:`patch_leaves`.
    """
    window, leaves = patch_leaves(params, prepared, differentiable)
    stokes, normal, specular_views = predict_from_leaves(params, prepared, config, leaves)
    return stokes, window, normal, specular_views, leaves


def predict_from_leaves(params, prepared, config, leaves, offsets=None):
    """The predicted Stokes components of a patch from :func:`patch_leaves`' leaves.

    ``offsets``: ``{name: Float}`` added per texel-view to the physical
    value of a glossy parameter or to a slope (``dH_du``, ``dH_dv``) before
    the model reads it: the tangents of the posterior's forward derivatives
    (:mod:`polarbssrdf.inverse.polarimetric.posterior`).

    Returns ``(stokes, normal, specular_views)`` (see :func:`predicted_patch`).
    """
    offsets = offsets or {}

    def value(name):
        return leaves[name] + offsets[name] if name in offsets else leaves[name]

    normal = per_view_normals(value("dH_du"), value("dH_dv"), prepared)
    per_view = {name: leaves[name] for name in OPTIMIZED if name != "displacement"}
    scale = params.amplitude_scale(per_view["eta"])
    for name in GLOSSY_ALBEDOS:
        per_view[name] = per_view[name] * scale
    per_view = {name: per_view[name] + offsets[name] if name in offsets else per_view[name]
                for name in per_view}
    held = dict(per_view)
    specular_views = None
    if config.separate_lobes:
        specular_views = dr.detach(half_vector_cosine(prepared.geometry, normal)) \
            > config.specular_half_cosine
        for name in ("rho_s", "alpha_s"):
            held[name] = dr.select(specular_views, per_view[name], dr.detach(per_view[name]))
        for name in ("rho_ss", "alpha_ss"):
            held[name] = dr.select(specular_views, dr.detach(per_view[name]), per_view[name])
    stokes = predict_stokes(prepared.geometry, normal, per_view["eta"], held["rho_s"],
                            held["alpha_s"], held["rho_ss"], held["alpha_ss"],
                            coaxial=config.coaxial)
    return stokes, normal, specular_views


def usable_views(prepared, normal, config):
    """Weight 1 for texel-views whose view and light cosines exceed ``min_cosine``, else 0."""
    geometry = prepared.geometry
    cos_view = dr.dot(dr.detach(normal), geometry.to_camera)
    cos_light = dr.dot(dr.detach(normal), geometry.to_light)
    return dr.select((cos_view > config.min_cosine) & (cos_light > config.min_cosine), 1.0, 0.0)


def solve_subsurface_albedo(stokes, prepared, weight, previous, temporal=None):
    """Least-squares ``rho_sss`` per window texel and band from ``L_sss`` (eq. 27), >= 0.

    ``I90 = A + rho B`` per texel-view (glossy and unit-albedo subsurface
    parts), so ``rho = sum w B (I90_obs - A) / sum w B^2`` per texel.
    Texels without usable views keep ``previous``.

    Parameters
    ----------
    previous : (n_bands, n_window) float32
        Current values over the window.
    temporal : tuple, optional
        ``(reference, strength, data_scale)``: the dynamic stage's eq. 39 term
        ``strength_i (rho - reference)^2`` per window texel and band, added to
        the data term scaled by ``data_scale`` (its weight per squared residual
        in the loss); then ``rho = (s num + c ref) / (s den + c)``.

    Returns
    -------
    (n_bands, n_window) float32 NumPy array.
    """
    glossy = dr.detach(stokes.glossy)
    unit = dr.detach(stokes.subsurface)
    A90 = 0.5 * (glossy[0] - glossy[1])
    B90 = 0.5 * (unit[0] - unit[1])
    products = [weight * dr.square(B90)]
    products += [weight * B90 * (observed[2] - A90) for observed in prepared.observed]
    sums = prepared.texel_sums(products)
    dr.eval(sums)
    sums = [np.array(total, dtype=np.float64) for total in sums]
    denominator = sums[0]
    known = denominator > 1e-30 * max(float(denominator.max(initial=0.0)), 1e-30)
    solved = np.array(previous, dtype=np.float32, copy=True)
    for band, numerator in enumerate(sums[1:]):
        if temporal is None:
            solved[band, known] = np.maximum(numerator[known] / denominator[known], 0.0)
            continue
        reference, strength, scale = temporal
        # I_sss = 2 I90: the residual of L_sss is twice I90's
        top = 4.0 * scale * numerator + strength * reference[band]
        bottom = 4.0 * scale * denominator + strength
        solved[band, known] = np.maximum(top[known] / bottom[known], 0.0)
    return solved


TEMPORAL_ALBEDO_SCALE = 0.01
"""Relative change of the albedo's intensity (mean over bands) above which eq. 39's pull fades."""

TEMPORAL_CHANGE_SIGMA_TEXELS = 1.5
"""Gaussian sigma (texels) of the low-pass the albedo's change passes before eq. 39's robust
weight reads it: a flush spreads over centimetres, the sensor noise is per texel."""


def _temporal_albedo_term(params, prepared, weight, config, current):
    """``(reference, strength, data_scale)`` of the dynamic stage's subsurface pull, or None.

    Eq. 39 weighs the pull toward the static albedo by ``W = |mean_b rho0 -
    mean_b rho|``, the change of the albedo's intensity: largest where
    hemoglobin changes, so a weight strong enough to steady the noise holds
    back the flush (on a raw 5-frame face a weight of 1e6 held back 14% of the
    cheeks' change and left the noise where it was). Here the weight is the
    robust ``W = 1 / (1 + (c / s)^2)`` of the relative change ``c`` of that
    intensity with ``s`` = :data:`TEMPORAL_ALBEDO_SCALE`: texels whose albedo
    moved by the noise are held to the static albedo, texels that really
    changed (a flush moves it by several percent) are free. ``c`` is the
    change averaged over the texel's neighbours (a Gaussian of
    :data:`TEMPORAL_CHANGE_SIGMA_TEXELS` over the window's valid texels): per
    texel, the noise alone moved many texels past ``s`` and freed them. On the
    raw 5-frame face of ``tests/inverse/polarimetric/test_dynamic.py`` the
    frame-to-frame spread of ``rho_sss`` without flush went from 0.74x to
    0.59x of the spread without eq. 39, the cheeks' change from 95% to 94% of
    the truth's (sigma 3: 0.51x, 90%).
    ``strength = lambda W / n_valid`` (a mean over the window's valid texels,
    like the other regularizers); ``data_scale = 1 / (sigma^2 count)``, the
    weight of a squared ``I_sss`` residual in ``L_sss``.
    """
    if params.reference is None or params.reference_weights["rho_sss_temporal"] <= 0:
        return None
    reference = params.reference["rho_sss"][:, prepared.window_index]
    intensity = np.maximum(reference.mean(axis=0), 1e-6)
    valid = prepared.window_valid
    relative = (np.asarray(current).mean(axis=0) - intensity) / intensity
    relative = masked_low_pass(relative.reshape(valid.shape), valid,
                               TEMPORAL_CHANGE_SIGMA_TEXELS).ravel()
    change = np.abs(relative)
    robust = 1.0 / (1.0 + np.square(change / TEMPORAL_ALBEDO_SCALE))
    valid = valid.ravel()
    strength = (params.reference_weights["rho_sss_temporal"] * robust * valid
                / max(float(valid.sum()), 1.0))
    count = max(float(dr.sum(weight)[0]), 1.0)
    sigma = config.photometric_noise * prepared.image_scale
    return reference, strength, 1.0 / (sigma * sigma * count)


def texel_view_terms(params, prepared, config, solve_albedo=True, differentiable=False):
    """Per texel-view data-term contributions of a patch, summed over bands.

    With ``solve_albedo`` the patch's ``rho_sss`` is first re-solved in closed
    form (and stored in ``params``); without, the current maps are used.

    Returns ``(per_view, weight, window, leaves)``: ``{term: Float}``
    (evaluated), the usable-view weights, and :func:`patch_leaves`' window
    values and leaves (with gradients enabled when ``differentiable``).
    """
    stokes, window, normal, _, leaves = predicted_patch(params, prepared, config, differentiable)
    weight = usable_views(prepared, normal, config)
    # the albedo solve and every loss term read these: compute them once
    dr.eval(stokes.glossy, stokes.subsurface, weight)
    T = params.resolution
    flat_rho = params.rho_sss.reshape(len(params.rho_sss), T * T)
    solved = flat_rho[:, prepared.window_index]
    if solve_albedo:
        solved = solve_subsurface_albedo(stokes, prepared, weight, solved,
                                         _temporal_albedo_term(params, prepared, weight, config,
                                                               solved))
        flat_rho[:, prepared.window_index] = solved
    Float = type(weight)
    glossy_I_s = stokes.glossy[1]  # I0 - I90 of the glossy lobes is S1
    per_view = {name: Float(0.0) for name in DATA_TERMS}
    for band, observed in enumerate(prepared.observed):
        rho = _per_view(to_jit(Float, solved[band], np.float32), prepared)
        predicted = stokes.analyser_images(rho)
        band_terms = data_loss_terms(predicted, observed, glossy_I_s, weight,
                                     dr.opaque(Float, prepared.image_scale),
                                     # opaque: the noise changes between epochs
                                     dr.opaque(Float, config.photometric_noise))
        for name in DATA_TERMS:
            per_view[name] = per_view[name] + band_terms[name]
    # one kernel for every band and term; reducing each separately would recompute the model
    dr.eval(*per_view.values())
    return per_view, weight, window, leaves


REGULARIZERS = {
    "H_magnitude": ("displacement", displacement_magnitude),
    "H_laplacian": ("displacement", displacement_laplacian),
    "alpha_s_smoothness": ("alpha_s", neighbourhood_smoothness),
    "alpha_ss_smoothness": ("alpha_ss", neighbourhood_smoothness),
    "eta_smoothness": ("eta", neighbourhood_smoothness),
}
"""Each regularizer term (eq. 33-35): the map it acts on and its function."""


@dataclasses.dataclass
class PatchLoss:
    """The loss of one patch.

    Attributes
    ----------
    terms : dict
        Every term: Dr.Jit scalars for the data terms, floats for the
        temporal terms and the regularizers.
    total : Float
        The weighted sum (a Dr.Jit scalar); only its data terms are attached
        to the leaves, the other terms enter as constants.
    weight : Float
        The usable-view weight of every texel-view.
    leaves : dict
        :func:`patch_leaves`' per texel-view values.
    window_gradient : dict
        ``map -> (n_window,) float64``: the gradient of the weighted temporal
        and regularizer terms over the window (after :func:`patch_gradients`,
        of the whole total).
    gradient_norm : float or None
        Norm of the total's gradient over every optimized map (set by :func:`patch_gradients`).
    dropped_views : int
        Texel-views left out of the gradient because theirs was not finite
        (set by :func:`patch_gradients`).
    """

    terms: dict
    total: object
    weight: object
    leaves: dict
    window_gradient: dict
    gradient_norm: float = None
    dropped_views: int = 0


def window_regularizers(windows, prepared, weights, optimized=OPTIMIZED):
    """Value of every regularizer term over a window and the weighted gradient per map.

    ``windows``: ``{map: (n_window,) array}``, the window values; gradients
    only for the ``optimized`` maps. Returns ``({term: float}, {map: (n_window,) array})``.
    """
    terms, gradients = {}, {}

    def add(term, name, gradient):
        weight = float(weights.get(term, 0.0))
        if weight != 0.0 and name in optimized:
            gradients[name] = gradients.get(name, 0.0) + weight * gradient.ravel()

    smooth = [(term, name) for term, (name, function) in REGULARIZERS.items()
              if function is neighbourhood_smoothness]
    # the 5 x 5 terms filter their maps as one stack
    values, stack = neighbourhood_smoothness(np.stack([windows[name] for _, name in smooth]),
                                             prepared.stencils)
    for (term, name), value, gradient in zip(smooth, values, stack):
        terms[term] = float(value)
        add(term, name, gradient)
    for term, (name, function) in REGULARIZERS.items():
        if function is not neighbourhood_smoothness:
            terms[term], gradient = function(windows[name], prepared.stencils)
            add(term, name, gradient)
    return {term: terms[term] for term in REGULARIZERS}, gradients


def temporal_terms(params, windows, prepared, weights):
    """The dynamic stage's pulls of ``rho_s`` and ``rho_ss`` toward the static maps (eq. 38).

    ``mean(valid (x - x_static)^2)`` over the window's valid texels, in the
    optimizer's variables. Returns ``({term: float}, {map: (n_window,) float64})``
    (weighted gradients), both empty without a reference.
    """
    terms, gradients = {}, {}
    if params.reference is None:
        return terms, gradients
    valid = prepared.window_valid.ravel().astype(np.float64)
    count = max(float(valid.sum()), 1.0)
    for name in GLOSSY_ALBEDOS:
        reference = np.array(_window_values(params.reference[name], prepared))
        difference = valid * (windows[name].astype(np.float64) - reference)
        term = f"{name}_temporal"
        terms[term] = float(np.sum(difference * difference)) / count
        weight = float(weights.get(term, 0.0))
        if weight != 0.0 and name in params.optimized:
            gradients[name] = weight * 2.0 * difference / count
    return terms, gradients


def patch_losses(params, prepared, config, weights, solve_albedo=True, differentiable=False):
    """Every loss term of a patch (:class:`PatchLoss`).

    See :func:`texel_view_terms` for ``solve_albedo`` and ``differentiable``.
    """
    per_view, weight, window, leaves = texel_view_terms(params, prepared, config, solve_albedo,
                                                        differentiable)
    count = dr.maximum(dr.detach(dr.sum(weight)), 1.0)
    terms = {name: dr.sum(term) / (count * len(prepared.observed))
             for name, term in per_view.items()}
    Float = type(count)
    # the weights (per stage and config) and the regularizers' values (NumPy, new at every
    # patch) enter as kernel inputs: as literals each patch compiled a kernel of its own
    total = sum(dr.opaque(Float, float(weights[name])) * terms[name]
                for name in terms if float(weights.get(name, 0.0)) != 0.0)
    windows = {name: np.array(values) for name, values in window.items()}
    gradients = {}
    for extra_terms, extra_gradients in (
            window_regularizers(windows, prepared, weights, params.optimized),
            temporal_terms(params, windows, prepared, weights)):
        terms.update(extra_terms)
        total = total + dr.opaque(Float, sum(float(weights.get(name, 0.0)) * value
                                             for name, value in extra_terms.items()))
        for name, gradient in extra_gradients.items():
            gradients[name] = gradients.get(name, 0.0) + gradient
    return PatchLoss(terms, total, weight, leaves, gradients)


def _leaf_gradients(leaves, prepared):
    """The reverse pass's gradients summed per texel, and how many texel-views were dropped.

    Returns ``({map: (n_window,) float64}, dropped)``. A texel-view whose
    gradient is not finite (a singular configuration of the model) is left
    out of the sums, and counted, rather than turning its patch's step into
    NaN. The slopes' gradients become the displacement's through the adjoint
    of the central differences
    (:func:`polarbssrdf.geometry.height.height_gradient_adjoint`).
    """
    names = [name for name, leaf in leaves.items() if dr.grad_enabled(leaf)]
    if not names:
        return {}, 0
    gradients = [dr.grad(leaves[name]) for name in names]
    finite = dr.isfinite(gradients[0])
    for gradient in gradients[1:]:
        finite &= dr.isfinite(gradient)
    gradients = [dr.select(finite, gradient, 0.0) for gradient in gradients]
    # the reverse pass in one kernel first: the sums' loop gathers from its results
    dr.eval(gradients, finite)
    dropped = len(prepared) - int(dr.count(finite)[0])
    sums = prepared.texel_sums(gradients)
    dr.eval(sums)
    window = {name: np.array(total, dtype=np.float64) for name, total in zip(names, sums)}
    if SLOPES[0] in window:
        shape = prepared.window_valid.shape
        height = height_gradient_adjoint(window.pop(SLOPES[0]).reshape(shape),
                                         window.pop(SLOPES[1]).reshape(shape),
                                         prepared.window_valid)
        window["displacement"] = (height * prepared.window_valid).ravel()
    return window, dropped


def patch_gradients(params, prepared, config, weights, solve_albedo=True):
    """The loss of a patch with the gradient of its total on every optimized map (:class:`PatchLoss`).

    Dr.Jit's reverse pass differentiates the data terms down to the per
    texel-view leaves; their gradients are summed per texel, the temporal
    terms' and the regularizers' own gradients added, and the result set as
    the gradient of every optimized map (zero outside the window), Sobolev-
    preconditioned where ``config.sobolev_lengths`` asks
    (:mod:`polarbssrdf.inverse.polarimetric.preconditioning`; ``window_gradient``
    keeps the plain gradient). See :func:`texel_view_terms` for ``solve_albedo``.
    """
    loss = patch_losses(params, prepared, config, weights, solve_albedo, differentiable=True)
    # with every data weight 0 (a regularizer alone) nothing is attached: not an error
    dr.backward(loss.total, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    gradients, loss.dropped_views = _leaf_gradients(loss.leaves, prepared)
    for name, gradient in loss.window_gradient.items():
        gradients[name] = gradients.get(name, 0.0) + gradient
    Float = type(loss.weight)
    T = params.resolution
    squared = 0.0
    for name in params.optimized:
        window = np.asarray(gradients.get(name, np.zeros(len(prepared.window_index))))
        # the clip reads the loss's own steepness, before the preconditioner reshapes the step
        squared += float(np.sum(window * window))
        length = float(config.sobolev_lengths.get(name, 0.0))
        if length > 0.0:
            window = sobolev_gradient(window.reshape(prepared.window_valid.shape), length,
                                      prepared.window_valid).ravel()
        full = dr.zeros(Float, T * T)
        # the window's texels are distinct: a plain scatter
        dr.scatter(full, to_jit(Float, window, np.float32), prepared.window_index_jit)
        dr.set_grad(params.optimizer[name], params.TensorXf(full, (T, T)))
    loss.window_gradient = gradients
    loss.gradient_norm = float(np.sqrt(squared))
    return loss


def active_weights(config, data_weights=None):
    """Loss weights with the regularization scale and the ablation switches applied."""
    weights = dict(data_weights if data_weights is not None else config.weights)
    for name in REGULARIZER_TERMS:
        weights[name] = weights[name] * config.regularization_scale
    if not config.polarimetric:
        weights["psi"] = weights["phi"] = 0.0
    return weights


def _scalar(value):
    """A loss term as a float (Dr.Jit scalars and Python numbers alike)."""
    return float(value) if isinstance(value, (int, float)) else float(value[0])


def optimizer_step(params, prepared, config, weights):
    """One step on one patch; returns ``{term: float}`` with ``total`` and the gradient norm."""
    if len(prepared) == 0:
        return None
    loss = patch_gradients(params, prepared, config, weights)
    terms, total, norm = loss.terms, loss.total, loss.gradient_norm
    if not np.isfinite(norm):
        # a non-finite gradient would turn texels into NaN (and the clamp into a bound): skip
        for name in params.optimized:
            dr.clear_grad(params.optimizer[name])
        record = {name: float("nan") for name in terms}
        record.update(total=float("nan"), gradient_norm=norm, skipped=1.0,
                      dropped_views=float(loss.dropped_views))
        return record
    scale = min(1.0, config.gradient_clip / norm) if norm > 0 and config.gradient_clip > 0 else 1.0
    if params.optimized:
        # opaque: a literal scale would compile a new kernel at every step
        Float = type(dr.grad(params.optimizer[params.optimized[0]]).array)
        params.optimizer.step(grad_scale=dr.opaque(Float, scale))
        params.clamp(config.bounds)
    record = {name: _scalar(value) for name, value in terms.items()}
    record["total"] = _scalar(total)
    record["gradient_norm"] = norm
    record["skipped"] = 0.0
    record["dropped_views"] = float(loss.dropped_views)
    return record
