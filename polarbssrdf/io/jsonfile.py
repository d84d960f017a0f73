"""Reading JSON files with errors that name the file, and the line and column when malformed."""

from __future__ import annotations

import json
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
