"""Settings of the polarimetric stages, with the paper's values as defaults (supplement sec. 5.1-5.2).

:class:`StaticConfig` holds the static stage's settings and, in its
``dynamic`` object, the dynamic stage's (:data:`DYNAMIC_WEIGHTS`,
:func:`parse_dynamic`). Every field can be overridden from a JSON file
(``reconstruct --config``, read by :func:`polarbssrdf.inverse.config.load_static_config`):
a JSON object with any subset of the keys below; nested ``weights``,
``bounds``, ``initial`` and ``learning_rates`` objects override only the
keys they name. Every value must have its JSON type (a flag ``true`` or
``false``, not ``"false"``; an integer ``30``, not ``30.0``); unknown keys,
wrong types and out-of-range values are errors that name the key. The
``bio`` object is carried for the biophysical stage, which checks it
(:func:`polarbssrdf.inverse.biophysical.config.bio_config`).
"""

from __future__ import annotations

import dataclasses
import math

from polarbssrdf.io.jsonfile import (
    check_boolean,
    check_integer,
    check_number,
    check_string,
    json_type,
)

STATIC_WEIGHTS = {
    "psi": 0.002, "sss": 1.0, "s": 1.0, "phi": 1.0,  # eq. 26
    "H_magnitude": 0.01, "H_laplacian": 100.0,  # eq. 33-34 (see STATIC_WEIGHTS' docstring)
    "alpha_s_smoothness": 200.0, "alpha_ss_smoothness": 200.0, "eta_smoothness": 400.0,  # eq. 35
}
"""Loss weights of eq. 26 and 32 (lambda_psi, lambda_sss, lambda_s, lambda_phi, then the regularizers).

The displacement's: once synth rendered the geometry its truth describes (issue 33), the
earlier ``H_magnitude`` 1 and ``H_laplacian`` 1000 flattened the recovered relief at
every scale (regression slope on the truth 0.18; 0.23-0.42 per octave of scale), and a
Gauss-Newton step with them kept it flat: the pull toward 0 and the curvature penalty,
not the data, set its amplitude. On a face at a seed of its own (8 views, raw mosaics,
256^2, no relief features) with the displacement's learning rate 4x: ``H_laplacian`` 10
gave slope 0.75 and normals 0.61 deg mean (texel-scale noise let through), 100 gave 0.63
and 0.52 deg (median 0.38), 300 gave 0.42 and 0.51 deg (median 0.41), against 0.55 deg
(median 0.49) with the old weights and 0.63 deg for the base mesh (2026-12-05,
bench/RESULTS.md). ``H_magnitude`` 0.01 keeps only the mean of each chart's relief
anchored to the base mesh: the stage sets that mean to the prior's 0 after the fit
(:mod:`~polarbssrdf.inverse.polarimetric.relief_level`), since no view sees it."""

BOUNDS = {
    "eta": (1.3, 1.6), "alpha_s": (0.1, 0.7), "alpha_ss": (0.7, 1.0),
    "rho_s": (0.0, 10.0), "rho_ss": (0.0, 10.0), "displacement": (-5.0, 5.0),
}
"""Box constraints applied after every step (albedos only need to stay >= 0; H in mm)."""

INITIAL = {"eta": 1.4, "alpha_s": 0.35, "alpha_ss": 1.0, "rho_s": 0.5, "rho_ss": 0.2,
           "displacement": 0.0}
"""Start values (those of the authors' code for eta, alpha_s, alpha_ss and H)."""

LEARNING_RATES = {"eta": 5e-3, "alpha_s": 2e-3, "alpha_ss": 5e-4, "rho_s": 1e-2, "rho_ss": 4e-3,
                  "displacement": 8e-3}
"""RMSProp learning rates per map (per step; H in mm per step).

RMSProp steps each texel by about its learning rate, so these set how far a
map can travel in the default 150 epochs. ``alpha_ss`` moves slowly: the two
GGX lobes trade roughness against albedo along a shallow valley, and a fast
``alpha_ss`` drifts along it (on a 12-view sphere: ``alpha_ss`` 0.89 for a
truth of 0.97 and ``alpha_s`` off by 0.025, against 0.973 and 0.020 with these
rates); ``rho_s`` starts far from typical skin (0.5 vs about 0.8) and moves fast.
The displacement's 8e-3 mm per step (2e-3 before): with the weaker regularizers of
:data:`STATIC_WEIGHTS` its long-wavelength relief, whose gradient is small per texel,
reached slope 0.56 of the truth's in 150 epochs at 2e-3 and 0.83 in 600; 8e-3 reaches 0.75
in 150.
"""

SOBOLEV_LENGTHS = {"displacement": 8.0, "eta": 0.0, "rho_s": 0.0, "alpha_s": 0.0, "rho_ss": 0.0,
                   "alpha_ss": 0.0}
"""Smoothing length (texels) of each map's Sobolev-preconditioned gradient
(:mod:`polarbssrdf.inverse.polarimetric.preconditioning`; 0: the plain gradient).

The displacement's 8 texels: on the demo's capture at seed 1 (256^2, 150 epochs) the relief's
slope on the truth went from 0.53 to 1.08 (correlation 0.78 to 0.94) and its MAE from 0.68 to
0.36 of the constant map's; 4, 8 and 16 texels gave 0.357, 0.358 and 0.362 (bench/RESULTS.md,
2026-12-07). The glossy maps stay at 0: at 4 texels eta and alpha_s improved (0.46 -> 0.43 and
0.47 -> 0.40 of the constant map's MAE), at 8 alpha_s's 2-std coverage fell from 0.97 to 0.55.
"""

OPTIMIZERS = ("rmsprop", "adam")
"""The ``drjit.opt`` optimizers the stages can use."""

OPTIMIZED = tuple(INITIAL)
"""The maps the gradient steps update (``rho_sss`` per band is solved in closed form)."""


@dataclasses.dataclass
class StaticConfig:
    """Settings of the static stage.

    Attributes
    ----------
    iterations : int
        Epochs: passes over every patch of the texture in a random order.
    patch_size : int
        Patch edge in texels (rounded down to the observation store's block size;
        the whole texture when it is smaller).
    min_steps_per_epoch : int
        On small textures one epoch is a single patch; repeat it so that an
        epoch takes at least this many steps.
    weights, bounds, initial, learning_rates : dict
        See :data:`STATIC_WEIGHTS`, :data:`BOUNDS`, :data:`INITIAL`, :data:`LEARNING_RATES`.
    regularization_scale : float
        One factor on every regularizer weight (eq. 32-35), keeping the
        paper's ratios. The default 1 keeps the paper's weights: 10 helped a
        raw face's eta (MAE 0.0184 -> 0.0166) but hurt a coarse sphere's
        (0.0083 -> 0.0126) and its normals, because eq. 35's window is fixed
        in texels (bench/RESULTS.md).
    glossy_amplitudes : bool
        Optimize ``rho_s`` and ``rho_ss`` through their amplitudes at normal
        incidence, ``rho F0(eta) / F0(initial eta)`` (see
        :mod:`polarbssrdf.inverse.polarimetric.optimize`), which takes the ``eta``-albedo
        valley out of the optimizer's way; ``False`` steps the albedos
        themselves.
    optimizer : str
        ``"rmsprop"`` (``drjit.opt.RMSProp``, the authors' choice) or
        ``"adam"`` (``drjit.opt.Adam``, beta_1 0.9, beta_2 0.999).
    gradient_clip : float
        Maximum global gradient norm (the authors' 2.0).
    face_level_evaluations : int
        Before the per-texel epochs, a run from the constant start may fit one
        face-wide value of each glossy map by Levenberg-Marquardt with the
        displacement held and ``rho_sss`` solved per texel
        (:func:`polarbssrdf.inverse.polarimetric.face_level.fit_face_levels`),
        in at most this many passes over the patches (at least 2: the first
        evaluates the start); 0 (the default) starts from ``initial`` as the
        authors' code does. On a wrinkled 512^2 face
        12 took the glossy maps from 1.7-4.9 times the constant map's error to
        1.00-1.01 (``alpha_ss`` excepted) and the displacement from 0.78 to
        0.36; on the demo's 256^2 captures it made ``rho_ss`` worse (1.06 ->
        1.56 and 1.07 -> 3.42 at seeds 0 and 1) and the displacement too (0.37
        -> 0.54 at seed 0), so it is off by default (bench/RESULTS.md).
    capture_blur_mm : float or None
        Standard deviation (mm) of the capture's blur of the surface, as one Gaussian
        (:func:`~polarbssrdf.inverse.observations.footprint.capture_blur_variance_mm2`):
        the displacement's std counts the relief finer than it as seen through the
        prior only. It does not change the fit. ``None`` (default): the static and
        dynamic stages estimate it from the capture's cameras; a Python call of
        :func:`~polarbssrdf.inverse.polarimetric.fit.run_polarimetric_fit` without it
        takes the data as sharp.
    sobolev_lengths : dict
        Per map, the smoothing length (texels) of its Sobolev-preconditioned
        gradient, ``(I + length^2 L)^-1 g`` (:data:`SOBOLEV_LENGTHS`; 0 steps
        the plain gradient). It changes how fast the long wavelengths
        converge, not where the minimum is.
    final_learning_rate : float
        The learning rates decay exponentially over the epochs to this
        fraction of their start values. RMSProp steps a texel by about its
        learning rate whatever the gradient, so with a constant rate the maps
        jitter by about the rate around the optimum; the decay removes that
        floor (1 keeps the rates constant, as the authors' code does).
    specular_half_cosine : float
        Texel-views whose half vector is within ``acos`` of this of the normal
        train the specular lobe (single scattering held), the others the
        single-scattering lobe (specular held); the authors' 0.86.
    separate_lobes : bool
        Split the texel-views between the lobes by ``specular_half_cosine``
        as the authors' code does; by default both lobes learn from every
        texel-view and are kept apart by their disjoint roughness bounds
        (``alpha_s`` in [0.1, 0.7], ``alpha_ss`` in [0.7, 1.0]), which fitted
        noise-free spheres better (see docs/reconstruct.md).
    photometric_noise : float
        Expected noise of the images as a fraction of the patch's mean
        ``I_sss``: data residuals are divided by it, so a data term is a
        mean chi-square per texel-view and the paper's regularizer weights
        act in parameter units against it.
    estimate_noise : bool
        After each epoch, raise the noise unit to the RMS ``I_sss`` residual
        the fit leaves (never below ``photometric_noise``), so data and
        regularizers keep their balance on noisier captures.
    min_cosine : float
        Texel-views used in the losses need ``cos`` of the view and of the
        light above this.
    min_views : int
        Texels with fewer usable texel-views get confidence 0 and take their
        values from their neighbours.
    residual_limit : float
        Texels whose mean chi-square of ``I_sss`` and ``I_s`` exceeds this many
        times the median texel's, plus the residual their albedo's step from
        their neighbours can cause (a freckle's: see
        :func:`polarbssrdf.inverse.polarimetric.fit.feature_chi_square`), get
        confidence 0 and their neighbours' values (0 turns the test off).
    seed : int
        Seed of the patch order (a resumed run repeats it exactly).
    polarimetric : bool
        Use ``L_psi`` and ``L_phi``; ``False`` is the ablation without them.
    dynamic : dict
        Settings of the dynamic stage: ``iterations`` (epochs per frame,
        default 30) and ``weights`` (keys of
        :data:`DYNAMIC_WEIGHTS`, eq. 36-39).
    bio : dict
        Settings of the biophysical stage: any key of
        :class:`polarbssrdf.inverse.biophysical.config.BiophysicalConfig`, and
        ``free_melanin`` (fit ``C_m`` and ``beta_m`` in every frame instead of
        holding the first frame's).
    coaxial : bool
        Ablation: take the light direction equal to the view direction.
    """

    iterations: int = 150
    patch_size: int = 256
    min_steps_per_epoch: int = 4
    weights: dict = dataclasses.field(default_factory=lambda: dict(STATIC_WEIGHTS))
    bounds: dict = dataclasses.field(default_factory=lambda: dict(BOUNDS))
    initial: dict = dataclasses.field(default_factory=lambda: dict(INITIAL))
    learning_rates: dict = dataclasses.field(default_factory=lambda: dict(LEARNING_RATES))
    regularization_scale: float = 1.0
    glossy_amplitudes: bool = False
    optimizer: str = "rmsprop"
    gradient_clip: float = 2.0
    final_learning_rate: float = 0.1
    sobolev_lengths: dict = dataclasses.field(default_factory=lambda: dict(SOBOLEV_LENGTHS))
    face_level_evaluations: int = 0
    capture_blur_mm: float | None = None
    specular_half_cosine: float = 0.86
    separate_lobes: bool = False
    photometric_noise: float = 0.01
    estimate_noise: bool = True
    min_cosine: float = 0.3
    min_views: int = 2
    residual_limit: float = 9.0
    seed: int = 0
    polarimetric: bool = True
    coaxial: bool = False
    dynamic: dict = dataclasses.field(default_factory=dict)
    bio: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        # JSON types first: Python's bool("false") is True, so a flag given as a string
        # would silently turn the option on
        for field in dataclasses.fields(self):
            if field.type == "bool":
                check_boolean(getattr(self, field.name), f"config: {field.name}")
        _positive_int(self.iterations, "iterations", minimum=0)
        _positive_int(self.patch_size, "patch_size", minimum=8)
        _positive_int(self.min_steps_per_epoch, "min_steps_per_epoch")
        _positive_int(self.min_views, "min_views")
        _positive_int(self.face_level_evaluations, "face_level_evaluations", minimum=0)
        if self.face_level_evaluations == 1:
            raise ValueError("config: face_level_evaluations must be 0 (off) or at least 2 (the "
                             "first pass only evaluates the start), got 1")
        _positive_int(self.seed, "seed", minimum=0)
        if self.capture_blur_mm is not None:
            _finite(self.capture_blur_mm, "capture_blur_mm", minimum=0.0)
        for key, table in (("weights", STATIC_WEIGHTS), ("learning_rates", LEARNING_RATES),
                           ("sobolev_lengths", SOBOLEV_LENGTHS)):
            values = getattr(self, key)
            _known_keys(values, table, key)
            for name, value in values.items():
                _finite(value, f"{key}.{name}", minimum=0.0)
        _known_keys(self.bounds, BOUNDS, "bounds")
        for name, pair in self.bounds.items():
            if (not isinstance(pair, (list, tuple)) or len(pair) != 2
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                               and math.isfinite(v) for v in pair) or not pair[0] < pair[1]):
                raise ValueError(f"config: bounds.{name} must be [low, high] (two numbers) with "
                                 f"low < high, got {pair!r}")
        self.bounds = {name: (float(low), float(high)) for name, (low, high) in self.bounds.items()}
        if self.bounds["eta"][0] <= 1.0:
            raise ValueError("config: bounds.eta must stay above 1 (a dielectric)")
        if self.bounds["alpha_s"][0] <= 0 or self.bounds["alpha_ss"][0] <= 0:
            raise ValueError("config: roughness bounds must be > 0")
        _known_keys(self.initial, INITIAL, "initial")
        for name, value in self.initial.items():
            _finite(value, f"initial.{name}")
            low, high = self.bounds[name]
            if not low <= value <= high:
                raise ValueError(f"config: initial.{name} = {value} is outside bounds.{name} "
                                 f"[{low}, {high}]")
        check_string(self.optimizer, "config: optimizer", OPTIMIZERS)
        _finite(self.gradient_clip, "gradient_clip", minimum=0.0)
        _finite(self.regularization_scale, "regularization_scale", minimum=0.0)
        _finite(self.final_learning_rate, "final_learning_rate", minimum=1e-6, maximum=1.0)
        _finite(self.specular_half_cosine, "specular_half_cosine", minimum=0.0, maximum=1.0)
        _finite(self.min_cosine, "min_cosine", minimum=0.0, maximum=1.0)
        _finite(self.residual_limit, "residual_limit", minimum=0.0)
        _finite(self.photometric_noise, "photometric_noise", minimum=1e-6)
        if not isinstance(self.dynamic, dict):
            raise ValueError(f"config: dynamic must be an object, got {json_type(self.dynamic)}")
        parse_dynamic(self.dynamic, self.iterations)
        if not isinstance(self.bio, dict):
            raise ValueError(f"config: bio must be an object, got {json_type(self.bio)}")

    def to_json(self) -> dict:
        data = dataclasses.asdict(self)
        data["bounds"] = {name: list(pair) for name, pair in self.bounds.items()}
        return data


DYNAMIC_WEIGHTS = {"sss": 1.0, "s": 1.0, "phi": 0.2, "psi": 0.0,
                   "H_magnitude": 0.001, "H_laplacian": 500.0,
                   "alpha_s_smoothness": 0.0, "alpha_ss_smoothness": 0.0, "eta_smoothness": 0.0,
                   "rho_s_temporal": 100.0, "rho_ss_temporal": 100.0, "rho_sss_temporal": 1e5}
"""Weights of eq. 36-39: the paper's, except the pulls toward the static albedos.

The paper's 0.01 weigh plain sums of squared image residuals; here the data
terms are chi-squares per texel-view (``losses``), against which 0.01 does
nothing: on a raw 5-frame face (64^2, 6 views) the frame-to-frame spread of
``rho_s`` in a region without flush was 1.86% with 0.01 and 1.86% with 0;
100 gives 0.25% (1000: 0.04%), with the cheek flush tracked alike (change
-0.01071 for a truth of -0.01055 at every weight). ``rho_sss_temporal``
acts through a robust weight instead of eq. 39's (see
:func:`polarbssrdf.inverse.polarimetric.optimize._temporal_albedo_term`): on the same face
the spread of ``rho_sss`` without flush was 0.132% with no pull, 0.119% with
1e4 and 0.052% with 1e5, the cheeks' change -0.01068 and -0.01040 for the
truth's -0.01055. With eq. 39's own weight, 1e6 held back 14% of the flush
and left the spread at 0.132%."""


DEFAULT_DYNAMIC_ITERATIONS = 30
"""Epochs per frame. A frame starts from the static maps, which are close: 30 epochs track a
raw face's cheek flush within 2% of its change with normals within 2 degrees
(tests/inverse/polarimetric/test_dynamic.py). At 256^2 with 6 views and 6 bands a frame took 22.7 s with 50
epochs (bench/RESULTS.md); the static stage's 150 would be 60 s."""


def parse_dynamic(overrides, default_iterations=None):
    """``(iterations, weights)`` from a config's ``dynamic`` object; errors name the key.

    ``overrides`` may set ``iterations`` (default :data:`DEFAULT_DYNAMIC_ITERATIONS`)
    and ``weights`` (keys of :data:`DYNAMIC_WEIGHTS`).
    """
    overrides = dict(overrides or {})
    weights = dict(DYNAMIC_WEIGHTS)
    extra = overrides.pop("weights", {}) or {}
    if not isinstance(extra, dict):
        raise ValueError(f"config: dynamic.weights must be an object, got {json_type(extra)}")
    unknown = sorted(set(extra) - set(DYNAMIC_WEIGHTS))
    if unknown:
        raise ValueError(f"config: unknown dynamic.weights key(s) {unknown}; known: "
                         f"{sorted(DYNAMIC_WEIGHTS)}")
    for name, value in extra.items():
        weights[name] = float(check_number(value, f"config: dynamic.weights.{name}", minimum=0))
    iterations = overrides.pop("iterations", DEFAULT_DYNAMIC_ITERATIONS)
    if overrides:
        raise ValueError(f"config: unknown dynamic key(s) {sorted(overrides)}; known: "
                         "['iterations', 'weights']")
    check_integer(iterations, "config: dynamic.iterations", minimum=0)
    return iterations, weights


def _positive_int(value, name, minimum=1):
    check_integer(value, f"config: {name}", minimum)


def _finite(value, name, minimum=None, maximum=None):
    check_number(value, f"config: {name}", minimum, maximum)


def _known_keys(values, table, name):
    if not isinstance(values, dict):
        raise ValueError(f"config: {name} must be an object, got {json_type(values)}")
    unknown = sorted(set(values) - set(table))
    if unknown:
        raise ValueError(f"config: unknown {name} key(s) {unknown}; known: {sorted(table)}")


def merged_config(overrides=None, **changes) -> StaticConfig:
    """A :class:`StaticConfig` from defaults, a JSON-like ``overrides`` dict and keyword changes.

    Nested objects (``weights``, ``bounds``, ...) override only the keys they
    name. The ``bio`` object is checked by the biophysical stage's own
    configuration (:func:`polarbssrdf.inverse.config.static_config` does both).
    """
    data = {}
    for source in (overrides or {}, changes):
        unknown = sorted(set(source) - {f.name for f in dataclasses.fields(StaticConfig)})
        if unknown:
            raise ValueError(f"config: unknown key(s) {unknown}; known: "
                             f"{sorted(f.name for f in dataclasses.fields(StaticConfig))}")
        for key, value in source.items():
            if key in ("weights", "bounds", "initial", "learning_rates", "sobolev_lengths",
                       "dynamic", "bio"):
                if not isinstance(value, dict):
                    raise ValueError(f"config: {key} must be an object, got {json_type(value)}")
                merged = dict(data.get(key) or getattr(StaticConfig(), key))
                merged.update(value)
                data[key] = merged
            else:
                data[key] = value
    return StaticConfig(**data)
