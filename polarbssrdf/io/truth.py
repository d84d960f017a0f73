"""Ground truth of a synthetic capture: ``truth/truth.json`` and per-frame map files.

``truth.json`` names the parameters, their units, the texture size and which
map channels exist for each frame; the maps themselves are float32 EXR files
``truth/maps_f0000.exr`` (one per frame) with one T x T channel per
parameter (``eta``, ``alpha_s``, ``displacement``, ...) or per parameter and
band (``rho_sss.<band>``). Maps follow the package texture convention: row 0
at the top, texel ``(i, j)`` at Mitsuba ``uv = ((j + 0.5) / T, (i + 0.5) / T)``.
Paths in ``truth.json`` are relative to the capture directory.
"""

from __future__ import annotations

import posixpath
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from polarbssrdf.io.manifest import (
    CaptureFormatError,
    _integer,
    _object,
    _relative_path,
    _string,
    _validated,
)

__all__ = [
    "DEFAULT_TRUTH_UNITS",
    "TEXTURE_CONVENTION",
    "TRUTH_SCHEMA",
    "TRUTH_SCHEMA_VERSION",
    "GroundTruth",
    "TruthManifest",
    "TruthMapRecord",
    "check_truth_channels",
    "truth_map_path",
]

TRUTH_SCHEMA = "polarbssrdf.capture.truth"
TRUTH_SCHEMA_VERSION = 1

DEFAULT_TRUTH_UNITS = {
    "eta": "1", "alpha_s": "1", "alpha_ss": "1", "rho_s": "1", "rho_ss": "1",
    "displacement": "mm", "C_m": "1", "beta_m": "1", "C_h_out": "1", "C_h_in": "1",
    "gamma": "1", "thickness_mm": "mm", "rho_sss": "1",
}
"""Units of the paper's parameters (``"1"``: dimensionless; fractions and albedos in [0, 1])."""

TEXTURE_CONVENTION = ("row 0 at the top; texel (i, j) at Mitsuba uv ((j + 0.5) / T, (i + 0.5) / T); "
                      "Mitsuba v = 1 - OBJ v")
"""Stored in ``truth.json`` so a reader without this package knows how to map texels."""


def truth_map_path(truth_json: str, frame_index: int) -> str:
    """Path of a frame's map file beside ``truth.json``: ``truth/maps_f0000.exr``."""
    return posixpath.join(posixpath.dirname(truth_json), f"maps_f{frame_index:04d}.exr")


def check_truth_channels(names: Iterable[str], units: Mapping[str, str],
                         band_names: Iterable[str], where: str) -> None:
    """Raise :class:`CaptureFormatError` unless every name is ``<parameter>`` or
    ``<parameter>.<band>`` with a parameter of ``units`` and a known band."""
    bands = set(band_names)
    for name in names:
        parameter, _, band = name.partition(".")
        if parameter not in units:
            raise CaptureFormatError(where, f"channel {name!r}: parameter {parameter!r} has no unit "
                                            f"(known: {', '.join(units)})")
        if band and band not in bands:
            raise CaptureFormatError(where, f"channel {name!r}: unknown band {band!r} "
                                            f"(known: {', '.join(bands)})")


@dataclass(frozen=True)
class TruthMapRecord:
    """The maps of one frame: its index, file and channel names."""

    frame: int
    path: str
    channels: tuple[str, ...]

    def __post_init__(self):
        _integer(self.frame, "frame", minimum=0)
        object.__setattr__(self, "path", _relative_path(self.path, "path", ".exr"))
        if not isinstance(self.channels, (list, tuple)) or not self.channels:
            raise CaptureFormatError("channels", "must be a non-empty list of channel names")
        for i, name in enumerate(self.channels):
            _string(name, f"channels[{i}]")
        if len(set(self.channels)) != len(self.channels):
            raise CaptureFormatError("channels", "contains duplicate names")
        object.__setattr__(self, "channels", tuple(self.channels))

    def to_json(self) -> dict:
        return {"frame": self.frame, "path": self.path, "channels": list(self.channels)}


@dataclass(frozen=True)
class TruthManifest:
    """Contents of ``truth.json``.

    Parameters
    ----------
    texture_size:
        T: every map is T x T texels.
    units:
        Parameter name -> unit (``"1"`` for dimensionless, ``"mm"``, ...).
    maps:
        One :class:`TruthMapRecord` per frame that has maps.
    metadata:
        Free-form JSON object (e.g. the settings that generated the maps).
    """

    texture_size: int
    units: dict
    maps: tuple[TruthMapRecord, ...]
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        _integer(self.texture_size, "texture_size", minimum=1)
        if not isinstance(self.units, Mapping) or not self.units:
            raise CaptureFormatError("units", "must be a non-empty object of parameter -> unit")
        for name, unit in self.units.items():
            _string(name, "units")
            if "." in name:
                raise CaptureFormatError(f"units.{name}", "parameter names must not contain '.'")
            _string(unit, f"units.{name}")
        object.__setattr__(self, "units", dict(self.units))
        object.__setattr__(self, "maps", tuple(self.maps))
        seen = set()
        for i, record in enumerate(self.maps):
            if record.frame in seen:
                raise CaptureFormatError(f"maps[{i}].frame", f"duplicate frame {record.frame}")
            seen.add(record.frame)
        if not isinstance(self.metadata, Mapping):
            raise CaptureFormatError("metadata", "must be a JSON object")

    def record(self, frame_index: int) -> TruthMapRecord:
        for record in self.maps:
            if record.frame == frame_index:
                return record
        raise KeyError(f"no ground-truth maps for frame {frame_index} (frames with maps: "
                       f"{', '.join(str(r.frame) for r in self.maps) or 'none'})")

    def to_json(self) -> dict:
        return {"schema": TRUTH_SCHEMA, "schema_version": TRUTH_SCHEMA_VERSION,
                "texture_size": self.texture_size, "texture_convention": TEXTURE_CONVENTION,
                "units": dict(self.units), "maps": [record.to_json() for record in self.maps],
                "metadata": dict(self.metadata)}

    @classmethod
    def from_json(cls, data) -> TruthManifest:
        def build():
            if not isinstance(data, Mapping):
                raise CaptureFormatError("", "must be a JSON object")
            if data.get("schema") != TRUTH_SCHEMA:
                raise CaptureFormatError("schema", f"expected {TRUTH_SCHEMA!r}, got "
                                                   f"{data.get('schema')!r}")
            version = _integer(data.get("schema_version"), "schema_version", minimum=1)
            if version > TRUTH_SCHEMA_VERSION:
                raise CaptureFormatError("schema_version", f"{version} is newer than the supported "
                                         f"version {TRUTH_SCHEMA_VERSION}; upgrade polarbssrdf")
            fields = _object(data, "", ("schema", "schema_version", "texture_size", "units", "maps"),
                             ("texture_convention", "metadata"))
            if not isinstance(fields["maps"], list):
                raise CaptureFormatError("maps", "must be a list")
            maps = tuple(_validated(lambda item=item: TruthMapRecord(
                **_object(item, "", ("frame", "path", "channels"))), f"maps[{i}]")
                for i, item in enumerate(fields["maps"]))
            return cls(fields["texture_size"], fields["units"], maps, fields.get("metadata", {}))

        return _validated(build, "")


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth to write with a capture (input of :func:`~polarbssrdf.io.write_capture`).

    Parameters
    ----------
    maps:
        Frame index -> channel name -> T x T array (see the module docstring).
    units:
        Parameter name -> unit; defaults to :data:`DEFAULT_TRUTH_UNITS`.
    metadata:
        Free-form JSON object stored in ``truth.json``.
    """

    maps: Mapping[int, Mapping[str, np.ndarray]]
    units: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_TRUTH_UNITS))
    metadata: Mapping = field(default_factory=dict)
