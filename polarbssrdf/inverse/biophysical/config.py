"""Settings of the biophysical stage (supplement sec. 5.3): :class:`BiophysicalConfig`.

A run's config file carries them in its ``bio`` object (any field of
:class:`BiophysicalConfig`, plus ``free_melanin``), read by :func:`bio_config`;
unknown keys, values of the wrong JSON type (``"false"`` for a flag, ``12.0``
for an integer) and out-of-range values are errors that name the key.
"""

from __future__ import annotations

import dataclasses

from polarbssrdf.inverse.biophysical.model import PARAMETERS
from polarbssrdf.inverse.biophysical.prior import population_prior, within_face_spread
from polarbssrdf.io.jsonfile import (
    check_boolean,
    check_integer,
    check_number,
    check_string,
    json_type,
)
from polarbssrdf.skin.inversion import BOUNDS as INVERSION_BOUNDS

LEARNING_RATES = {"C_m": 3e-4, "beta_m": 3e-3, "C_h_out": 3e-4, "C_h_in": 2e-4}
"""Adam's first step size per map (fractions per step), decayed to ``final_lr_fraction`` of it."""


METHODS = ("gauss_newton", "adam")
"""Step (c)'s optimizers (:attr:`BiophysicalConfig.method`)."""

PRIORS = ("matern", "none")
"""The maps' priors (:attr:`BiophysicalConfig.prior`)."""

NOISE_MODELS = ("fit", "fixed")
"""How the albedo noise is set (:attr:`BiophysicalConfig.noise`)."""

STD_NOISE_MODELS = ("correlated", "projected", "white")
"""How the reported std treats the noise between texels (:attr:`BiophysicalConfig.std_noise`)."""


@dataclasses.dataclass
class BiophysicalConfig:
    """Settings of :func:`polarbssrdf.inverse.biophysical.fit.fit_biophysical`.

    Attributes
    ----------
    method : {"gauss_newton", "adam"}
        Step (c)'s optimizer. ``"gauss_newton"`` (default): damped
        Gauss-Newton (Levenberg-Marquardt) steps with the exact gradient of
        the loss (Dr.Jit reverse mode through the blur) and, per texel, the
        4 x 4 curvature of the unblurred model (Dr.Jit forward mode); a step
        that does not lower the loss is retried with more damping.
        ``"adam"``: ``drjit.opt.Adam`` with ``learning_rates``. The four
        parameters are strongly correlated per texel (melanin and hemoglobin
        both absorb in the blue), which a diagonal optimizer crosses slowly:
        Adam needs hundreds of steps where Gauss-Newton needs about ten
        (docs/biophysical.md).
    iterations : int
        Steps per round of (c) (Gauss-Newton: at most this many accepted or
        rejected trials; it stops earlier once a step lowers the loss by less
        than ``tolerance`` of it).
    tolerance : float
        Relative loss decrease below which Gauss-Newton stops.
    rounds : int
        Maximum rounds of (b)-(c); the fit stops earlier once the kernels change
        by less than ``kernel_tolerance`` (largest absolute change of a
        normalized SoG weight).
    learning_rates : dict
        First step size per map; decayed geometrically to ``final_lr_fraction``.
    prior : {"matern", "none"}
        ``"matern"`` (default): each chromophore map is a Matérn field around a
        face mean with spread ``prior_std`` and correlation length
        ``correlation_mm``, the face mean a Gaussian around ``prior_mean``
        (:mod:`polarbssrdf.inverse.biophysical.prior`); the posterior standard
        deviation of every map is written beside it. ``"none"``: the data term
        and ``smoothness`` only (the fit before issue 20; its std channels then
        hold the data term's own, per texel).
    prior_std : dict
        ``name -> std`` of a chromophore within one face (volume fractions);
        default the mean of Table 2's within-region "(std)" over its rows. The
        start, when ``spread`` is ``"fit"``.
    spread : {"fit", "fixed"}
        ``"fit"`` (default): after every round each chromophore's spread is
        re-estimated from its posterior (expectation-maximization), so a face
        that varies more than Table 2's regions is not flattened; where the
        bands cannot tell a map, its spread stays about where it started.
        ``"fixed"`` keeps ``prior_std``.
    prior_mean : dict
        ``name -> [mean, std]`` of the face mean's hyperprior; default the mean
        and spread of Table 2's eight rows. A std of 0 holds the face mean there.
    correlation_mm : float or "fit"
        Correlation length of the Matérn fields (mm). ``"fit"`` (default):
        estimated from the input albedo's covariance between texels two and
        more texels apart (:func:`~polarbssrdf.inverse.biophysical.correlation.albedo_correlation_length`;
        the result's metadata ``correlation_length`` gives it). On synthetic faces
        whose fields are Gaussian-filtered over 8 mm it finds 6.4-6.7 mm at 128^2,
        7.8-8.2 mm at 256^2 and 11.3 mm at 512^2 (the Gaussian's shape is not a
        Matérn's); on the demo's capture 8.4 mm. A number fixes it (the fit before 2026-12-02 used 5).
    prior_order : {1, 2}
        The Matérn fields' ``alpha`` (:class:`~polarbssrdf.inverse.biophysical.prior.SpatialPrior`):
        2 (default) is smooth at the texel scale and pools the data of a few
        correlation lengths; 1 is rougher and pools over a few texels only.
    face_means : {"blocks", "joint"}
        How each chromophore's face mean is found. ``"blocks"`` (default): the
        albedo is averaged over blocks of ``mean_block_mm`` and inverted per
        block (eq. 47), the blocks' mean combined with the ``prior_mean``
        hyperprior and held during the fit (:func:`~polarbssrdf.inverse.biophysical.fit.block_face_means`).
        ``"joint"``: the means are fitted with the maps; noise turned into bias
        along the melanin-eumelanin ridge that way (bench/RESULTS.md).
    hold_uninformed : bool
        Hold a chromophore at its face mean when the bands tell less about it
        than the prior does, even pooled over one correlation area
        (:func:`~polarbssrdf.inverse.biophysical.fit.prior_dominated_maps`;
        default ``true``); its std is then the prior spread.
    mean_block_mm : float
        Block size (mm) of ``face_means: "blocks"``.
    gain_std : float
        Spread of ``albedo_gain``, a band-common multiplicative error of the
        input albedo fitted as a nuisance map (Matérn, mean 1, the same
        correlation length); 0 (default) leaves it out. With six bands a gain
        is nearly confounded with melanin and blood together: on the demo face
        the fitted gain spread to 0.72-1.11 (5-95%) with the errors of C_m,
        C_h_out and C_h_in 0.94, 0.91 and 0.81 correlated with it, and on
        synthetic faces it doubled C_m's error (bench/RESULTS.md, 2026-12-02);
        the band-common part of the error is modelled as noise
        (``common_noise``) instead.
    noise : {"fit", "fixed"}
        ``"fit"`` (default): each band's own relative noise and the
        band-common noise start at ``albedo_noise`` and ``common_noise`` and
        are re-estimated after every round from the residuals (moments over the
        degrees of freedom the posterior leaves), so the uncertainty is
        calibrated on the data; ``"fixed"`` keeps the starts.
    std_noise : {"projected", "correlated", "white"}
        ``"projected"`` (default): the ``<map>_std`` channels account for the
        noise's correlation between neighbouring texels (offsets up to 3
        texels) by a sandwich covariance
        (:func:`~polarbssrdf.inverse.biophysical.prior.posterior_covariance`),
        the correlation measured on the whitened residuals projected per texel
        on the band directions no map can move
        (:func:`~polarbssrdf.inverse.biophysical.fit.residual_correlation`): the
        maps absorb the smooth part of the noise along their own directions, so
        the plain residuals understate its correlation (on the demo 0.15 between
        neighbours, where the albedo error's is 0.43). ``"correlated"``: the
        plain residuals' correlation. ``"white"`` takes the noise as
        independent between texels.
    smoothness : float or dict
        Weight of an extra smoothness penalty per map (one number for all, or
        ``name -> weight``): the mean over neighbouring texel pairs of the
        squared slope of the map, in bounds ranges per mm, against the data
        term. 0 by default (the Matérn prior smooths); ``prior="none"`` with
        ``smoothness=300`` is the fit before issue 20.
    albedo_noise : float
        Relative noise of the albedo maps per band, independent between bands (the
        start when ``noise`` is ``"fit"``).
    common_noise : float
        Relative noise shared by every band of a texel (the start when ``noise``
        is ``"fit"``; 0 with ``"fixed"`` leaves it out): an error of the albedo's
        level, such as the static stage's refractive index error makes
        (d ln albedo / d eta = -1.24, flat over bands), which the chromophores
        would otherwise take for a change of colour.
    start_texel_mm : float
        Block size (mm) of the start's per-texel inversion (a); 0 inverts at full resolution.
    bounds : dict
        Physical box of each map (those of the per-texel inversion by default).
    thickness_mm, eta : float
        Epidermis thickness; refractive index where the input has no ``eta`` map.
    """

    method: str = "gauss_newton"
    iterations: int = 12
    tolerance: float = 1e-4
    rounds: int = 3
    kernel_tolerance: float = 0.02
    learning_rates: dict = dataclasses.field(default_factory=lambda: dict(LEARNING_RATES))
    final_lr_fraction: float = 0.05
    prior: str = "matern"
    prior_std: dict = dataclasses.field(default_factory=within_face_spread)
    prior_mean: dict = dataclasses.field(default_factory=lambda: {n: list(v) for n, v in population_prior().items()})
    correlation_mm: float | str = "fit"
    prior_order: int = 2
    gain_std: float = 0.0
    face_means: str = "blocks"
    hold_uninformed: bool = True
    mean_block_mm: float = 16.0
    noise: str = "fit"
    std_noise: str = "projected"
    spread: str = "fit"
    smoothness: object = 0.0
    albedo_noise: float = 0.01
    common_noise: float = 0.01
    start_texel_mm: float = 2.0
    bounds: dict = dataclasses.field(default_factory=lambda: dict(INVERSION_BOUNDS))
    thickness_mm: float = 0.25
    eta: float = 1.4

    def smoothness_weights(self):
        """``name -> weight`` of the smoothness prior (see ``smoothness``)."""
        value = self.smoothness
        weights = ({n: value for n in PARAMETERS} if not isinstance(value, dict)
                   else {n: value.get(n, 0.0) for n in PARAMETERS})
        if isinstance(value, dict):
            unknown = sorted(set(value) - set(PARAMETERS))
            if unknown:
                raise ValueError(f"smoothness: unknown map(s) {unknown}; known: {list(PARAMETERS)}")
        for name, weight in weights.items():
            where = f"smoothness.{name}" if isinstance(value, dict) else "smoothness"
            check_number(weight, where, minimum=0)
        return {n: float(w) for n, w in weights.items()}

    def _check_prior_tables(self):
        for key in ("prior_std", "prior_mean"):
            value = getattr(self, key)
            if not isinstance(value, dict):
                raise ValueError(f"{key} must be an object, got {json_type(value)}")
            unknown = sorted(set(value) - set(PARAMETERS))
            if unknown:
                raise ValueError(f"{key}: unknown map(s) {unknown}; known: {list(PARAMETERS)}")
        spread = within_face_spread()
        hyper = population_prior()
        for name, value in self.prior_std.items():
            check_number(value, f"prior_std.{name}")
            if not value > 0:
                raise ValueError(f"prior_std.{name} must be > 0, got {value!r}")
        for name, pair in self.prior_mean.items():
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ValueError(f"prior_mean.{name} must be [mean, std], got {json_type(pair)}")
            check_number(pair[0], f"prior_mean.{name}[0]")
            check_number(pair[1], f"prior_mean.{name}[1]", minimum=0)
        self.prior_std = {**spread, **{k: float(v) for k, v in self.prior_std.items()}}
        self.prior_mean = {**{k: list(v) for k, v in hyper.items()},
                           **{k: [float(v[0]), float(v[1])] for k, v in self.prior_mean.items()}}

    def __post_init__(self):
        # JSON types first (errors name the key and the type found): a string or a
        # boolean where a number belongs would otherwise pass or fail far from here
        for name in ("iterations", "rounds"):
            check_integer(getattr(self, name), name, minimum=1 if name == "rounds" else 0)
        check_string(self.method, "method", METHODS)
        check_string(self.prior, "prior", PRIORS)
        check_string(self.noise, "noise", NOISE_MODELS)
        check_string(self.spread, "spread", NOISE_MODELS)
        check_string(self.std_noise, "std_noise", STD_NOISE_MODELS)
        check_string(self.face_means, "face_means", ("blocks", "joint"))
        check_boolean(self.hold_uninformed, "hold_uninformed")
        check_number(self.mean_block_mm, "mean_block_mm")
        if not self.mean_block_mm > 0:
            raise ValueError(f"mean_block_mm must be > 0 (mm), got {self.mean_block_mm!r}")
        if self.correlation_mm != "fit":
            if isinstance(self.correlation_mm, str):
                raise ValueError(f"correlation_mm must be \"fit\" or a length in mm, got {self.correlation_mm!r}")
            check_number(self.correlation_mm, "correlation_mm")
            if not self.correlation_mm > 0:
                raise ValueError(f"correlation_mm must be > 0 (mm) or \"fit\", got {self.correlation_mm!r}")
        check_integer(self.prior_order, "prior_order", minimum=1)
        if self.prior_order > 2:
            raise ValueError(f"prior_order must be 1 or 2, got {self.prior_order!r}")
        check_number(self.gain_std, "gain_std", minimum=0)
        if not self.gain_std < 1:
            raise ValueError(f"gain_std must be in [0, 1), got {self.gain_std!r}")
        self._check_prior_tables()
        self.smoothness_weights()  # validates
        for name in ("kernel_tolerance", "albedo_noise", "start_texel_mm", "common_noise"):
            check_number(getattr(self, name), name, minimum=0)
        check_number(self.tolerance, "tolerance", minimum=0)
        if not self.tolerance < 1:
            raise ValueError(f"tolerance must be in [0, 1), got {self.tolerance!r}")
        if not self.albedo_noise > 0:
            raise ValueError("albedo_noise must be > 0")
        check_number(self.final_lr_fraction, "final_lr_fraction", maximum=1)
        if not 0 < self.final_lr_fraction:
            raise ValueError("final_lr_fraction must be in (0, 1]")
        for key in ("learning_rates", "bounds"):
            if not isinstance(getattr(self, key), dict):
                raise ValueError(f"{key} must be an object, got {json_type(getattr(self, key))}")
        for name in set(self.learning_rates) | set(self.bounds):
            if name not in PARAMETERS:
                raise ValueError(f"unknown map {name!r}; known: {list(PARAMETERS)}")
        for name, value in self.learning_rates.items():
            check_number(value, f"learning_rates.{name}")
            if not value > 0:
                raise ValueError(f"learning rate of {name} must be > 0, got {value!r}")
        for name, pair in self.bounds.items():
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ValueError(f"bounds.{name} must be [low, high], got {json_type(pair)}")
            for value in pair:
                check_number(value, f"bounds.{name}")
        self.learning_rates = {**LEARNING_RATES, **self.learning_rates}
        self.bounds = {**INVERSION_BOUNDS, **{k: tuple(v) for k, v in self.bounds.items()}}
        for name, (low, high) in self.bounds.items():
            if not (0.0 <= low < high <= 1.0):
                raise ValueError(f"bounds of {name} must satisfy 0 <= low < high <= 1, got {(low, high)}")
        check_number(self.thickness_mm, "thickness_mm")
        if not self.thickness_mm > 0:
            raise ValueError("thickness_mm must be > 0")
        check_number(self.eta, "eta")
        if not self.eta > 1:
            raise ValueError("eta must be > 1")


def bio_config(settings):
    """:class:`BiophysicalConfig` from a config's ``bio`` object (keys of the dataclass)."""
    settings = dict(settings or {})
    free = check_boolean(settings.pop("free_melanin", False), "free_melanin")
    known = {f.name for f in dataclasses.fields(BiophysicalConfig)}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ValueError(f"config: unknown bio key(s) {unknown}; known: "
                         f"{sorted(known | {'free_melanin'})}")
    return BiophysicalConfig(**settings), free
