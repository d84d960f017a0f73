"""Float32 OpenEXR images with named channels and JSON metadata.

Channels are H x W arrays stored as 32-bit float under the names given
(``S0``, ``I90``, ``S0.R``, ...), losslessly (ZIP), so values round-trip
bit-exactly. Metadata is a JSON object kept in one string attribute of the
EXR header (:data:`METADATA_ATTRIBUTE`) together with a schema version and
the channel order. Files are written atomically (temporary file + rename)
and an existing file is only replaced on request.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import json
import os
import sys
import tempfile
import threading
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from polarbssrdf.io.atomic import atomic_write

__all__ = [
    "EXR_METADATA_SCHEMA_VERSION",
    "METADATA_ATTRIBUTE",
    "read_exr",
    "validate_channels",
    "write_exr",
]

METADATA_ATTRIBUTE = "polarbssrdf.metadata"
"""Name of the EXR header string attribute that holds the JSON metadata."""

EXR_METADATA_SCHEMA_VERSION = 1
"""Version of the JSON layout in :data:`METADATA_ATTRIBUTE`:
``{"schema_version": 1, "channels": [names in write order], "metadata": {...}}``."""

_EXR_MAGIC = b"\x76\x2f\x31\x01"

_CAPTURE_LOCK = threading.Lock()


def _as_float32(name: str, array) -> np.ndarray:
    """``array`` as a C-contiguous float32 NumPy array, or a clear error."""
    try:
        values = np.asarray(array)
    except Exception as error:  # e.g. a Dr.Jit array that cannot convert
        raise TypeError(f"channel '{name}': cannot convert {type(array).__name__} "
                        f"to a NumPy array ({error})") from error
    if values.dtype == object or not (np.issubdtype(values.dtype, np.floating)
                                      or np.issubdtype(values.dtype, np.integer)):
        raise TypeError(f"channel '{name}' has dtype {values.dtype}; expected real numbers")
    with np.errstate(over="ignore"):  # overflow is reported by _check_finite
        return np.ascontiguousarray(values, dtype=np.float32)


def _check_finite(name: str, original, values: np.ndarray) -> None:
    """Raise if ``values`` holds NaN/inf, saying where and whether it is a float32 overflow."""
    finite = np.isfinite(values)
    if finite.all():
        return
    row, column = (int(i) for i in np.argwhere(~finite)[0])
    n_nan = int(np.isnan(values).sum())
    n_inf = int(np.isinf(values).sum())
    source = np.asarray(original)
    if np.issubdtype(source.dtype, np.floating) and np.isfinite(source).all():
        raise ValueError(f"channel '{name}' has values outside the float32 range "
                         f"(first at row {row}, column {column}: {float(source[row, column]):g})")
    raise ValueError(f"channel '{name}' contains {n_nan} NaN and {n_inf} infinite value(s) "
                     f"(first at row {row}, column {column}); pass allow_nonfinite=True "
                     "to store them anyway")


def validate_channels(channels: Mapping[str, np.ndarray], allow_nonfinite: bool = False
                      ) -> dict[str, np.ndarray]:
    """Check image channels and convert them to C-contiguous float32 arrays.

    Parameters
    ----------
    channels:
        Mapping from channel name (a non-empty string, e.g. ``"S0"`` or
        ``"S0.R"``) to an H x W array of real numbers. All channels must
        have the same shape.
    allow_nonfinite:
        Accept NaN and infinite values (rejected by default).

    Returns
    -------
    dict
        Channel name -> float32 H x W array, in the given order.

    Raises
    ------
    TypeError, ValueError
        Naming the offending channel: wrong type, not 2-D, empty, shape
        different from the first channel, non-finite values.
    """
    if not isinstance(channels, Mapping):
        raise TypeError(f"channels must be a dict of name -> H x W array, "
                        f"not {type(channels).__name__}")
    if len(channels) == 0:
        raise ValueError("no channels given: an EXR image needs at least one channel")
    result: dict[str, np.ndarray] = {}
    first_name, first_shape = None, None
    for name, array in channels.items():
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"channel names must be non-empty strings, got {name!r}")
        values = _as_float32(name, array)
        if values.ndim != 2:
            raise ValueError(f"channel '{name}' has shape {values.shape}; "
                             "expected a 2-D H x W array")
        if values.size == 0:
            raise ValueError(f"channel '{name}' is empty (shape {values.shape})")
        if first_shape is None:
            first_name, first_shape = name, values.shape
        elif values.shape != first_shape:
            raise ValueError(f"channel '{name}' has shape {values.shape} but channel "
                             f"'{first_name}' has shape {first_shape}; all channels "
                             "must have the same shape")
        if not allow_nonfinite:
            _check_finite(name, array, values)
        result[name] = values
    return result


def _json_default(value):
    """JSON encoding of NumPy scalars and arrays (as plain numbers and lists)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"{type(value).__name__} is not JSON serializable")


def _metadata_json(metadata: Mapping | None, channel_names: list[str]) -> str:
    """The JSON text stored in the header, or a clear error for unserializable metadata."""
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, Mapping):
        raise TypeError(f"metadata must be a dict, not {type(metadata).__name__}")
    document = {
        "schema_version": EXR_METADATA_SCHEMA_VERSION,
        "channels": channel_names,
        "metadata": dict(metadata),
    }
    try:
        return json.dumps(document, default=_json_default, allow_nan=False, sort_keys=False)
    except (TypeError, ValueError) as error:
        raise ValueError(f"metadata cannot be stored as JSON: {error}") from error


def _write_exr_file(path: Path, header: dict, channels: dict[str, np.ndarray]) -> None:
    """Encode one single-part scanline EXR at ``path`` (the temporary file)."""
    import OpenEXR

    OpenEXR.File(header, channels).write(str(path))


def write_exr(path: str | os.PathLike, channels: Mapping[str, np.ndarray],
              metadata: Mapping | None = None, overwrite: bool = False,
              allow_nonfinite: bool = False) -> Path:
    """Write a float32 OpenEXR image with named channels, atomically.

    Parameters
    ----------
    path:
        Destination ``.exr`` file; its directory must exist.
    channels:
        Channel name -> H x W array (any real dtype; stored as float32).
        Names are kept exactly, e.g. ``S0``, ``I45``, ``S0.R``.
    metadata:
        A JSON-serializable dict (NumPy scalars and arrays are converted to
        numbers and lists; NaN is rejected), returned by :func:`read_exr`.
    overwrite:
        Replace an existing file. By default an existing ``path`` raises
        :class:`FileExistsError` naming it.
    allow_nonfinite:
        Store NaN and infinite values instead of rejecting them.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    import OpenEXR

    arrays = validate_channels(channels, allow_nonfinite=allow_nonfinite)
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        METADATA_ATTRIBUTE: _metadata_json(metadata, list(arrays)),
    }
    return atomic_write(path, lambda temporary: _write_exr_file(temporary, header, arrays),
                        overwrite=overwrite)


def _flush_c_streams() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask: nothing buffered there to lose
        pass


@contextlib.contextmanager
def _output_captured():
    """Collect what is printed meanwhile, by C++ code on file descriptors 1 and 2 and by
    Python code on ``sys.stdout``/``sys.stderr``; yields a list that holds those lines once
    the block has ended. The OpenEXR binding prints its diagnostics of a damaged file there
    (a warning through Python's stdout, the library's errors on descriptor 2), around any
    message of ours. Without usable descriptors only Python's output is collected."""
    lines = []
    python_output = io.StringIO()
    with _CAPTURE_LOCK, contextlib.ExitStack() as stack:  # descriptors are process-wide
        try:
            sys.stdout.flush()
            sys.stderr.flush()
            saved = [os.dup(1), os.dup(2)]
        except (OSError, ValueError, AttributeError):
            saved = None
        stream = stack.enter_context(tempfile.TemporaryFile()) if saved else None
        stack.enter_context(contextlib.redirect_stdout(python_output))
        stack.enter_context(contextlib.redirect_stderr(python_output))
        if saved:
            for descriptor in (1, 2):
                os.dup2(stream.fileno(), descriptor)
        try:
            yield lines
        finally:
            if saved:
                _flush_c_streams()  # C++ streams write through C stdio, buffered off a tty
                for descriptor, copy in zip((1, 2), saved):
                    os.dup2(copy, descriptor)
                    os.close(copy)
                stream.seek(0)
                lines += stream.read().decode("utf-8", "replace").splitlines()
            lines += python_output.getvalue().splitlines()


def _check_readable_exr(path: Path) -> None:
    """Raise a clear error unless ``path`` is an existing file that starts like an EXR."""
    if not path.exists():
        raise FileNotFoundError(f"EXR file '{path}' does not exist")
    if path.is_dir():
        raise IsADirectoryError(f"'{path}' is a directory, not an EXR file")
    with open(path, "rb") as stream:
        magic = stream.read(4)
    if magic != _EXR_MAGIC:
        raise ValueError(f"'{path}' is not an OpenEXR file (its first bytes are {magic!r}, "
                         f"expected {_EXR_MAGIC!r})")


def _parse_metadata(path: Path, header: dict) -> tuple[dict, list[str] | None]:
    """The user metadata and the stored channel order from the header attribute."""
    text = header.get(METADATA_ATTRIBUTE)
    if text is None:
        return {}, None
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    try:
        document = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"'{path}': header attribute '{METADATA_ATTRIBUTE}' is not "
                         f"valid JSON ({error})") from error
    version = document.get("schema_version") if isinstance(document, dict) else None
    if not isinstance(version, int):
        raise ValueError(f"'{path}': header attribute '{METADATA_ATTRIBUTE}' has no "
                         "integer schema_version")
    if version > EXR_METADATA_SCHEMA_VERSION:
        raise ValueError(f"'{path}': metadata schema version {version} is newer than the "
                         f"supported version {EXR_METADATA_SCHEMA_VERSION}; "
                         "upgrade polarbssrdf")
    return dict(document.get("metadata") or {}), document.get("channels")


def read_exr(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read an OpenEXR image written by :func:`write_exr` (or any single-part EXR).

    Parameters
    ----------
    path:
        The ``.exr`` file.

    Returns
    -------
    channels : dict
        Channel name -> H x W array, in the order they were written (for
        foreign files: the file's order). Float and half channels are
        returned as float32; integer channels keep their dtype.
    metadata : dict
        The ``metadata`` dict passed to :func:`write_exr`; ``{}`` for files
        without it.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The file is not an OpenEXR file, is truncated or damaged (the message
        names it and carries OpenEXR's diagnostic instead of printing it), or
        has metadata of a newer schema version.
    """
    import OpenEXR

    path = Path(path)
    _check_readable_exr(path)
    error = None
    with _output_captured() as diagnostics:
        try:
            exr = OpenEXR.File(str(path), separate_channels=True)
            header = exr.header()
            stored = {name: channel.pixels for name, channel in exr.channels().items()}
        except (RuntimeError, ValueError, OSError) as caught:  # damaged files raise any
            error = caught
    diagnostics = [line for line in diagnostics if line.strip()]
    if error is not None:
        # OpenEXR's own diagnostic says where the file breaks; its exception often does
        # not ("Invalid part index '0': file has 0 parts")
        located = [line for line in diagnostics if str(path) in line] or diagnostics
        reason = located[0].replace(str(path), "").strip(" :") if located else str(error)
        raise ValueError(f"'{path}' is not a readable OpenEXR file (truncated or damaged: "
                         f"{reason})") from error
    if diagnostics:  # a file that read with warnings, or another thread's output: pass on
        print("\n".join(diagnostics), file=sys.stderr)
    metadata, order = _parse_metadata(path, header)
    if order is not None and sorted(order) == sorted(stored):
        stored = {name: stored[name] for name in order}
    channels = {}
    for name, pixels in stored.items():
        pixels = np.asarray(pixels)
        if np.issubdtype(pixels.dtype, np.floating):
            pixels = pixels.astype(np.float32, copy=False)
        channels[name] = np.ascontiguousarray(pixels)
    return channels, metadata

