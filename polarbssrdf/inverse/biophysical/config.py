"""Settings of the biophysical stage (supplement sec. 5.3): :class:`BiophysicalConfig`.

A run's config file carries them in its ``bio`` object (any field of
:class:`BiophysicalConfig`, plus ``free_melanin``), read by :func:`bio_config`;
unknown keys, values of the wrong JSON type (``"false"`` for a flag, ``12.0``
for an integer) and out-of-range values are errors that name the key.
"""

from __future__ import annotations

import dataclasses

from polarbssrdf.inverse.biophysical.model import PARAMETERS
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
    smoothness : float or dict
        Weight of the smoothness prior per map (one number for all, or
        ``name -> weight``): the mean over neighbouring texel pairs of the
        squared slope of the map, in bounds ranges per mm (so the same weight
        means the same at any texture size), against the data term (mean
        squared relative residual over ``albedo_noise``).
    albedo_noise : float
        Expected relative noise of the albedo maps (scales the data term).
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
    smoothness: object = 300.0
    albedo_noise: float = 0.01
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

    def __post_init__(self):
        # JSON types first (errors name the key and the type found): a string or a
        # boolean where a number belongs would otherwise pass or fail far from here
        for name in ("iterations", "rounds"):
            check_integer(getattr(self, name), name, minimum=1 if name == "rounds" else 0)
        check_string(self.method, "method", METHODS)
        self.smoothness_weights()  # validates
        for name in ("kernel_tolerance", "albedo_noise", "start_texel_mm"):
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
