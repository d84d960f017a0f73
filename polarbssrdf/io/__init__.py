"""Reading and writing files: float32 OpenEXR images with JSON metadata, atomic writes.

:func:`write_exr` / :func:`read_exr` handle images with named channels
(:mod:`.exr`); :func:`atomic_write_bytes` / :func:`atomic_write_text` write
any file through a temporary file and a rename (:mod:`.atomic`). Nothing
here replaces an existing file unless asked to (``overwrite=True``).
"""

from polarbssrdf.io.atomic import atomic_write, atomic_write_bytes, atomic_write_text
from polarbssrdf.io.exr import (
    EXR_METADATA_SCHEMA_VERSION,
    METADATA_ATTRIBUTE,
    read_exr,
    validate_channels,
    write_exr,
)

__all__ = [
    "EXR_METADATA_SCHEMA_VERSION",
    "METADATA_ATTRIBUTE",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "read_exr",
    "validate_channels",
    "write_exr",
]
