"""Ground-truth appearance maps for synthetic captures.

Every map is a smooth random field in texture space around a base value:
white noise filtered by a Gaussian of ``correlation_mm`` (through the mean
texel size), scaled to a standard deviation and clipped to the parameter's
valid range. The biophysical maps start from a row of the supplement's
Table 2; a dynamic sequence varies the hemoglobin fractions over frames.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
from scipy.ndimage import gaussian_filter

from polarbssrdf.skin.parameters import TABLE2

# name -> (base, standard deviation, lower bound, upper bound)
DEFAULT_REFLECTANCE = {
    "eta": (1.42, 0.015, 1.3, 1.6),
    "alpha_s": (0.55, 0.03, 0.05, 1.0),
    "alpha_ss": (0.97, 0.01, 0.05, 1.0),
    "rho_s": (0.8, 0.1, 0.0, 1.0),
    "rho_ss": (0.3, 0.05, 0.0, 1.0),
    "displacement": (0.0, 0.1, -1.0, 1.0),  # mm
}
BIOPHYSICAL = ("C_m", "beta_m", "C_h_out", "C_h_in")
DEFAULT_BIOPHYSICAL_STD = {"C_m": 0.004, "beta_m": 0.01, "C_h_out": 0.01, "C_h_in": 0.008}
MAP_NAMES = tuple(DEFAULT_REFLECTANCE) + BIOPHYSICAL


@dataclasses.dataclass(frozen=True)
class TruthSettings:
    """What the synthetic face or sphere is made of.

    Attributes
    ----------
    reflectance : dict
        ``name -> (base, std, low, high)`` for eta, alpha_s, alpha_ss, rho_s,
        rho_ss and displacement (mm).
    skin : (region, type)
        Row of Table 2 for the biophysical base values, e.g. ("forehead", "II").
    biophysical_std : dict
        Standard deviation of each biophysical map (absolute fractions).
    correlation_mm : float
        Correlation length of the random fields, mm.
    hemoglobin_swing : float
        Relative peak change of C_h_out and C_h_in over a dynamic sequence.
    """

    reflectance: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_REFLECTANCE))
    skin: tuple = ("forehead", "II")
    biophysical_std: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_BIOPHYSICAL_STD))
    correlation_mm: float = 8.0
    hemoglobin_swing: float = 0.3

    def __post_init__(self):
        if tuple(self.skin) not in TABLE2:
            raise ValueError(f"skin must be one of {sorted(TABLE2)}, got {self.skin!r}")
        for name, value in self.reflectance.items():
            if name not in DEFAULT_REFLECTANCE:
                raise ValueError(f"unknown reflectance map {name!r}; known: {list(DEFAULT_REFLECTANCE)}")
            if len(value) != 4:
                raise ValueError(f"{name}: expected [base, std, low, high], got {list(value)}")
            base, std, low, high = value
            if not (low <= base <= high) or std < 0:
                raise ValueError(f"{name}: base {base} outside [{low}, {high}] or negative std")
        if set(self.biophysical_std) != set(BIOPHYSICAL):
            raise ValueError(f"biophysical_std must give {list(BIOPHYSICAL)}, got "
                             f"{sorted(self.biophysical_std)}")
        if any(std < 0 for std in self.biophysical_std.values()):
            raise ValueError(f"biophysical_std must be >= 0, got {self.biophysical_std}")
        if self.correlation_mm <= 0:
            raise ValueError("correlation_mm must be > 0")


def load_settings(path):
    """Settings from a JSON file: any subset of the fields of :class:`TruthSettings`.

    ``reflectance`` and ``biophysical_std`` may give only some maps; the
    others keep their defaults. The keys are documented in ``docs/synth.md``.
    """
    from polarbssrdf.io.jsonfile import read_json_file

    path = pathlib.Path(path)
    data = read_json_file(path, "parameter file")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: settings must be a JSON object")
    unknown = set(data) - {f.name for f in dataclasses.fields(TruthSettings)}
    if unknown:
        raise ValueError(f"{path}: unknown settings {sorted(unknown)}")
    if "reflectance" in data:
        data["reflectance"] = {**DEFAULT_REFLECTANCE,
                               **{k: tuple(v) for k, v in data["reflectance"].items()}}
    if "biophysical_std" in data:
        unknown = set(data["biophysical_std"]) - set(BIOPHYSICAL)
        if unknown:
            raise ValueError(f"{path}: unknown biophysical maps {sorted(unknown)}; known: "
                             f"{list(BIOPHYSICAL)}")
        data["biophysical_std"] = {**DEFAULT_BIOPHYSICAL_STD, **data["biophysical_std"]}
    if "skin" in data:
        data["skin"] = tuple(data["skin"])
    return TruthSettings(**data)


def smooth_field(shape, correlation_texels, rng):
    """Unit-variance smooth random field (Gaussian-filtered white noise)."""
    field = gaussian_filter(rng.standard_normal(shape), correlation_texels, mode="wrap")
    return field / max(field.std(), 1e-12)


def truth_maps(atlas, settings, rng):
    """The static maps (T x T float32) of every parameter in :data:`MAP_NAMES`."""
    texel_mm = float(np.median(atlas.texel_size_mm[atlas.valid]))
    correlation = settings.correlation_mm / texel_mm
    shape = atlas.valid.shape
    maps = {}
    for name, (base, std, low, high) in settings.reflectance.items():
        field = np.clip(base + std * smooth_field(shape, correlation, rng), low, high)
        # texels off the surface keep the base value: valid, and never seen
        maps[name] = np.where(atlas.valid, field, base)
    skin = TABLE2[tuple(settings.skin)]
    for name in BIOPHYSICAL:
        base = getattr(skin, name)
        std = settings.biophysical_std[name]
        field = np.clip(base + std * smooth_field(shape, correlation, rng), 0.0, 1.0)
        maps[name] = np.where(atlas.valid, field, base)
    return {name: value.astype(np.float32) for name, value in maps.items()}


def frame_maps(static, frame, n_frames, settings, flush_region=None):
    """Maps of ``frame``: hemoglobin rises over the sequence (a flush), peaking at the last frame.

    ``C_h = C_h(frame 0) (1 + swing sin(pi/2 frame / (n_frames - 1)) flush)``.

    Parameters
    ----------
    static : dict
        Maps of frame 0 (:func:`truth_maps`).
    flush_region : (T, T) float array, optional
        Where the skin flushes (weight in [0, 1]); everywhere by default.
    """
    if n_frames <= 1 or frame == 0:
        return dict(static)
    phase = np.sin(0.5 * np.pi * frame / (n_frames - 1))
    weight = 1.0 if flush_region is None else flush_region
    factor = 1.0 + settings.hemoglobin_swing * phase * weight
    maps = dict(static)
    for name in ("C_h_out", "C_h_in"):
        maps[name] = np.clip(static[name] * factor, 0.0, 1.0).astype(np.float32)
    return maps
