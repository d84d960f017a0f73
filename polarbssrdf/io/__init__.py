"""Reading and writing files: float32 OpenEXR images with JSON metadata, atomic writes.

:func:`write_exr` / :func:`read_exr` handle images with named channels
(:mod:`.exr`); :func:`atomic_write_bytes` / :func:`atomic_write_text` write
any file through a temporary file and a rename (:mod:`.atomic`). Nothing
here replaces an existing file unless asked to (``overwrite=True``).

The capture format (``docs/capture_format.md``): :mod:`.manifest` (the
``capture.json`` dataclasses and their validation), :mod:`.truth` (ground
truth of synthetic captures), :mod:`.capture` (:func:`write_capture`,
:class:`CaptureWriter`, :func:`load_capture`) and :mod:`.mitsuba_camera`
(capture cameras as Mitsuba sensors). Their names are importable from here;
they load on first use, so the EXR and atomic-write helpers stay light.
"""

from polarbssrdf.io.atomic import atomic_write, atomic_write_bytes, atomic_write_text
from polarbssrdf.io.exr import (
    EXR_METADATA_SCHEMA_VERSION,
    METADATA_ATTRIBUTE,
    read_exr,
    validate_channels,
    write_exr,
)

_LAZY = {
    "polarbssrdf.io.manifest": (
        "CAPTURE_SCHEMA", "CAPTURE_SCHEMA_VERSION", "Camera", "CaptureFormatError",
        "CaptureManifest", "Frame", "ImageRecord", "Light", "expected_channels", "image_path",
        "plan_frame"),
    "polarbssrdf.io.truth": ("DEFAULT_TRUTH_UNITS", "GroundTruth", "TruthManifest"),
    "polarbssrdf.io.capture": (
        "Capture", "CaptureWriter", "check_image_channels", "load_capture", "write_capture"),
    "polarbssrdf.io.mitsuba_camera": (
        "camera_from_look_at", "camera_to_world", "look_at_parameters", "mitsuba_sensor_dict"),
}
_LAZY_NAMES = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name):
    # The capture modules import the spectral and camera packages (colour-science,
    # SciPy); load them only when one of their names is asked for.
    module = _LAZY_NAMES.get(name)
    if module is None:
        raise AttributeError(f"module 'polarbssrdf.io' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


__all__ = [
    *_LAZY_NAMES,
    "EXR_METADATA_SCHEMA_VERSION",
    "METADATA_ATTRIBUTE",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "read_exr",
    "validate_channels",
    "write_exr",
]
