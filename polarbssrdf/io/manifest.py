"""The capture manifest (``capture.json``): cameras, lights, bands, frames, images.

A capture is a directory whose ``capture.json`` describes everything needed to
read its images (see ``docs/capture_format.md``). This module holds the
in-memory form of that file as frozen dataclasses, their JSON conversion and
their validation. Validation errors are :class:`CaptureFormatError` (a
``ValueError``) whose message starts with the path to the offending field,
e.g. ``frames[2].images[0].camera: unknown camera 'cam9'``.

Units: lengths in mm, wavelengths in nm, light intensity in W/sr (so
radiance, the unit of analyser images, is W/(sr mm^2)). Camera
extrinsics map world points to OpenCV camera coordinates (x right, y down,
z forward): ``X_cam = R X_world + t``; pixels are ``x ~ K X_cam`` with
OpenCV's convention that pixel ``(column u, row v)`` has its centre at the
integer coordinates ``(u, v)``.
"""

from __future__ import annotations

import math
import posixpath
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from polarbssrdf.capture.layout import IMX250MYR, IMX250MZR, SensorLayout
from polarbssrdf.optics.stokes import ANALYSER_ANGLES_DEG
from polarbssrdf.spectral.bands import Band

__all__ = [
    "CAPTURE_SCHEMA",
    "CAPTURE_SCHEMA_VERSION",
    "CAPTURE_UNITS",
    "IMAGE_KINDS",
    "ROTATION_TOLERANCE",
    "SENSOR_LAYOUTS",
    "Camera",
    "CaptureFormatError",
    "CaptureManifest",
    "Frame",
    "ImageRecord",
    "Light",
    "expected_channels",
    "image_path",
    "plan_frame",
]

CAPTURE_SCHEMA = "polarbssrdf.capture"
"""Value of the ``schema`` field of ``capture.json``."""

CAPTURE_SCHEMA_VERSION = 1
"""The newest ``schema_version`` this code reads and the one it writes."""

CAPTURE_UNITS = {"length": "mm", "wavelength": "nm", "intensity": "W/sr"}
"""The only units schema version 1 allows (the package's conventions)."""

SENSOR_LAYOUTS: dict[str, SensorLayout | None] = {
    "IMX250MZR": IMX250MZR,
    "IMX250MYR": IMX250MYR,
    "ideal": None,
}
"""Sensor names allowed in a camera entry; ``ideal`` has no filter mosaic
(analyser images only, any image size)."""

IMAGE_KINDS = ("analyser", "raw")
"""``analyser``: ``<band>.I0, <band>.I45, <band>.I90, <band>.I135`` per band;
``raw``: ``<band>.raw`` per band, the sensor mosaic in digital numbers."""

ROTATION_TOLERANCE = 1e-6
"""Largest allowed deviation of ``R R^T`` from the identity and of ``det R`` from 1."""


class CaptureFormatError(ValueError):
    """A capture manifest (or file) that breaks the format.

    Attributes
    ----------
    field:
        Path to the offending field, e.g. ``cameras[1].R`` (may be empty).
    problem:
        What is wrong with it.
    """

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}" if field else problem)

    def inside(self, prefix: str) -> CaptureFormatError:
        """The same error with ``prefix`` prepended to its field path."""
        if not prefix:
            return self
        if not self.field:
            joined = prefix
        elif self.field.startswith("["):
            joined = prefix + self.field
        else:
            joined = f"{prefix}.{self.field}"
        return CaptureFormatError(joined, self.problem)


# --------------------------------------------------------------------------- checks
def _is_number(value) -> bool:
    """True for int/float (and NumPy real scalars), but not for bool."""
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)))


def _number(value, name: str, *, minimum: float | None = None) -> float:
    if not _is_number(value):
        raise CaptureFormatError(name, f"must be a number, got {_describe(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise CaptureFormatError(name, f"must be finite, got {number}")
    if minimum is not None and number < minimum:
        raise CaptureFormatError(name, f"must be >= {minimum:g}, got {number:g}")
    return number


def _integer(value, name: str, *, minimum: int | None = None) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, (bool, np.bool_)):
        raise CaptureFormatError(name, f"must be an integer, got {_describe(value)}")
    if minimum is not None and value < minimum:
        raise CaptureFormatError(name, f"must be >= {minimum}, got {value}")
    return int(value)


def _string(value, name: str) -> str:
    if not isinstance(value, str) or not value:
        raise CaptureFormatError(name, f"must be a non-empty string, got {_describe(value)}")
    return value


def _describe(value) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{type(value).__name__} {text}"


def _shape_of_nested(value, name: str) -> tuple[int, ...]:
    """Shape of a rectangular nested list of numbers, or a clear error."""
    if _is_number(value):
        return ()
    if not isinstance(value, (list, tuple)):
        raise CaptureFormatError(name, f"must contain only numbers, found {_describe(value)}")
    shapes = {_shape_of_nested(item, f"{name}[{i}]") for i, item in enumerate(value)}
    if len(shapes) > 1:
        raise CaptureFormatError(name, "is ragged (rows of different lengths)")
    return (len(value), *(shapes.pop() if shapes else ()))


def _array(value, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` (nested lists or an array of numbers) as a finite float64 array of ``shape``."""
    if isinstance(value, np.ndarray):
        if value.dtype == bool or not (np.issubdtype(value.dtype, np.floating)
                                       or np.issubdtype(value.dtype, np.integer)):
            raise CaptureFormatError(name, f"must hold real numbers, got dtype {value.dtype}")
        found = value.shape
    else:
        found = _shape_of_nested(value, name)
    if found != shape:
        expected = " x ".join(map(str, shape)) if len(shape) > 1 else f"a {shape[0]}-vector"
        raise CaptureFormatError(name, f"must be {expected}, got shape {found}")
    array = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise CaptureFormatError(name, "must be finite (found NaN or infinity)")
    array.setflags(write=False)
    return array


def _rotation(value, name: str) -> np.ndarray:
    rotation = _array(value, name, (3, 3))
    orthogonality = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    if orthogonality > ROTATION_TOLERANCE:
        raise CaptureFormatError(name, f"is not a rotation: max |R R^T - I| = {orthogonality:.3g} "
                                       f"> {ROTATION_TOLERANCE:g}")
    determinant = float(np.linalg.det(rotation))
    if abs(determinant - 1.0) > ROTATION_TOLERANCE:
        raise CaptureFormatError(name, f"is not a rotation: det = {determinant:.9g} "
                                       "(a reflection has det -1)")
    return rotation


def _relative_path(value, name: str, suffix: str | None = None) -> str:
    """A POSIX path relative to the capture directory that stays inside it."""
    path = _string(value, name)
    if "\\" in path:
        raise CaptureFormatError(name, f"must use '/' as separator, got {path!r}")
    if path.startswith("/") or (len(path) > 1 and path[1] == ":"):
        raise CaptureFormatError(name, f"must be relative to the capture directory, got {path!r}")
    parts = path.split("/")
    if any(part in ("", ".", "..") for part in parts):
        raise CaptureFormatError(name, f"must be a plain relative path without '.', '..' or "
                                       f"empty components, got {path!r}")
    if suffix is not None and not path.lower().endswith(suffix):
        raise CaptureFormatError(name, f"must end with '{suffix}', got {path!r}")
    return posixpath.normpath(path)


def _object(value, name: str, required: Iterable[str], optional: Iterable[str] = ()) -> dict:
    """Check that ``value`` is a JSON object with exactly the allowed keys."""
    if not isinstance(value, Mapping):
        raise CaptureFormatError(name, f"must be a JSON object, got {_describe(value)}")
    required, optional = tuple(required), tuple(optional)
    for key in required:
        if key not in value:
            raise CaptureFormatError(f"{name}.{key}" if name else key, "missing required field")
    unknown = [key for key in value if key not in required and key not in optional]
    if unknown:
        where = f"{name}.{unknown[0]}" if name else str(unknown[0])
        raise CaptureFormatError(where, "unexpected field (allowed: "
                                        f"{', '.join(required + optional)})")
    return dict(value)


def _unique_names(names: list[str], name: str) -> None:
    seen: dict[str, int] = {}
    for i, item in enumerate(names):
        if item in seen:
            raise CaptureFormatError(f"{name}[{i}].name", f"duplicate name {item!r} "
                                                          f"(also {name}[{seen[item]}])")
        seen[item] = i


def _optional_vector(value, name: str) -> np.ndarray | None:
    return None if value is None else _array(value, name, (3,))


def _plain(array: np.ndarray) -> list:
    return np.asarray(array, dtype=np.float64).tolist()


def _validated(build, where: str):
    """Run ``build()`` and put ``where`` in front of the field path of its errors."""
    try:
        return build()
    except CaptureFormatError as error:
        raise error.inside(where) from None


# --------------------------------------------------------------------------- records
@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera (OpenCV model), in mm.

    Parameters
    ----------
    name:
        Unique name, e.g. ``cam00``.
    K:
        3 x 3 intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels;
        OpenCV pixel centres lie at integer coordinates.
    dist:
        OpenCV distortion ``[k1, k2, p1, p2, k3]``.
    R, t:
        World -> camera rotation (3 x 3) and translation (mm):
        ``X_cam = R X_world + t``, camera axes x right, y down, z forward.
    image_size:
        ``(width, height)`` in pixels; a multiple of the sensor's period.
    sensor:
        ``IMX250MZR``, ``IMX250MYR`` or ``ideal`` (see :data:`SENSOR_LAYOUTS`).
    """

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int]
    sensor: str = "ideal"

    def __post_init__(self):
        _string(self.name, "name")
        K = _array(self.K, "K", (3, 3))
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise CaptureFormatError("K", "must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CaptureFormatError("K", f"focal lengths must be > 0, got fx={K[0, 0]:g}, "
                                          f"fy={K[1, 1]:g}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", _array(self.dist, "dist", (5,)))
        object.__setattr__(self, "R", _rotation(self.R, "R"))
        object.__setattr__(self, "t", _array(self.t, "t", (3,)))
        size = self.image_size
        if not isinstance(size, (list, tuple)) or len(size) != 2:
            raise CaptureFormatError("image_size", f"must be [width, height], got {_describe(size)}")
        width = _integer(size[0], "image_size[0]", minimum=1)
        height = _integer(size[1], "image_size[1]", minimum=1)
        object.__setattr__(self, "image_size", (width, height))
        if not isinstance(self.sensor, str) or self.sensor not in SENSOR_LAYOUTS:
            raise CaptureFormatError("sensor", f"unknown sensor {self.sensor!r} "
                                               f"(known: {', '.join(SENSOR_LAYOUTS)})")
        layout = SENSOR_LAYOUTS[self.sensor]
        if layout is not None:
            rows, columns = layout.period
            if width % columns or height % rows:
                raise CaptureFormatError("image_size", f"{width} x {height} (width x height) is not "
                                         f"a multiple of the {columns} x {rows} period of sensor "
                                         f"{self.sensor}")

    # --- derived quantities
    @property
    def width(self) -> int:
        return self.image_size[0]

    @property
    def height(self) -> int:
        return self.image_size[1]

    @property
    def layout(self) -> SensorLayout | None:
        """The sensor's filter layout, or None for an ``ideal`` sensor."""
        return SENSOR_LAYOUTS[self.sensor]

    @property
    def center(self) -> np.ndarray:
        """Position of the centre of projection in world space (mm): ``-R^T t``."""
        return -self.R.T @ self.t

    @property
    def right(self) -> np.ndarray:
        """World direction of image right (camera +x)."""
        return self.R[0].copy()

    @property
    def down(self) -> np.ndarray:
        """World direction of image down (camera +y)."""
        return self.R[1].copy()

    @property
    def forward(self) -> np.ndarray:
        """World direction of the optical axis (camera +z)."""
        return self.R[2].copy()

    def project(self, points_mm) -> np.ndarray:
        """OpenCV pixel coordinates ``(u, v)`` of world points (with distortion).

        Parameters
        ----------
        points_mm:
            ``(..., 3)`` world points in mm, in front of the camera.

        Returns
        -------
        numpy.ndarray
            ``(..., 2)``: column ``u`` and row ``v``, pixel centres at integers.
        """
        points = np.asarray(points_mm, dtype=np.float64)
        camera = points @ self.R.T + self.t
        x, y = camera[..., 0] / camera[..., 2], camera[..., 1] / camera[..., 2]
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.K
        u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        v = K[1, 1] * yd + K[1, 2]
        return np.stack([u, v], axis=-1)

    def normalized_rays(self, u, v) -> np.ndarray:
        """Inverse of :meth:`project`: the camera-frame ray ``(x, y, 1)`` of pixel ``(u, v)``.

        Parameters
        ----------
        u, v:
            Same-shape arrays of column and row (pixel centres at integers).

        Returns
        -------
        numpy.ndarray
            ``(..., 2)``: ``(x, y)`` on the plane ``z = 1``. Exact without
            distortion; with it, OpenCV inverts the model iteratively (40
            iterations or 1e-10), ``undistortPointsIter`` in 4.x and
            ``undistortPoints`` with the criteria in 5.x.
        """
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        K = self.K
        if not np.any(self.dist != 0):
            y = (v - K[1, 2]) / K[1, 1]
            return np.stack([(u - K[0, 2] - K[0, 1] * y) / K[0, 0], y], axis=-1)
        import cv2  # deferred: OpenCV's import is slow and only distorted cameras need it here

        pixels = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x: the iterative variant takes criteria
            rays = cv2.undistortPointsIter(pixels, K, self.dist, None, None, criteria)
        else:  # OpenCV 5.x: undistortPoints takes them
            rays = cv2.undistortPoints(pixels, K, self.dist, R=None, P=None, criteria=criteria)
        return np.asarray(rays, dtype=np.float64).reshape(u.shape + (2,))

    # --- JSON
    def to_json(self) -> dict:
        return {"name": self.name, "K": _plain(self.K), "dist": _plain(self.dist),
                "R": _plain(self.R), "t": _plain(self.t),
                "image_size": list(self.image_size), "sensor": self.sensor}

    @classmethod
    def from_json(cls, data, where: str = "camera") -> Camera:
        def build():
            fields = _object(data, "", ("name", "K", "dist", "R", "t", "image_size", "sensor"))
            return cls(**fields)

        return _validated(build, where)

    def __eq__(self, other):
        return isinstance(other, Camera) and self.to_json() == other.to_json()

    __hash__ = None


@dataclass(frozen=True, eq=False)
class Light:
    """A point light behind a linear polarizer (the ``ppoint`` emitter).

    Parameters
    ----------
    name:
        Unique name, e.g. ``light00``.
    position:
        World position in mm.
    intensity:
        Radiant intensity in W/sr (>= 0).
    polarization_axis:
        World transmission axis of the polarizer (non-zero; not normalized here).
    polarizer_normal:
        Optional normal of the polarizer sheet (``ppoint``'s dichroic model);
        must not be parallel to ``polarization_axis``.
    """

    name: str
    position: np.ndarray
    intensity: float
    polarization_axis: np.ndarray
    polarizer_normal: np.ndarray | None = None

    def __post_init__(self):
        _string(self.name, "name")
        object.__setattr__(self, "position", _array(self.position, "position", (3,)))
        object.__setattr__(self, "intensity", _number(self.intensity, "intensity", minimum=0.0))
        axis = _array(self.polarization_axis, "polarization_axis", (3,))
        if np.linalg.norm(axis) == 0:
            raise CaptureFormatError("polarization_axis", "must be a non-zero vector")
        object.__setattr__(self, "polarization_axis", axis)
        normal = _optional_vector(self.polarizer_normal, "polarizer_normal")
        if normal is not None:
            norm = np.linalg.norm(normal)
            if norm == 0:
                raise CaptureFormatError("polarizer_normal", "must be a non-zero vector or null")
            # ppoint builds its absorption axis as normal x axis: it must not vanish
            if np.linalg.norm(np.cross(normal / norm, axis / np.linalg.norm(axis))) < 1e-6:
                raise CaptureFormatError("polarizer_normal", "must not be parallel to "
                                                             "polarization_axis")
        object.__setattr__(self, "polarizer_normal", normal)

    def mitsuba_dict(self) -> dict:
        """The ``ppoint`` emitter dict for :func:`mitsuba.load_dict` (register plugins first)."""
        emitter = {"type": "ppoint", "position": _plain(self.position),
                   "intensity": self.intensity,
                   "polarization_axis": _plain(self.polarization_axis)}
        if self.polarizer_normal is not None:
            emitter["polarizer_normal"] = _plain(self.polarizer_normal)
        return emitter

    def to_json(self) -> dict:
        return {"name": self.name, "position": _plain(self.position), "intensity": self.intensity,
                "polarization_axis": _plain(self.polarization_axis),
                "polarizer_normal": None if self.polarizer_normal is None
                else _plain(self.polarizer_normal)}

    @classmethod
    def from_json(cls, data, where: str = "light") -> Light:
        def build():
            fields = _object(data, "", ("name", "position", "intensity", "polarization_axis"),
                             ("polarizer_normal",))
            return cls(**fields)

        return _validated(build, where)

    def __eq__(self, other):
        return isinstance(other, Light) and self.to_json() == other.to_json()

    __hash__ = None


_CALIBRATION_FIELDS = ("radiance_per_dn", "black_level_dn", "saturation_dn")
"""Optional fields of an image record: the radiometric calibration of a raw image."""


@dataclass(frozen=True)
class ImageRecord:
    """One image file of a frame: what camera saw with which light on.

    Parameters
    ----------
    camera, light:
        Names of a camera and a light of the manifest.
    path:
        EXR file, relative to the capture directory (``/`` separators).
    kind:
        ``analyser`` or ``raw`` (see :data:`IMAGE_KINDS`).
    radiance_per_dn:
        Raw images only, optional: ``{band: radiance per digital number}``,
        radiance in W/(sr mm^2) (the unit of analyser images), one positive
        finite number for every band of the manifest (checked there). The
        mean response of the shot is linear:
        ``radiance = (DN - black_level_dn) * radiance_per_dn[band]``.
        ``None`` (older captures): the image has no radiometric scale;
        readers that need radiance refuse it.
    black_level_dn:
        The offset of the same formula, DN (>= 0, finite); given exactly when
        ``radiance_per_dn`` is.
    saturation_dn:
        Optional (raw images with ``radiance_per_dn`` only): pixels reading
        this many DN or more are clipped (e.g. 4095 for a 12-bit ADC) and
        carry no radiance; must exceed ``black_level_dn``. ``None``: unknown,
        nothing is flagged.
    """

    camera: str
    light: str
    path: str
    kind: str = "analyser"
    radiance_per_dn: dict | None = None
    black_level_dn: float | None = None
    saturation_dn: float | None = None

    def __post_init__(self):
        _string(self.camera, "camera")
        _string(self.light, "light")
        object.__setattr__(self, "path", _relative_path(self.path, "path", ".exr"))
        if self.kind not in IMAGE_KINDS:
            raise CaptureFormatError("kind", f"must be one of {', '.join(IMAGE_KINDS)}, "
                                             f"got {self.kind!r}")
        given = [name for name in _CALIBRATION_FIELDS if getattr(self, name) is not None]
        if given and self.kind != "raw":
            raise CaptureFormatError(given[0], f"only raw images carry a radiometric calibration "
                                               f"({self.kind} images are radiance already)")
        if self.radiance_per_dn is None:
            if given:
                raise CaptureFormatError(given[0], "needs radiance_per_dn (the calibration is "
                                                   "radiance = (DN - black_level_dn) * "
                                                   "radiance_per_dn[band])")
            return
        scales = self.radiance_per_dn
        if not isinstance(scales, Mapping) or not scales:
            raise CaptureFormatError("radiance_per_dn", "must be a non-empty JSON object "
                                     f"{{band: radiance per DN}}, got {_describe(scales)}")
        checked = {}
        for band, value in scales.items():
            where = f"radiance_per_dn.{band}"
            if not isinstance(band, str) or not band:
                raise CaptureFormatError("radiance_per_dn", f"band names must be non-empty "
                                                            f"strings, got {_describe(band)}")
            number = _number(value, where)
            if number <= 0:
                raise CaptureFormatError(where, f"must be > 0, got {number:g}")
            checked[band] = number
        object.__setattr__(self, "radiance_per_dn", checked)
        if self.black_level_dn is None:
            raise CaptureFormatError("black_level_dn", "missing: required with radiance_per_dn "
                                                       "(0 for a sensor without offset)")
        black = _number(self.black_level_dn, "black_level_dn", minimum=0.0)
        object.__setattr__(self, "black_level_dn", black)
        if self.saturation_dn is not None:
            saturation = _number(self.saturation_dn, "saturation_dn")
            if saturation <= black:
                raise CaptureFormatError("saturation_dn", f"must exceed black_level_dn "
                                                          f"({black:g}), got {saturation:g}")
            object.__setattr__(self, "saturation_dn", saturation)

    def __hash__(self):
        scales = None if self.radiance_per_dn is None else tuple(self.radiance_per_dn.items())
        return hash((self.camera, self.light, self.path, self.kind, scales, self.black_level_dn,
                     self.saturation_dn))

    @property
    def calibrated(self) -> bool:
        """True for a raw record with a radiometric calibration (``radiance_per_dn``)."""
        return self.radiance_per_dn is not None

    def radiance(self, band: str, dn) -> np.ndarray:
        """``(dn - black_level_dn) * radiance_per_dn[band]`` as float64, W/(sr mm^2).

        Saturated pixels are not flagged here (compare ``dn`` with
        ``saturation_dn``). ``ValueError`` for records without a calibration,
        ``KeyError`` for a band it does not have.
        """
        if self.radiance_per_dn is None:
            raise ValueError(f"image {self.path!r} ({self.kind}) has no radiance_per_dn")
        if band not in self.radiance_per_dn:
            raise KeyError(f"image {self.path!r} has no radiance_per_dn for band {band!r} "
                           f"(it has {', '.join(self.radiance_per_dn)})")
        values = np.asarray(dn, dtype=np.float64)
        return (values - self.black_level_dn) * self.radiance_per_dn[band]

    def to_json(self) -> dict:
        document = {"camera": self.camera, "light": self.light, "path": self.path,
                    "kind": self.kind}
        if self.radiance_per_dn is not None:
            document["radiance_per_dn"] = dict(self.radiance_per_dn)
            document["black_level_dn"] = self.black_level_dn
            if self.saturation_dn is not None:
                document["saturation_dn"] = self.saturation_dn
        return document

    @classmethod
    def from_json(cls, data, where: str = "image") -> ImageRecord:
        return _validated(lambda: cls(**_object(data, "", ("camera", "light", "path", "kind"),
                                                _CALIBRATION_FIELDS)),
                          where)


@dataclass(frozen=True, eq=False)
class Frame:
    """One time step: the object's pose and the images taken.

    Parameters
    ----------
    index:
        Frame number (>= 0, unique in the capture).
    time_s:
        Time stamp in seconds.
    pose:
        4 x 4 rigid object-to-world transform (mm); its 3 x 3 block is a rotation.
    images:
        The frame's :class:`ImageRecord` s, at most one per (camera, light).
    """

    index: int
    time_s: float
    pose: np.ndarray
    images: tuple[ImageRecord, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "index", _integer(self.index, "index", minimum=0))
        object.__setattr__(self, "time_s", _number(self.time_s, "time_s"))
        pose = _array(self.pose, "pose", (4, 4))
        if not np.array_equal(pose[3], [0.0, 0.0, 0.0, 1.0]):
            raise CaptureFormatError("pose", f"last row must be [0, 0, 0, 1], got {pose[3].tolist()}")
        _validated(lambda: _rotation(pose[:3, :3], "rotation"), "pose")
        object.__setattr__(self, "pose", pose)
        if not isinstance(self.images, (list, tuple)):
            raise CaptureFormatError("images", f"must be a list, got {_describe(self.images)}")
        for i, record in enumerate(self.images):
            if not isinstance(record, ImageRecord):
                raise CaptureFormatError(f"images[{i}]", f"must be an ImageRecord, got "
                                                         f"{_describe(record)}")
        object.__setattr__(self, "images", tuple(self.images))
        seen: dict[tuple[str, str], int] = {}
        for i, record in enumerate(self.images):
            key = (record.camera, record.light)
            if key in seen:
                raise CaptureFormatError(f"images[{i}]", f"second image for camera {key[0]!r} and "
                                                         f"light {key[1]!r} (also images[{seen[key]}])")
            seen[key] = i

    def image(self, camera: str, light: str) -> ImageRecord:
        """The record of ``camera`` with ``light``; ``KeyError`` naming them if absent."""
        for record in self.images:
            if record.camera == camera and record.light == light:
                return record
        raise KeyError(f"frame {self.index} has no image for camera {camera!r} and light {light!r}")

    def to_json(self) -> dict:
        return {"index": self.index, "time_s": self.time_s, "pose": _plain(self.pose),
                "images": [record.to_json() for record in self.images]}

    @classmethod
    def from_json(cls, data, where: str = "frame") -> Frame:
        def build():
            fields = _object(data, "", ("index", "time_s", "pose", "images"))
            images = fields["images"]
            if not isinstance(images, list):
                raise CaptureFormatError("images", f"must be a list, got {_describe(images)}")
            fields["images"] = tuple(ImageRecord.from_json(item, f"images[{i}]")
                                     for i, item in enumerate(images))
            return cls(**fields)

        return _validated(build, where)

    def __eq__(self, other):
        return isinstance(other, Frame) and self.to_json() == other.to_json()

    __hash__ = None


def image_path(frame_index: int, camera: str, light: str) -> str:
    """The conventional path of an image: ``images/f0000/cam00_light00.exr``."""
    return f"images/f{frame_index:04d}/{camera}_{light}.exr"


def plan_frame(index: int, time_s: float, pose, pairs: Iterable[tuple[str, str]],
               kind: str = "analyser", calibration: Mapping[str, Mapping] | None = None) -> Frame:
    """A :class:`Frame` with one image per ``(camera, light)`` pair at :func:`image_path`.

    Parameters
    ----------
    index, time_s, pose:
        As in :class:`Frame` (seconds; 4 x 4 object-to-world in mm).
    pairs:
        ``(camera name, light name)`` for each image taken in this frame.
    kind:
        ``analyser`` or ``raw`` for all images.
    calibration:
        Raw images only: ``{camera name: {"radiance_per_dn": {band: float},
        "black_level_dn": float, "saturation_dn": float}}`` (the optional
        fields of :class:`ImageRecord`) for the cameras that have one.
    """
    calibration = calibration or {}
    images = tuple(ImageRecord(camera, light, image_path(index, camera, light), kind,
                               **calibration.get(camera, {}))
                   for camera, light in pairs)
    return Frame(index, time_s, pose, images)


def expected_channels(kind: str, band_names: Iterable[str]) -> tuple[str, ...]:
    """Channel names of an image of ``kind``, in the order they are written.

    ``analyser``: ``<band>.I0, <band>.I45, <band>.I90, <band>.I135`` for each band
    in turn; ``raw``: ``<band>.raw`` for each band.
    """
    if kind == "analyser":
        return tuple(f"{band}.I{angle}" for band in band_names for angle in ANALYSER_ANGLES_DEG)
    if kind == "raw":
        return tuple(f"{band}.raw" for band in band_names)
    raise ValueError(f"unknown image kind {kind!r} (known: {', '.join(IMAGE_KINDS)})")


# --------------------------------------------------------------------------- manifest
_MANIFEST_FIELDS = ("schema", "schema_version", "units", "mesh", "bands", "cameras", "lights",
                    "frames", "synthetic", "truth")


@dataclass(frozen=True, eq=False)
class CaptureManifest:
    """Everything ``capture.json`` says; validated on construction.

    Parameters
    ----------
    bands:
        :class:`~polarbssrdf.spectral.bands.Band` s with unique names
        (letters, digits, ``_`` and ``-``; they prefix channel names).
    cameras, lights:
        :class:`Camera` s and :class:`Light` s with unique names.
    frames:
        :class:`Frame` s with unique indices; their images refer to the
        cameras and lights above by name and use unique paths.
    mesh:
        Path of the object's mesh (OBJ UV convention) relative to the
        capture directory, or None.
    synthetic:
        True for rendered captures.
    truth:
        Path of ``truth.json`` relative to the capture directory (synthetic
        captures only), or None.
    metadata:
        Free-form JSON object (e.g. how the capture was made); an addition to
        the decided format, omitted from the file when empty.
    schema_version:
        Version of the file this came from (1).
    """

    bands: tuple[Band, ...]
    cameras: tuple[Camera, ...]
    lights: tuple[Light, ...]
    frames: tuple[Frame, ...]
    mesh: str | None = None
    synthetic: bool = False
    truth: str | None = None
    metadata: dict = field(default_factory=dict)
    schema_version: int = CAPTURE_SCHEMA_VERSION

    def __post_init__(self):
        version = _integer(self.schema_version, "schema_version", minimum=1)
        if version > CAPTURE_SCHEMA_VERSION:
            raise CaptureFormatError("schema_version", f"{version} is newer than the supported "
                                     f"version {CAPTURE_SCHEMA_VERSION}; upgrade polarbssrdf")
        for name, kind in (("bands", Band), ("cameras", Camera), ("lights", Light),
                           ("frames", Frame)):
            items = getattr(self, name)
            if not isinstance(items, (list, tuple)):
                raise CaptureFormatError(name, f"must be a list, got {_describe(items)}")
            for i, item in enumerate(items):
                if not isinstance(item, kind):
                    raise CaptureFormatError(f"{name}[{i}]", f"must be a {kind.__name__}, got "
                                                             f"{_describe(item)}")
            object.__setattr__(self, name, tuple(items))
        for name in ("bands", "cameras", "lights", "frames"):
            if not getattr(self, name):
                raise CaptureFormatError(name, "must not be empty")
        band_names = [band.name for band in self.bands]
        for i, band_name in enumerate(band_names):
            if not band_name or not all(c.isalnum() or c in "_-" for c in band_name):
                raise CaptureFormatError(f"bands[{i}].name", f"{band_name!r} must be non-empty and "
                                         "use only letters, digits, '_' and '-' (it prefixes "
                                         "channel names)")
        _unique_names(band_names, "bands")
        _unique_names([camera.name for camera in self.cameras], "cameras")
        _unique_names([light.name for light in self.lights], "lights")
        if self.mesh is not None:
            object.__setattr__(self, "mesh", _relative_path(self.mesh, "mesh"))
        if not isinstance(self.synthetic, bool):
            raise CaptureFormatError("synthetic", f"must be true or false, got "
                                                  f"{_describe(self.synthetic)}")
        if self.truth is not None:
            object.__setattr__(self, "truth", _relative_path(self.truth, "truth", ".json"))
            if not self.synthetic:
                raise CaptureFormatError("truth", "only synthetic captures have ground truth "
                                                  "(set synthetic to true or truth to null)")
        if not isinstance(self.metadata, Mapping):
            raise CaptureFormatError("metadata", f"must be a JSON object, got "
                                                 f"{_describe(self.metadata)}")
        object.__setattr__(self, "metadata", dict(self.metadata))
        self._check_references()

    def _check_references(self) -> None:
        cameras = {camera.name: camera for camera in self.cameras}
        lights = [light.name for light in self.lights]
        frame_positions: dict[int, int] = {}
        paths: dict[str, str] = {}
        reserved = {self.mesh, self.truth}
        for k, frame in enumerate(self.frames):
            if frame.index in frame_positions:
                raise CaptureFormatError(f"frames[{k}].index", f"duplicate frame index {frame.index} "
                                         f"(also frames[{frame_positions[frame.index]}])")
            frame_positions[frame.index] = k
            for i, record in enumerate(frame.images):
                where = f"frames[{k}].images[{i}]"
                if record.camera not in cameras:
                    raise CaptureFormatError(f"{where}.camera", f"unknown camera {record.camera!r} "
                                             f"(known: {', '.join(cameras)})")
                if record.light not in lights:
                    raise CaptureFormatError(f"{where}.light", f"unknown light {record.light!r} "
                                             f"(known: {', '.join(lights)})")
                if record.kind == "raw" and cameras[record.camera].sensor == "ideal":
                    raise CaptureFormatError(f"{where}.kind", f"camera {record.camera!r} has an "
                                             "ideal sensor without a mosaic: it has no raw images")
                if record.radiance_per_dn is not None:
                    bands = self.band_names
                    missing = [band for band in bands if band not in record.radiance_per_dn]
                    if missing:
                        raise CaptureFormatError(f"{where}.radiance_per_dn", f"missing band(s) "
                                                 f"{', '.join(missing)} (every band needs a "
                                                 "scale)")
                    extra = [band for band in record.radiance_per_dn if band not in bands]
                    if extra:
                        raise CaptureFormatError(f"{where}.radiance_per_dn.{extra[0]}",
                                                 f"unknown band (bands: {', '.join(bands)})")
                if record.path in paths:
                    raise CaptureFormatError(f"{where}.path", f"{record.path!r} is used twice "
                                             f"(also {paths[record.path]})")
                if record.path in reserved or record.path == "capture.json":
                    raise CaptureFormatError(f"{where}.path", f"{record.path!r} is not an image path")
                paths[record.path] = where

    # --- lookups
    @property
    def band_names(self) -> tuple[str, ...]:
        return tuple(band.name for band in self.bands)

    def camera(self, name: str) -> Camera:
        """The camera called ``name``; ``KeyError`` listing the known ones otherwise."""
        for camera in self.cameras:
            if camera.name == name:
                return camera
        raise KeyError(f"unknown camera {name!r} (known: {', '.join(c.name for c in self.cameras)})")

    def light(self, name: str) -> Light:
        """The light called ``name``; ``KeyError`` listing the known ones otherwise."""
        for light in self.lights:
            if light.name == name:
                return light
        raise KeyError(f"unknown light {name!r} (known: {', '.join(l.name for l in self.lights)})")

    def frame(self, index: int) -> Frame:
        """The frame with ``index`` (its number, not its list position)."""
        for frame in self.frames:
            if frame.index == index:
                return frame
        raise KeyError(f"no frame with index {index} (indices: "
                       f"{', '.join(str(f.index) for f in self.frames)})")

    def records(self) -> list[tuple[Frame, ImageRecord]]:
        """Every ``(frame, image record)`` pair, in manifest order."""
        return [(frame, record) for frame in self.frames for record in frame.images]

    def expected_channels(self, record: ImageRecord) -> tuple[str, ...]:
        """Channel names the file of ``record`` must hold (see :func:`expected_channels`)."""
        return expected_channels(record.kind, self.band_names)

    # --- JSON
    def to_json(self) -> dict:
        document = {
            "schema": CAPTURE_SCHEMA,
            "schema_version": CAPTURE_SCHEMA_VERSION,
            "units": dict(CAPTURE_UNITS),
            "mesh": self.mesh,
            "bands": [band.to_dict() for band in self.bands],
            "cameras": [camera.to_json() for camera in self.cameras],
            "lights": [light.to_json() for light in self.lights],
            "frames": [frame.to_json() for frame in self.frames],
            "synthetic": self.synthetic,
            "truth": self.truth,
        }
        if self.metadata:
            document["metadata"] = dict(self.metadata)
        return document

    @classmethod
    def from_json(cls, data) -> CaptureManifest:
        """Parse and validate the decoded ``capture.json``; errors name the field path."""
        if not isinstance(data, Mapping):
            raise CaptureFormatError("", f"the manifest must be a JSON object, got {_describe(data)}")
        schema = data.get("schema")
        if schema != CAPTURE_SCHEMA:
            raise CaptureFormatError("schema", f"expected {CAPTURE_SCHEMA!r}, got {schema!r}: "
                                               "not a polarbssrdf capture manifest")
        if "schema_version" not in data:
            raise CaptureFormatError("schema_version", "missing required field")
        version = _integer(data["schema_version"], "schema_version", minimum=1)
        if version > CAPTURE_SCHEMA_VERSION:
            raise CaptureFormatError("schema_version", f"{version} is newer than the supported "
                                     f"version {CAPTURE_SCHEMA_VERSION}; upgrade polarbssrdf")
        fields = _object(data, "", _MANIFEST_FIELDS, ("metadata",))
        units = fields["units"]
        if not isinstance(units, Mapping) or dict(units) != CAPTURE_UNITS:
            raise CaptureFormatError("units", f"must be {CAPTURE_UNITS} (schema version "
                                              f"{CAPTURE_SCHEMA_VERSION}), got {units!r}")
        lists = {}
        for name in ("bands", "cameras", "lights", "frames"):
            if not isinstance(fields[name], list):
                raise CaptureFormatError(name, f"must be a list, got {_describe(fields[name])}")
            lists[name] = fields[name]
        bands = tuple(_band_from_json(item, f"bands[{i}]") for i, item in enumerate(lists["bands"]))
        cameras = tuple(Camera.from_json(item, f"cameras[{i}]")
                        for i, item in enumerate(lists["cameras"]))
        lights = tuple(Light.from_json(item, f"lights[{i}]")
                       for i, item in enumerate(lists["lights"]))
        frames = tuple(Frame.from_json(item, f"frames[{i}]")
                       for i, item in enumerate(lists["frames"]))
        return cls(bands=bands, cameras=cameras, lights=lights, frames=frames,
                   mesh=fields["mesh"], synthetic=fields["synthetic"], truth=fields["truth"],
                   metadata=fields.get("metadata", {}), schema_version=version)

    def __eq__(self, other):
        return isinstance(other, CaptureManifest) and self.to_json() == other.to_json()

    __hash__ = None


def _band_from_json(data, where: str) -> Band:
    def build():
        fields = _object(data, "", ("name", "wavelengths_nm", "weights"),
                         ("description", "metadata"))
        _string(fields["name"], "name")
        for key in ("wavelengths_nm", "weights"):
            shape = _shape_of_nested(fields[key], key)
            if len(shape) != 1:
                raise CaptureFormatError(key, f"must be a list of numbers, got shape {shape}")
        if not isinstance(fields.get("description", ""), str):
            raise CaptureFormatError("description", "must be a string")
        if not isinstance(fields.get("metadata", {}), Mapping):
            raise CaptureFormatError("metadata", "must be a JSON object")
        try:
            return Band.from_dict(fields)
        except ValueError as error:
            raise CaptureFormatError("", str(error)) from None

    return _validated(build, where)
