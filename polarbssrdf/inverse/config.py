"""The configuration of a whole run: one JSON object for every stage, each stage checking its part.

A run is configured by a :class:`~polarbssrdf.inverse.polarimetric.config.StaticConfig`:
its own fields set the static stage, its ``dynamic`` object the dynamic stage
(both checked by :mod:`polarbssrdf.inverse.polarimetric.config`), its ``bio``
object the biophysical stage (checked by
:func:`polarbssrdf.inverse.biophysical.config.bio_config`). This module sits
above both stages so that neither imports the other's settings; ``reconstruct
--config FILE.json`` and :func:`polarbssrdf.inverse.reconstruct` read configs
through it. See docs/reconstruct.md for every key.
"""

from __future__ import annotations

from polarbssrdf.inverse.biophysical.config import bio_config
from polarbssrdf.inverse.polarimetric.config import StaticConfig, merged_config
from polarbssrdf.io.jsonfile import read_json_file

DEFAULT_TEXTURE = 512
"""Texture size of a run when none is given and the capture has no ground truth."""


def check_bio_settings(settings) -> None:
    """Raise :class:`ValueError` (naming the key) unless ``settings`` is a valid ``bio`` object."""
    try:
        bio_config(settings)
    except (TypeError, ValueError) as error:
        # the stage's own message may start with "config: " too: say it once
        raise ValueError(f"config: bio: {str(error).removeprefix('config: ')}") from None


def static_config(overrides=None, **changes) -> StaticConfig:
    """A run's :class:`StaticConfig` from defaults, a JSON-like ``overrides`` dict and keyword
    changes, every stage's part checked (errors name the key)."""
    config = merged_config(overrides, **changes)
    check_bio_settings(config.bio)
    return config


def load_static_config(path, **changes) -> StaticConfig:
    """:func:`static_config` from a JSON file (errors name the file)."""
    data = read_json_file(path, "config file")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the config must be a JSON object")
    try:
        return static_config(data, **changes)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def run_config(config=None, iterations=None) -> StaticConfig:
    """The config of a run from what a user passes.

    ``config``: None (the paper's settings), a :class:`StaticConfig`, a dict of
    overrides, or the path of a JSON file. ``iterations`` (the command's
    ``--iterations``) sets the epochs of the static stage and, unless the config
    sets ``dynamic.iterations``, of every dynamic frame.
    """
    changes = {} if iterations is None else {"iterations": iterations}
    if config is None or isinstance(config, dict):
        result = static_config(config, **changes)
    elif isinstance(config, StaticConfig):
        result = static_config(config.to_json(), **changes)
    else:
        result = load_static_config(config, **changes)
    if iterations is not None and "iterations" not in result.dynamic:
        result.dynamic = {**result.dynamic, "iterations": iterations}
    return result
