"""Biophysical skin parameters (Donner et al. 2008 two-layer form) and the
paper's Table 2 estimates (supplement section 7)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .chromophores import DEFAULT_REFRACTIVE_INDEX


@dataclass(frozen=True)
class SkinParameters:
    """One skin: epidermis (outer layer) over a semi-infinite dermis (inner).

    C_m       melanin volume fraction of the epidermis, [0, 1]
    beta_m    eumelanin fraction of that melanin, [0, 1]
    C_h_out   hemoglobin (blood) fraction of the epidermis, [0, 1]
    C_h_in    hemoglobin (blood) fraction of the dermis, [0, 1]
    gamma     oxygenated fraction of the hemoglobin, [0, 1] (default 0.75)
    thickness_mm   epidermis thickness in mm (> 0, default 0.25)
    eta       refractive index of both layers (> 0, default 1.4)

    Melanin lives in the epidermis (supplement Table 3 says inner layer; that
    is an erratum, see DESIGN.md). Also C_m + C_h_out <= 1 (volume fractions
    of one layer). Violations raise ``ValueError`` naming the field.
    """

    C_m: float
    beta_m: float
    C_h_out: float
    C_h_in: float
    gamma: float = 0.75
    thickness_mm: float = 0.25
    eta: float = DEFAULT_REFRACTIVE_INDEX

    def __post_init__(self) -> None:
        for name in ("C_m", "beta_m", "C_h_out", "C_h_in", "gamma"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a fraction in [0, 1], got {value!r}")
        if self.C_m + self.C_h_out > 1.0:
            raise ValueError(f"C_m + C_h_out must be <= 1 (epidermis volume fractions), got {self.C_m + self.C_h_out!r}")
        if not (self.thickness_mm > 0):
            raise ValueError(f"thickness_mm must be > 0, got {self.thickness_mm!r}")
        if not (math.isfinite(self.eta) and self.eta > 0):
            raise ValueError(f"eta must be a finite number > 0, got {self.eta!r}")

    def as_dict(self) -> dict:
        return asdict(self)


#: Table 2 means: (region, skin type) -> SkinParameters. Table 2 "He. (inner)"
#: is C_h_in, "He. (outer)" C_h_out, "Melanin" C_m, "Rel. eumel." beta_m,
#: "Refrac. idx" eta.
TABLE2: dict[tuple[str, str], SkinParameters] = {
    ("forehead", "I"): SkinParameters(C_m=0.03243, beta_m=0.09607, C_h_out=0.01701, C_h_in=0.03691, eta=1.44248),
    ("forehead", "II"): SkinParameters(C_m=0.05036, beta_m=0.04759, C_h_out=0.08323, C_h_in=0.02072, eta=1.41736),
    ("forehead", "III"): SkinParameters(C_m=0.06155, beta_m=0.05304, C_h_out=0.07337, C_h_in=0.03622, eta=1.39902),
    ("forehead", "IV"): SkinParameters(C_m=0.08909, beta_m=0.05291, C_h_out=0.10450, C_h_in=0.02654, eta=1.41017),
    ("cheek", "I"): SkinParameters(C_m=0.02891, beta_m=0.07224, C_h_out=0.04337, C_h_in=0.02672, eta=1.41323),
    ("cheek", "II"): SkinParameters(C_m=0.04335, beta_m=0.03684, C_h_out=0.05639, C_h_in=0.01722, eta=1.42730),
    ("cheek", "III"): SkinParameters(C_m=0.03993, beta_m=0.02355, C_h_out=0.09753, C_h_in=0.05753, eta=1.41453),
    ("cheek", "IV"): SkinParameters(C_m=0.07982, beta_m=0.05559, C_h_out=0.09513, C_h_in=0.02135, eta=1.42888),
}


#: Table 2's "(std)" values: (region, skin type) -> name -> standard deviation of that
#: parameter over the measured region of the subject (same units as the means).
TABLE2_STD: dict[tuple[str, str], dict[str, float]] = {
    ("forehead", "I"): {"C_m": 0.00183, "beta_m": 0.00393, "C_h_out": 0.00256, "C_h_in": 0.00563, "eta": 0.01258},
    ("forehead", "II"): {"C_m": 0.00400, "beta_m": 0.01404, "C_h_out": 0.02069, "C_h_in": 0.00792, "eta": 0.01182},
    ("forehead", "III"): {"C_m": 0.00228, "beta_m": 0.00658, "C_h_out": 0.00441, "C_h_in": 0.00903, "eta": 0.00759},
    ("forehead", "IV"): {"C_m": 0.00330, "beta_m": 0.00629, "C_h_out": 0.01002, "C_h_in": 0.00837, "eta": 0.00734},
    ("cheek", "I"): {"C_m": 0.00286, "beta_m": 0.00821, "C_h_out": 0.00637, "C_h_in": 0.00645, "eta": 0.01404},
    ("cheek", "II"): {"C_m": 0.00434, "beta_m": 0.00971, "C_h_out": 0.00652, "C_h_in": 0.00643, "eta": 0.01083},
    ("cheek", "III"): {"C_m": 0.00435, "beta_m": 0.01014, "C_h_out": 0.01057, "C_h_in": 0.00970, "eta": 0.01454},
    ("cheek", "IV"): {"C_m": 0.00686, "beta_m": 0.01228, "C_h_out": 0.01790, "C_h_in": 0.01118, "eta": 0.01116},
}


def table2_spread_across_rows() -> dict[str, float]:
    """Standard deviation (ddof 0) of each biophysical parameter over the eight Table 2 means:
    the spread between skin types and regions, 2-10x the within-row "(std)" of
    :data:`TABLE2_STD`."""
    return {name: float(np.std([getattr(p, name) for p in TABLE2.values()]))
            for name in ("C_m", "beta_m", "C_h_out", "C_h_in")}


def table2_ranges() -> dict[str, tuple[float, float]]:
    """Min and max of each biophysical parameter over the Table 2 means."""
    out = {}
    for name in ("C_m", "beta_m", "C_h_out", "C_h_in"):
        values = [getattr(p, name) for p in TABLE2.values()]
        out[name] = (min(values), max(values))
    return out
