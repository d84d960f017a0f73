"""Reading JSON files with errors that name the file, and the line and column when malformed;
checking the type of a decoded value (``check_boolean``, ``check_integer``, ...) with errors
that name the key and the JSON type found."""

from __future__ import annotations

import json
import math
from pathlib import Path


def read_json_file(path, what="file"):
    """Decode the JSON file ``path``.

    Raises ``FileNotFoundError`` ("<what> not found: <path>") or ``ValueError``
    ("<path>: not valid JSON (<reason> at line L, column C)").
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error.msg} at line {error.lineno}, "
                         f"column {error.colno})") from None


def json_type(value) -> str:
    """The JSON type of a decoded value, as a user reads it: ``a string ("false")``,
    ``a number (2.5)``, ``a boolean (true)``, ``null``, ``an object``, ``an array``."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"a boolean ({json.dumps(value)})"
    if isinstance(value, int):
        return f"an integer ({value})"
    if isinstance(value, float):
        return f"a number ({value!r})"
    if isinstance(value, str):
        text = json.dumps(value)
        return f"a string ({text if len(text) <= 40 else text[:37] + '...'})"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, (list, tuple)):
        return "an array"
    return f"a {type(value).__name__}"


def check_boolean(value, name: str) -> bool:
    """``value`` if it is a JSON boolean, else a ``ValueError`` naming ``name`` and the type.

    Python's ``bool("false")`` is ``True``: a config flag given as a string must
    be refused, not read as on.
    """
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false (a JSON boolean), got {json_type(value)}")
    return value


def check_integer(value, name: str, minimum: int | None = None) -> int:
    """``value`` if it is a JSON integer (not a boolean, not ``2.0``) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or (
            minimum is not None and value < minimum):
        bound = "" if minimum is None else f" >= {minimum}"
        raise ValueError(f"{name} must be an integer{bound}, got {json_type(value)}")
    return value


def check_number(value, name: str, minimum=None, maximum=None) -> float:
    """``value`` if it is a finite JSON number (an integer or not; not a boolean) in range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {json_type(value)}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value!r}")
    return value


def check_string(value, name: str, choices=None) -> str:
    """``value`` if it is a JSON string (one of ``choices`` when given)."""
    if not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {json_type(value)}")
    if choices is not None and value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def check_object_keys(value, where: str, noun: str, known, required=()) -> None:
    """``ValueError`` naming ``where`` unless ``value`` is a dict (a JSON object, called
    ``noun`` in the message) whose keys are among ``known`` and include ``required``."""
    if not isinstance(value, dict):
        raise ValueError(f"{where}: {noun} must be an object with keys {sorted(known)}")
    unknown = sorted(set(value) - set(known))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
    for key in required:
        if key not in value:
            raise ValueError(f"{where}: missing key {key!r}")
