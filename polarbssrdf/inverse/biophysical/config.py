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
from polarbssrdf.skin.nuisances import DEFAULT_NUISANCE_MEAN, DEFAULT_NUISANCE_STD, NUISANCES
from polarbssrdf.skin.quadrature import DESIGN_BOX, SPECTRAL_METHODS

PRIORS = ("matern", "none")
"""The maps' priors (:attr:`BiophysicalConfig.prior`)."""

NOISE_MODELS = ("fit", "fixed")
"""How the albedo noise is set (:attr:`BiophysicalConfig.noise`)."""

OXYGENATION_MODES = ("fit", "held")
"""How the face's oxygenation is set (:attr:`BiophysicalConfig.oxygenation`)."""

STD_NOISE_MODELS = ("correlated", "projected", "white")
"""How the reported std treats the noise between texels (:attr:`BiophysicalConfig.std_noise`)."""


@dataclasses.dataclass
class BiophysicalConfig:
    """Settings of :func:`polarbssrdf.inverse.biophysical.fit.fit_biophysical`.

    Attributes
    ----------
    iterations : int
        Gauss-Newton steps per round at most (a step that does not lower the loss is
        retried with more damping); a round stops earlier once a step lowers the loss by
        less than ``tolerance`` of it.
    tolerance : float
        Relative loss decrease below which the last round's Gauss-Newton steps stop (the
        rounds before it stop at
        :data:`~polarbssrdf.inverse.biophysical.fit.EARLY_ROUND_TOLERANCE` if that is larger).
    rounds : int
        Rounds at most of the outer loop (kernels, the face's thickness and oxygenation,
        noise and spreads refreshed between rounds); it stops earlier once the kernels
        change by less than ``kernel_tolerance`` and no noise estimate, spread nor face
        value moves by more than 5% (of itself; of its std for the face values).
    kernel_tolerance : float
        Largest absolute change of a normalized SoG weight counted as settled.
    prior : {"matern", "none"}
        ``"matern"`` (default): each chromophore map is a Matérn field around a face mean
        with spread ``prior_std`` and correlation length ``correlation_mm``, the face means
        Gaussian around ``prior_mean`` (:mod:`polarbssrdf.inverse.biophysical.prior`); the
        posterior standard deviation of every map is written beside it. ``"none"``: the data
        term only (its std channels then hold the data term's own, per texel, and no
        nuisance is marginalized).
    prior_std : dict
        ``name -> std`` of a chromophore within one face (volume fractions); default
        the mean of Table 2's within-region "(std)" over its rows. The start, when
        ``spread`` is ``"fit"``.
    spread : {"fit", "fixed"}
        ``"fit"`` (default): after every round each chromophore's spread is
        re-estimated from its posterior (expectation-maximization), so a face that
        varies more than Table 2's regions is not flattened and one that varies less is
        not roughened; where the bands cannot tell a map, its spread stays about where
        it started and the map stays near its face mean. ``"fixed"`` keeps ``prior_std``.
    prior_mean : dict
        ``name -> [mean, std]`` of the chromophores' face means' hyperprior; default the
        mean and spread of Table 2's eight rows.
    correlation_mm : float or "fit"
        Correlation length of the Matérn fields (mm). ``"fit"`` (default): estimated
        from the input albedo's covariance between texels two and more texels apart
        (:func:`~polarbssrdf.inverse.biophysical.correlation.albedo_correlation_length`).
    prior_order : {1, 2}
        The Matérn fields' ``alpha``: 2 (default) is smooth at the texel scale.
    feature_fraction, feature_spread : float
        The spike and slab that frees the chromophore fields at local features (order 2;
        :func:`~polarbssrdf.inverse.biophysical.prior.feature_coupling`): a texel whose
        albedo departs from its surroundings, read as a departure of the maps, is a feature
        with prior probability ``feature_fraction`` (default 0.01: 25 freckles of 3 mm
        cover 0.5% of a face) that departs ``feature_spread`` (default 10) times as far as
        the typical texel. Where a texel is one, its prior is loosened (its spread widened
        ``feature_spread``-fold, its pairs cut), so a freckle keeps its melanin and a std
        that says how little the data pin it, where a Gaussian field shrank it into the
        skin around (issue 32, item 3). ``feature_fraction`` 0: the Gaussian field.
    feature_maps : list of str
        The chromophores a local feature frees (default all four: the bands alone cannot
        tell which map a small spot is, so a freckle's melanin is only as certain as the
        other maps there allow; ``["C_m"]`` frees melanin alone).
    capture_blur_mm : float or None
        Standard deviation (mm) of the capture's blur of the input maps, as one Gaussian
        (:func:`~polarbssrdf.inverse.observations.footprint.capture_blur_variance_mm2`): the
        prediction is blurred so and the std knows that detail finer than it is seen only
        through the prior. ``None`` (default): ``reconstruct`` estimates it from the
        capture's cameras; a Python call without it takes the input as sharp (0).
    nuisance_std : dict
        ``name -> std`` within a face of what the std marginalizes (:data:`NUISANCES`,
        :data:`DEFAULT_NUISANCE_STD`): the thickness (mm) and oxygenation about their face
        values, the index about the input map (an input ``eta_std`` map replaces it by its
        median; ``reconstruct`` passes none, :func:`~.stage.albedo_inputs`). 0 leaves a
        nuisance out of the std.
    nuisance_mean : dict
        ``name -> [mean, std]`` of the face's thickness (mm) and oxygenation
        (:data:`DEFAULT_NUISANCE_MEAN`): the hyperprior of the face values.
    noise : {"fit", "fixed"}
        ``"fit"`` (default): each band's own relative noise and the band-common noise
        start at ``albedo_noise`` and ``common_noise`` and are re-estimated after every
        round from the residuals; ``"fixed"`` keeps the starts.
    std_noise : {"projected", "correlated", "white"}
        How the ``<map>_std`` channels account for the noise's correlation between
        neighbouring texels (:func:`~polarbssrdf.inverse.biophysical.uncertainty.residual_correlation`):
        ``"projected"`` (default) measures it on the residuals projected on the band
        directions no map can move, ``"correlated"`` on the plain residuals, ``"white"``
        takes the noise as independent between texels.
    albedo_noise, common_noise : float
        Relative noise of the albedo per band, and shared by the bands of a texel (the
        starts when ``noise`` is ``"fit"``).
    start_texel_mm : float
        Block size (mm) of the start's per-texel inversion; 0 inverts at full resolution.
    bounds : dict
        Physical box of each chromophore map (those of the per-texel inversion by default).
    oxygenation : {"fit", "held"}
        ``"fit"`` (default): the face's oxygenation is estimated from the albedo's band
        shape before the maps are fitted
        (:func:`~polarbssrdf.inverse.biophysical.oxygenation.face_oxygenation`), with its
        std in place of ``nuisance_mean["gamma"]``'s; ``"held"`` renders at ``gamma``.
    thickness_mm, gamma, eta : float
        The face's epidermal thickness (mm) and oxygenation the model is rendered at (their
        uncertainty, ``nuisance_mean``'s std, enters the std; ``gamma`` only where
        ``oxygenation`` is ``"held"``); the index where the input has no ``eta`` map.
    spectral : {"integral", "effective"}
        The model of a band value: ``"integral"`` (default) the band integral a camera
        records, by the bands' spectral quadrature
        (:func:`~polarbssrdf.skin.quadrature.band_integral_quadrature`); ``"effective"``
        the band-effective approximation (one node per band), for measuring what it costs.
    """

    iterations: int = 12
    tolerance: float = 1e-4
    rounds: int = 6
    kernel_tolerance: float = 0.02
    prior: str = "matern"
    prior_std: dict = dataclasses.field(default_factory=within_face_spread)
    prior_mean: dict = dataclasses.field(default_factory=lambda: {n: list(v) for n, v in population_prior().items()})
    correlation_mm: float | str = "fit"
    prior_order: int = 2
    feature_fraction: float = 0.01
    feature_spread: float = 10.0
    feature_maps: list = dataclasses.field(default_factory=lambda: list(PARAMETERS))
    capture_blur_mm: float | None = None
    nuisance_std: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_NUISANCE_STD))
    nuisance_mean: dict = dataclasses.field(default_factory=lambda: {k: list(v) for k, v in DEFAULT_NUISANCE_MEAN.items()})
    noise: str = "fit"
    std_noise: str = "projected"
    spread: str = "fit"
    albedo_noise: float = 0.01
    common_noise: float = 0.01
    start_texel_mm: float = 2.0
    bounds: dict = dataclasses.field(default_factory=lambda: dict(INVERSION_BOUNDS))
    oxygenation: str = "fit"
    thickness_mm: float = 0.25
    gamma: float = 0.75
    eta: float = 1.4
    spectral: str = "integral"

    def _check_tables(self, key, names, pairs):
        value = getattr(self, key)
        if not isinstance(value, dict):
            raise ValueError(f"{key} must be an object, got {json_type(value)}")
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise ValueError(f"{key}: unknown map(s) {unknown}; known: {list(names)}")
        for name, entry in value.items():
            if pairs:
                if not isinstance(entry, (list, tuple)) or len(entry) != 2:
                    raise ValueError(f"{key}.{name} must be [mean, std], got {json_type(entry)}")
                check_number(entry[0], f"{key}.{name}[0]")
                check_number(entry[1], f"{key}.{name}[1]", minimum=0)
            else:
                check_number(entry, f"{key}.{name}", minimum=0)

    def __post_init__(self):
        # JSON types first (errors name the key and the type found): a string or a
        # boolean where a number belongs would otherwise pass or fail far from here
        for name in ("iterations", "rounds"):
            check_integer(getattr(self, name), name, minimum=1 if name == "rounds" else 0)
        check_string(self.prior, "prior", PRIORS)
        check_string(self.noise, "noise", NOISE_MODELS)
        check_string(self.spread, "spread", NOISE_MODELS)
        check_string(self.std_noise, "std_noise", STD_NOISE_MODELS)
        check_string(self.oxygenation, "oxygenation", OXYGENATION_MODES)
        check_string(self.spectral, "spectral", SPECTRAL_METHODS)
        if self.correlation_mm != "fit":
            if isinstance(self.correlation_mm, str):
                raise ValueError(f"correlation_mm must be \"fit\" or a length in mm, got {self.correlation_mm!r}")
            check_number(self.correlation_mm, "correlation_mm")
            if not self.correlation_mm > 0:
                raise ValueError(f"correlation_mm must be > 0 (mm) or \"fit\", got {self.correlation_mm!r}")
        check_integer(self.prior_order, "prior_order", minimum=1)
        if self.prior_order > 2:
            raise ValueError(f"prior_order must be 1 or 2, got {self.prior_order!r}")
        check_number(self.feature_fraction, "feature_fraction", minimum=0, maximum=0.5)
        check_number(self.feature_spread, "feature_spread", minimum=1)
        if not isinstance(self.feature_maps, (list, tuple)) or any(n not in PARAMETERS for n in self.feature_maps):
            raise ValueError(f"feature_maps must be a list of {list(PARAMETERS)}, got {self.feature_maps!r}")
        self.feature_maps = list(self.feature_maps)
        if self.capture_blur_mm is not None:
            check_number(self.capture_blur_mm, "capture_blur_mm", minimum=0)
        self._check_tables("prior_std", PARAMETERS, pairs=False)
        for name, value in self.prior_std.items():
            if not value > 0:
                raise ValueError(f"prior_std.{name} must be > 0, got {value!r}")
        self._check_tables("prior_mean", PARAMETERS, pairs=True)
        self._check_tables("nuisance_std", NUISANCES, pairs=False)
        self._check_tables("nuisance_mean", ("thickness_mm", "gamma"), pairs=True)
        self.prior_std = {**within_face_spread(), **{k: float(v) for k, v in self.prior_std.items()}}
        self.prior_mean = {**{k: list(v) for k, v in population_prior().items()},
                           **{k: [float(v[0]), float(v[1])] for k, v in self.prior_mean.items()}}
        self.nuisance_std = {**DEFAULT_NUISANCE_STD, **{k: float(v) for k, v in self.nuisance_std.items()}}
        self.nuisance_mean = {**{k: list(v) for k, v in DEFAULT_NUISANCE_MEAN.items()},
                              **{k: [float(v[0]), float(v[1])] for k, v in self.nuisance_mean.items()}}
        for name in ("kernel_tolerance", "albedo_noise", "start_texel_mm", "common_noise"):
            check_number(getattr(self, name), name, minimum=0)
        check_number(self.tolerance, "tolerance", minimum=0)
        if not self.tolerance < 1:
            raise ValueError(f"tolerance must be in [0, 1), got {self.tolerance!r}")
        if not self.albedo_noise > 0:
            raise ValueError("albedo_noise must be > 0")
        if not isinstance(self.bounds, dict):
            raise ValueError(f"bounds must be an object, got {json_type(self.bounds)}")
        for name, pair in self.bounds.items():
            if name not in PARAMETERS:
                raise ValueError(f"bounds: unknown map {name!r}; known: {list(PARAMETERS)}")
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ValueError(f"bounds.{name} must be [low, high], got {json_type(pair)}")
            for value in pair:
                check_number(value, f"bounds.{name}")
        self.bounds = {**INVERSION_BOUNDS, **{k: tuple(v) for k, v in self.bounds.items()}}
        for name, (low, high) in self.bounds.items():
            if not (0.0 <= low < high <= 1.0):
                raise ValueError(f"bounds of {name} must satisfy 0 <= low < high <= 1, got {(low, high)}")
        for name in ("thickness_mm", "gamma"):
            check_number(getattr(self, name), name)
            low, high = DESIGN_BOX[name]
            if not low <= getattr(self, name) <= high:
                raise ValueError(f"{name} must be in [{low}, {high}] (the spectral quadrature's range), "
                                 f"got {getattr(self, name)!r}")
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
