"""What ``synth`` checks in a ``--params`` file before it writes or renders anything.

:func:`polarbssrdf.synth.truth.load_settings` checks the file's structure;
this module adds, first, the checks whose messages must name the file and the
key: every ``[base, std, low, high]`` is a list of four numbers (a string
such as ``"1.4"`` is not split into characters), a negative spread is named
as such (not blamed on the base), a biophysical spread is one a volume
fraction can have; and, once the file is read, that the maps the
``pbssrdf`` plugin receives stay inside the ranges the plugin accepts. The
maps are clipped to ``[low, high]``, so both bounds must lie in the plugin's
range (:data:`polarbssrdf.plugins.pbssrdf.PARAMETERS`, the plugin's own
check): otherwise the plugin refuses them inside Mitsuba, after the capture
directory was started.
"""

from __future__ import annotations

from pathlib import Path

from polarbssrdf.io.jsonfile import json_type, read_json_file

MAP_FIELDS = ("reflectance", "biophysical")
"""Settings whose entries are ``name -> [base, std, low, high]``."""

LARGEST_FRACTION_STD = 0.5
"""No quantity in [0, 1] spreads more than this (half its values at 0, half at 1)."""


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_map_entry(value, where: str) -> None:
    """``ValueError`` naming ``where`` unless ``value`` is ``[base, std, low, high]`` with
    ``std >= 0`` and ``low <= base <= high``; each fault is named as what it is."""
    if not isinstance(value, list) or len(value) != 4 or not all(map(_is_number, value)):
        got = json_type(value) if not isinstance(value, list) else f"{value!r}"
        raise ValueError(f"{where}: expected a list of four numbers [base, std, low, high], "
                         f"got {got}")
    base, std, low, high = value
    if std < 0:
        raise ValueError(f"{where}: the std (second number) must be >= 0, got {std}")
    if low > high:
        raise ValueError(f"{where}: low {low} is above high {high}")
    if not low <= base <= high:
        raise ValueError(f"{where}: base {base} is outside [low, high] = [{low}, {high}]")


def check_biophysical_std(value, where: str) -> None:
    """``ValueError`` naming ``where`` unless ``value`` is a spread a volume fraction can have."""
    if not _is_number(value):
        raise ValueError(f"{where}: expected a number, got {json_type(value)}")
    if not 0 <= value <= LARGEST_FRACTION_STD:
        raise ValueError(f"{where}: must be in [0, {LARGEST_FRACTION_STD}] (a volume fraction "
                         f"in [0, 1] cannot spread more), got {value}")


def check_params_data(data, path) -> None:
    """The per-entry checks of a decoded ``--params`` file (``ValueError``, ``path: key: ...``)."""
    if not isinstance(data, dict):
        return  # load_settings says what the file must be
    for field in MAP_FIELDS:
        maps = data.get(field)
        if isinstance(maps, dict):
            for name, value in maps.items():
                check_map_entry(value, f"{path}: {field}.{name}")
    spreads = data.get("biophysical_std")
    if isinstance(spreads, dict):
        for name, value in spreads.items():
            check_biophysical_std(value, f"{path}: biophysical_std.{name}")


def check_plugin_ranges(truth_settings, where: str) -> None:
    """``ValueError`` naming ``where`` and the key when a reflectance map's ``[low, high]``
    leaves the range the ``pbssrdf`` plugin accepts for it."""
    from polarbssrdf.plugins.pbssrdf import PARAMETERS  # the plugin's own ranges

    for name, (base, _, low, high) in truth_settings.reflectance.items():
        parameter = PARAMETERS.get(name)
        if parameter is None:  # e.g. the displacement moves the mesh, not the plugin
            continue
        for label, bound in (("base", base), ("low", low), ("high", high)):
            try:
                parameter.check(name, [bound])
            except ValueError:
                raise ValueError(f"{where}: reflectance.{name}: {label} {bound:g} is outside "
                                 f"{parameter.describe_range()}, the range the pbssrdf plugin "
                                 f"accepts for {name}; the map is clipped to [low, high], so "
                                 "both must lie in it") from None


def load_checked_settings(path):
    """:func:`~polarbssrdf.synth.truth.load_settings` of ``path`` after this module's checks;
    every error is one line naming the file and the key."""
    from polarbssrdf.synth.truth import load_settings

    path = Path(path)
    check_params_data(read_json_file(path, "parameter file"), path)
    settings = load_settings(path)
    check_plugin_ranges(settings, str(path))
    return settings
