"""Writing and loading capture directories (format: ``docs/capture_format.md``).

A capture directory holds ``capture.json`` (:class:`~polarbssrdf.io.manifest.CaptureManifest`),
float32 EXR images (``images/f0000/cam00_light00.exr``), optionally a mesh and,
for synthetic captures, ``truth/``. ``capture.json`` is always written last and
atomically, so a directory that has it is complete; while a
:class:`CaptureWriter` is at work the directory holds ``capture.plan.json``
instead (the manifest it is filling in), which lets a re-run resume.
"""

from __future__ import annotations

import datetime
import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from polarbssrdf.io.atomic import atomic_write_bytes, atomic_write_text
from polarbssrdf.io.exr import read_exr, validate_channels, write_exr
from polarbssrdf.io.manifest import (
    Camera,
    CaptureFormatError,
    CaptureManifest,
    Frame,
    ImageRecord,
    Light,
)
from polarbssrdf.io.truth import (
    DEFAULT_TRUTH_UNITS,
    GroundTruth,
    TruthManifest,
    TruthMapRecord,
    check_truth_channels,
    truth_map_path,
)

__all__ = [
    "MANIFEST_NAME",
    "PLAN_NAME",
    "Capture",
    "CaptureWriter",
    "PlanMismatchError",
    "check_image_channels",
    "dumps_json",
    "json_differences",
    "load_capture",
    "read_json",
    "short_json",
    "write_capture",
]

MANIFEST_NAME = "capture.json"
PLAN_NAME = "capture.plan.json"
"""Written by :class:`CaptureWriter` when it starts; removed once ``capture.json`` exists."""

NEGATIVE_TOLERANCE = 1e-6
"""Analyser images may dip below zero by at most this fraction of their maximum (rounding)."""


# --------------------------------------------------------------------------- JSON
def dumps_json(value, indent: int = 2) -> str:
    """JSON text with one entry per line, except lists of numbers (and of such lists),
    which stay on one line so matrices and spectra remain readable. NaN is rejected."""

    def is_flat(item) -> bool:
        return isinstance(item, list) and all(
            (isinstance(x, (int, float)) and not isinstance(x, bool)) or is_flat(x) for x in item)

    def encode(item, level: int) -> str:
        if is_flat(item):
            return json.dumps(item, allow_nan=False, separators=(", ", ": "))
        pad, inner = " " * (indent * level), " " * (indent * (level + 1))
        if isinstance(item, Mapping) and item:
            entries = [f"{inner}{json.dumps(str(k))}: {encode(v, level + 1)}" for k, v in item.items()]
            return "{\n" + ",\n".join(entries) + f"\n{pad}}}"
        if isinstance(item, (list, tuple)) and item:
            entries = [inner + encode(v, level + 1) for v in item]
            return "[\n" + ",\n".join(entries) + f"\n{pad}]"
        return json.dumps(item, allow_nan=False)

    return encode(value, 0) + "\n"


def read_json(path: str | os.PathLike):
    """Decode a JSON file; a malformed file raises ``ValueError`` naming line and column."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"'{path}' does not exist")
    text = path.read_text(encoding="utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise CaptureFormatError("", f"'{path}' is not valid JSON: {error.msg} at line "
                                     f"{error.lineno}, column {error.colno}") from None


# --------------------------------------------------------------------------- image checks
def _article(word: str) -> str:
    """``an`` before a vowel (``an analyser image``), else ``a`` (``a raw image``)."""
    return "an" if word[:1].lower() in "aeiou" else "a"


def check_image_channels(channels: Mapping[str, np.ndarray], expected: tuple[str, ...],
                         image_size: tuple[int, int], kind: str, what: str,
                         allow_nan: bool = False) -> None:
    """Raise ``ValueError`` naming ``what`` unless ``channels`` fit the manifest.

    Checks: exactly the ``expected`` channel names, each a float32 array of
    ``(height, width)`` = ``image_size[::-1]``, finite, and for ``analyser``
    images no value below ``-1e-6 * max``. With ``allow_nan`` (how the
    observation builder reads images) NaN pixels pass, as missing data that
    drops only the texel-views touching them; infinities and negative radiance
    are still errors.
    """
    names = set(channels)
    if names != set(expected):
        missing = [name for name in expected if name not in names]
        unexpected = sorted(names - set(expected))
        raise CaptureFormatError("", f"{what}: wrong channel set for {_article(kind)} {kind} image: missing "
                                     f"{missing or 'none'}, unexpected {unexpected or 'none'}")
    width, height = image_size
    maximum = 0.0
    minimum, minimum_name = np.inf, None
    for name in expected:
        values = channels[name]
        if values.dtype != np.float32:
            raise CaptureFormatError("", f"{what}: channel '{name}' has dtype {values.dtype}; "
                                         "expected float32")
        if values.shape != (height, width):
            raise CaptureFormatError("", f"{what}: channel '{name}' is {values.shape[1]} x "
                                         f"{values.shape[0]} (width x height); the camera's "
                                         f"image_size is {width} x {height}")
        finite = np.isfinite(values)
        everywhere = bool(finite.all())
        bad = np.isinf(values) if allow_nan and not everywhere else ~finite
        if not everywhere and bad.any():
            row, column = (int(i) for i in np.argwhere(bad)[0])
            raise CaptureFormatError("", f"{what}: channel '{name}' has {int(np.isnan(values).sum())} "
                                         f"NaN and {int(np.isinf(values).sum())} infinite values "
                                         f"(first at row {row}, column {column})")
        if not everywhere:
            if not finite.any():
                continue  # all NaN: no texel-view of this image survives, nothing to compare
            values = values[finite]
        maximum = max(maximum, float(values.max()))
        if float(values.min()) < minimum:
            minimum, minimum_name = float(values.min()), name
    if kind == "analyser" and minimum < -NEGATIVE_TOLERANCE * maximum:
        raise CaptureFormatError("", f"{what}: channel '{minimum_name}' has negative intensity "
                                     f"{minimum:g} (maximum {maximum:g}); analyser images are "
                                     "radiance >= 0")


def _check_truth_maps(channels: Mapping[str, np.ndarray], texture_size: int | None,
                      what: str) -> int:
    """Check square, equal-size, finite float32 maps; return their size T."""
    size = texture_size
    for name, values in channels.items():
        if values.ndim != 2 or values.shape[0] != values.shape[1]:
            raise CaptureFormatError("", f"{what}: map '{name}' has shape {values.shape}; "
                                         "maps are square T x T textures")
        if size is None:
            size = values.shape[0]
        if values.shape[0] != size:
            raise CaptureFormatError("", f"{what}: map '{name}' is {values.shape[0]} x "
                                         f"{values.shape[0]} but the texture size is {size}")
        if values.dtype != np.float32:
            raise CaptureFormatError("", f"{what}: map '{name}' has dtype {values.dtype}; "
                                         "expected float32")
        if not np.isfinite(values).all():
            raise CaptureFormatError("", f"{what}: map '{name}' contains NaN or infinite values")
    return size


def _obj_text(mesh) -> str:
    """Wavefront OBJ text of a :class:`~polarbssrdf.geometry.mesh.SurfaceMesh` (one UV per vertex)."""
    lines = [f"# {mesh.name}: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles, mm"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(mesh.vertices, dtype=float).tolist()]
    lines += [f"vt {u!r} {v!r}" for u, v in np.asarray(mesh.uvs, dtype=float).tolist()]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in face)
              for face in np.asarray(mesh.faces).tolist()]
    return "\n".join(lines) + "\n"


def _frame_index(frame) -> int:
    return frame.index if isinstance(frame, Frame) else int(frame)


def _name(item) -> str:
    return item.name if isinstance(item, (Camera, Light)) else str(item)


# --------------------------------------------------------------------------- plan comparison
def json_differences(old, new, path: str = "") -> list[tuple[str, object, object]]:
    """``(path, old value, new value)`` of every place where two JSON documents differ.

    Paths are dotted (``metadata.settings.spp``, ``cameras[1].name``). Lists of
    different lengths, and values of different types, are reported whole at
    their path rather than element by element.
    """
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        differences = []
        for key in list(old) + [k for k in new if k not in old]:
            child = f"{path}.{key}" if path else str(key)
            if key not in old or key not in new:
                differences.append((child, old.get(key, "<absent>"), new.get(key, "<absent>")))
            else:
                differences += json_differences(old[key], new[key], child)
        return differences
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        differences = []
        for index, (a, b) in enumerate(zip(old, new)):
            differences += json_differences(a, b, f"{path}[{index}]")
        return differences
    return [] if old == new else [(path, old, new)]


class PlanMismatchError(FileExistsError):
    """``resume`` found a capture (plan or finished manifest) that differs from the new plan.

    Attributes
    ----------
    directory : pathlib.Path
    differences : list of (path, old, new)
        Where the plan on disk (``old``) and the new plan (``new``) differ, as
        :func:`json_differences` gives them (paths start with ``manifest.``,
        ``truth_units`` or ``truth_metadata``).
    """

    def __init__(self, message: str, directory: Path, differences):
        self.directory = Path(directory)
        self.differences = list(differences)
        shown = "; ".join(f"{path}: {short_json(old)} -> {short_json(new)}"
                          for path, old, new in self.differences[:5])
        more = f"; and {len(self.differences) - 5} more" if len(self.differences) > 5 else ""
        super().__init__(f"{message} ({shown}{more})" if shown else message)


def short_json(value, limit: int = 60) -> str:
    """A one-line JSON rendering of ``value``, cut to ``limit`` characters."""
    text = json.dumps(value, allow_nan=False) if not isinstance(value, str) else repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


# --------------------------------------------------------------------------- writer
class CaptureWriter:
    """Write a capture image by image, so an interrupted run can resume.

    The writer is given the complete manifest up front (the *plan*: every
    frame and every image record) and stores it as ``capture.plan.json``.
    Each :meth:`add_image` checks the channels against the plan and writes the
    EXR atomically, so a file under its final name is always complete.
    :meth:`finish` checks that every planned file exists, writes
    ``truth/truth.json`` (synthetic captures) and then ``capture.json``, and
    removes the plan.

    Resuming: construct the writer again with the same manifest and
    ``resume=True``; :meth:`completed` returns the ``(frame index, camera,
    light)`` keys already on disk (and :meth:`missing` the rest), so the
    caller renders only what is missing::

        writer = CaptureWriter(out, manifest, resume=True)
        done = writer.completed()
        for frame, record in manifest.records():
            if (frame.index, record.camera, record.light) not in done:
                writer.add_image(frame, record.camera, record.light, render(...))
        writer.finish()

    Parameters
    ----------
    directory:
        Capture directory; created if missing.
    manifest:
        The complete :class:`~polarbssrdf.io.manifest.CaptureManifest`.
    truth_units:
        Parameter -> unit of the ground-truth maps (only when ``manifest.truth``
        is set; default :data:`~polarbssrdf.io.truth.DEFAULT_TRUTH_UNITS`).
    truth_metadata:
        Free-form JSON object for ``truth.json``.
    overwrite:
        Accept a non-empty directory and start the capture anew: files at the
        paths the new plan names (its images, truth maps and ``truth.json``)
        are removed before anything is written, so none of them can later be
        mistaken for a finished image of this plan (e.g. by a resume after an
        interrupt). Files the new plan does not name are never touched; an
        existing ``capture.json`` is renamed to
        ``capture.superseded-<UTC time>.json`` (not deleted) so the directory
        does not look complete meanwhile.
    resume:
        Continue a capture started by a writer with the same plan.

    Raises
    ------
    FileExistsError
        The directory is not empty and neither flag is given.
    PlanMismatchError
        (a ``FileExistsError``) ``resume`` and the directory holds a different
        capture; ``differences`` lists the fields that differ.
    """

    def __init__(self, directory: str | os.PathLike, manifest: CaptureManifest, *,
                 truth_units: Mapping[str, str] | None = None,
                 truth_metadata: Mapping | None = None,
                 overwrite: bool = False, resume: bool = False):
        if not isinstance(manifest, CaptureManifest):
            raise TypeError(f"manifest must be a CaptureManifest, not {type(manifest).__name__}")
        self.directory = Path(directory)
        self.manifest = manifest
        self.overwrite = bool(overwrite)
        self.resume = bool(resume)
        if manifest.truth is None and truth_units is not None:
            raise ValueError("truth_units given but the manifest has no truth (truth is null)")
        self.truth_units = (dict(DEFAULT_TRUTH_UNITS if truth_units is None else truth_units)
                            if manifest.truth is not None else None)
        self.truth_metadata = dict(truth_metadata or {})
        self._plan_text = dumps_json({"manifest": manifest.to_json(),
                                      "truth_units": self.truth_units,
                                      "truth_metadata": self.truth_metadata})
        self._prepare_directory()

    # --- set-up
    def _prepare_directory(self) -> None:
        directory = self.directory
        if directory.exists() and not directory.is_dir():
            raise NotADirectoryError(f"'{directory}' exists and is not a directory")
        directory.mkdir(parents=True, exist_ok=True)
        entries = sorted(os.listdir(directory))
        plan = directory / PLAN_NAME
        manifest_path = directory / MANIFEST_NAME
        if self.resume and entries:
            if manifest_path.exists() and not plan.exists():
                existing = CaptureManifest.from_json(read_json(manifest_path))
                if existing != self.manifest:
                    differences = json_differences(existing.to_json(), self.manifest.to_json())
                    raise PlanMismatchError(
                        f"'{directory}' holds a finished capture with a different manifest; "
                        "refusing to resume into it", directory,
                        [(f"manifest.{p}", a, b) for p, a, b in differences])
                return
            if not plan.exists():
                raise FileExistsError(f"cannot resume in '{directory}': it has no {PLAN_NAME} "
                                      "(not a capture started by CaptureWriter)")
            existing_plan = json.loads(plan.read_text(encoding="utf-8"))
            differences = json_differences(existing_plan, json.loads(self._plan_text))
            if differences:
                raise PlanMismatchError(f"cannot resume in '{directory}': its {PLAN_NAME} "
                                        "describes a different capture", directory, differences)
            return
        if entries and not self.overwrite:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise FileExistsError(f"'{directory}' is not empty ({len(entries)} entries: {shown}); "
                                  "pass overwrite=True to replace files of the same names or "
                                  "resume=True to continue a partial capture")
        if manifest_path.exists():
            stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%S%f")
            manifest_path.rename(directory / f"capture.superseded-{stamp}.json")
        self._remove_planned_files()
        atomic_write_text(plan, self._plan_text, overwrite=True)

    def _planned_paths(self) -> list[Path]:
        """Every file this plan writes besides the mesh and ``capture.json``: images,
        truth maps and ``truth.json``."""
        paths = [self.directory / record.path for _, record in self.manifest.records()]
        if self.manifest.truth is not None:
            paths += [self.directory / truth_map_path(self.manifest.truth, frame.index)
                      for frame in self.manifest.frames]
            paths.append(self.directory / self.manifest.truth)
        return paths

    def _remove_planned_files(self) -> None:
        """Start anew: remove earlier files at this plan's paths (``overwrite`` would replace
        them anyway), so that :meth:`completed` only ever finds images written under the
        current plan, also after an interrupt and a resume."""
        for path in self._planned_paths():
            if path.is_file() or path.is_symlink():
                path.unlink()

    # --- paths and state
    def path_of(self, frame, camera, light) -> Path:
        """Absolute path of the planned image of ``(frame, camera, light)``."""
        record = self.manifest.frame(_frame_index(frame)).image(_name(camera), _name(light))
        return self.directory / record.path

    def completed(self) -> set[tuple[int, str, str]]:
        """``(frame index, camera, light)`` of the planned images already on disk.

        Files appear under their final name only once completely written
        (atomic writes), so an existing file is a finished image.
        """
        return {(frame.index, record.camera, record.light)
                for frame, record in self.manifest.records()
                if (self.directory / record.path).is_file()}

    def missing(self) -> list[tuple[int, str, str]]:
        """``(frame index, camera, light)`` of the planned images not yet written, in plan order."""
        done = self.completed()
        return [(frame.index, record.camera, record.light)
                for frame, record in self.manifest.records()
                if (frame.index, record.camera, record.light) not in done]

    def completed_truth(self) -> set[int]:
        """Frame indices whose ground-truth maps are already on disk."""
        if self.manifest.truth is None:
            return set()
        return {frame.index for frame in self.manifest.frames
                if (self.directory / truth_map_path(self.manifest.truth, frame.index)).is_file()}

    # --- writing
    def add_image(self, frame, camera, light, channels: Mapping[str, np.ndarray]) -> Path:
        """Check and write one planned image atomically.

        Parameters
        ----------
        frame:
            Frame index (or :class:`Frame`).
        camera, light:
            Names (or :class:`Camera` / :class:`Light`).
        channels:
            Channel name -> H x W array: ``<band>.I0 ... <band>.I135`` per band
            (analyser) or ``<band>.raw`` (raw), as the plan's record says.

        Returns
        -------
        pathlib.Path
            The written file. An existing file raises ``FileExistsError``
            unless the writer was made with ``overwrite=True``.
        """
        index, camera_name, light_name = _frame_index(frame), _name(camera), _name(light)
        record = self.manifest.frame(index).image(camera_name, light_name)
        path = self.directory / record.path
        what = f"image of frame {index}, camera {camera_name!r}, light {light_name!r}"
        arrays = validate_channels(channels)
        expected = self.manifest.expected_channels(record)
        check_image_channels(arrays, expected, self.manifest.camera(camera_name).image_size,
                             record.kind, what)
        path.parent.mkdir(parents=True, exist_ok=True)
        metadata = {"frame": index, "camera": camera_name, "light": light_name, "kind": record.kind}
        return write_exr(path, {name: arrays[name] for name in expected}, metadata=metadata,
                         overwrite=self.overwrite)

    def add_truth(self, frame, maps: Mapping[str, np.ndarray]) -> Path:
        """Write the ground-truth maps of one frame (``truth/maps_f0000.exr``).

        ``maps``: channel -> T x T array; channels are parameters of
        ``truth_units`` or ``<parameter>.<band>`` (e.g. ``rho_sss.RA``).
        """
        if self.manifest.truth is None:
            raise ValueError("the manifest has no truth (truth is null): cannot add truth maps")
        index = _frame_index(frame)
        self.manifest.frame(index)  # KeyError for frames not in the plan
        relative = truth_map_path(self.manifest.truth, index)
        what = f"ground-truth maps of frame {index}"
        arrays = validate_channels(maps)
        check_truth_channels(arrays, self.truth_units, self.manifest.band_names, what)
        _check_truth_maps(arrays, None, what)
        path = self.directory / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        return write_exr(path, arrays, metadata={"frame": index}, overwrite=self.overwrite)

    def add_mesh(self, mesh) -> Path:
        """Write the manifest's mesh file: from a file path (copied byte for byte) or a
        :class:`~polarbssrdf.geometry.mesh.SurfaceMesh` (saved as OBJ, mm, OBJ UVs)."""
        if self.manifest.mesh is None:
            raise ValueError("the manifest has no mesh (mesh is null)")
        target = self.directory / self.manifest.mesh
        target.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(mesh, (str, os.PathLike)):
            data = Path(mesh).read_bytes()
        else:
            data = _obj_text(mesh).encode("utf-8")
        return atomic_write_bytes(target, data, overwrite=self.overwrite or self.resume)

    def finish(self) -> Path:
        """Write ``truth.json`` and ``capture.json`` once every planned file exists.

        Returns
        -------
        pathlib.Path
            The path of ``capture.json``.

        Raises
        ------
        FileNotFoundError
            Naming the first missing images (and how many), the mesh or truth maps.
        """
        manifest_path = self.directory / MANIFEST_NAME
        plan = self.directory / PLAN_NAME
        if manifest_path.exists() and not plan.exists():
            return manifest_path  # resumed a finished capture
        missing = self.missing()
        if missing:
            shown = "; ".join(f"frame {f}, camera {c!r}, light {l!r}" for f, c, l in missing[:3])
            raise FileNotFoundError(f"cannot finish the capture in '{self.directory}': "
                                    f"{len(missing)} planned image(s) not written ({shown}"
                                    f"{'; ...' if len(missing) > 3 else ''})")
        if self.manifest.mesh is not None and not (self.directory / self.manifest.mesh).is_file():
            raise FileNotFoundError(f"cannot finish the capture in '{self.directory}': the mesh "
                                    f"'{self.manifest.mesh}' was not written (call add_mesh)")
        if self.manifest.truth is not None:
            self._write_truth_manifest()
        replace = self.overwrite or self.resume
        atomic_write_text(manifest_path, dumps_json(self.manifest.to_json()), overwrite=replace)
        plan.unlink(missing_ok=True)
        return manifest_path

    def _write_truth_manifest(self) -> None:
        records, size = [], None
        for frame in self.manifest.frames:
            relative = truth_map_path(self.manifest.truth, frame.index)
            if not (self.directory / relative).is_file():
                continue
            channels, _ = read_exr(self.directory / relative)
            size = _check_truth_maps(channels, size, f"'{relative}'")
            records.append(TruthMapRecord(frame.index, relative, tuple(channels)))
        if not records:
            raise FileNotFoundError(f"cannot finish the capture in '{self.directory}': the manifest "
                                    "has truth but no ground-truth maps were written (add_truth)")
        truth = TruthManifest(size, self.truth_units, tuple(records), self.truth_metadata)
        atomic_write_text(self.directory / self.manifest.truth, dumps_json(truth.to_json()),
                          overwrite=self.overwrite or self.resume)


def write_capture(directory: str | os.PathLike, manifest: CaptureManifest,
                  images: Mapping[str, Mapping[str, np.ndarray]],
                  truth: GroundTruth | None = None, overwrite: bool = False,
                  mesh=None) -> Path:
    """Write a complete capture in one go.

    Parameters
    ----------
    directory:
        Output directory; must be empty or absent unless ``overwrite=True``
        (which replaces files of the same names and never deletes others).
    manifest:
        The :class:`~polarbssrdf.io.manifest.CaptureManifest`.
    images:
        Image path (as in the manifest's records) -> channel name -> H x W array.
        Must cover every record exactly.
    truth:
        :class:`~polarbssrdf.io.truth.GroundTruth` when ``manifest.truth`` is set.
    mesh:
        Mesh file path or ``SurfaceMesh`` when ``manifest.mesh`` is set.

    Returns
    -------
    pathlib.Path
        Path of ``capture.json`` (written last).
    """
    planned = {record.path: (frame, record) for frame, record in manifest.records()}
    unknown = sorted(set(images) - set(planned))
    if unknown:
        raise ValueError(f"images given for paths the manifest does not name: {unknown[:3]}")
    absent = [path for path in planned if path not in images]
    if absent:
        raise ValueError(f"no image data for {len(absent)} manifest record(s), e.g. '{absent[0]}'")
    if (truth is None) != (manifest.truth is None):
        raise ValueError("pass truth exactly when the manifest has a truth path "
                         f"(manifest.truth is {manifest.truth!r}, truth is "
                         f"{'given' if truth is not None else 'None'})")
    if (mesh is None) != (manifest.mesh is None):
        raise ValueError(f"pass mesh exactly when the manifest names one (manifest.mesh is "
                         f"{manifest.mesh!r})")
    writer = CaptureWriter(directory, manifest, overwrite=overwrite,
                           truth_units=None if truth is None else truth.units,
                           truth_metadata=None if truth is None else truth.metadata)
    for path, (frame, record) in planned.items():
        writer.add_image(frame, record.camera, record.light, images[path])
    if truth is not None:
        for index, maps in truth.maps.items():
            writer.add_truth(index, maps)
    if mesh is not None:
        writer.add_mesh(mesh)
    return writer.finish()


# --------------------------------------------------------------------------- reader
class Capture:
    """A loaded capture: its manifest, ground truth description and lazy image access.

    Use :func:`load_capture` to make one.
    """

    def __init__(self, directory: Path, manifest: CaptureManifest, truth: TruthManifest | None):
        self.directory = directory
        self.manifest = manifest
        self.truth = truth

    def __repr__(self) -> str:
        m = self.manifest
        return (f"Capture('{self.directory}', {len(m.frames)} frames, {len(m.cameras)} cameras, "
                f"{len(m.lights)} lights, {len(m.bands)} bands)")

    @property
    def mesh_path(self) -> Path | None:
        return None if self.manifest.mesh is None else self.directory / self.manifest.mesh

    def load_mesh(self):
        """The capture's mesh as a :class:`~polarbssrdf.geometry.mesh.SurfaceMesh` (mm)."""
        if self.mesh_path is None:
            raise ValueError(f"capture '{self.directory}' has no mesh")
        from polarbssrdf.geometry.mesh import load_mesh

        return load_mesh(self.mesh_path)

    def record(self, frame, camera, light) -> ImageRecord:
        return self.manifest.frame(_frame_index(frame)).image(_name(camera), _name(light))

    def image_path(self, frame, camera, light) -> Path:
        return self.directory / self.record(frame, camera, light).path

    def images(self, frame, camera, light) -> dict[str, np.ndarray]:
        """Channel name -> H x W float32 array of one image, read now and checked.

        ``frame`` is a frame index (or :class:`Frame`), ``camera`` and ``light``
        names (or objects).
        """
        record = self.record(frame, camera, light)
        return _read_image(self.directory, self.manifest, record)

    def truth_maps(self, frame) -> dict[str, np.ndarray]:
        """Channel -> T x T float32 ground-truth map of one frame."""
        if self.truth is None:
            raise ValueError(f"capture '{self.directory}' has no ground truth")
        record = self.truth.record(_frame_index(frame))
        return _read_truth(self.directory, self.truth, record)


def _read_image(directory: Path, manifest: CaptureManifest, record: ImageRecord) -> dict:
    path = directory / record.path
    channels, _ = read_exr(path)
    check_image_channels(channels, manifest.expected_channels(record),
                         manifest.camera(record.camera).image_size, record.kind, f"'{path}'")
    return {name: channels[name] for name in manifest.expected_channels(record)}


def _read_truth(directory: Path, truth: TruthManifest, record: TruthMapRecord) -> dict:
    path = directory / record.path
    channels, _ = read_exr(path)
    if set(channels) != set(record.channels):
        raise CaptureFormatError("", f"'{path}': channels {sorted(channels)} differ from those "
                                     f"truth.json lists {sorted(record.channels)}")
    _check_truth_maps(channels, truth.texture_size, f"'{path}'")
    return {name: channels[name] for name in record.channels}


def _with_source(error: CaptureFormatError, source: Path) -> CaptureFormatError:
    """The error with the file's path in front of its field path."""
    return CaptureFormatError(f"{source}: {error.field}" if error.field else str(source),
                              error.problem)


def load_capture(directory: str | os.PathLike, check_images: bool = True,
                 frames=None) -> Capture:
    """Load and validate a capture directory.

    Parameters
    ----------
    directory:
        Directory holding ``capture.json``.
    check_images:
        Also read every image (and truth map) and check its channel set, size,
        finiteness and, for analyser images, non-negativity. Without it only
        the manifests and the existence of every referenced file are checked.
    frames:
        Frame indices whose image files are checked (default: every frame). A
        stage that runs frames independently checks each frame's images when
        it starts that frame, so one missing image fails only its frame.

    Returns
    -------
    Capture

    Raises
    ------
    FileNotFoundError
        The directory, ``capture.json`` or a referenced file is missing.
    ValueError
        (:class:`~polarbssrdf.io.manifest.CaptureFormatError`) naming the file
        and the field or problem: malformed JSON (line and column), invalid
        manifest, wrong image contents.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"capture directory '{directory}' does not exist")
    manifest_path = directory / MANIFEST_NAME
    if not manifest_path.is_file():
        hint = (f" (it has {PLAN_NAME}: the capture was not finished)"
                if (directory / PLAN_NAME).exists() else "")
        raise FileNotFoundError(f"'{directory}' has no {MANIFEST_NAME}{hint}")
    document = read_json(manifest_path)
    try:
        manifest = CaptureManifest.from_json(document)
    except CaptureFormatError as error:
        raise _with_source(error, manifest_path) from None
    checked = None if frames is None else {int(f) for f in frames}
    for k, frame in enumerate(manifest.frames):
        if checked is not None and frame.index not in checked:
            continue
        for i, record in enumerate(frame.images):
            if not (directory / record.path).is_file():
                raise FileNotFoundError(f"{manifest_path}: frames[{k}].images[{i}].path: image file "
                                        f"'{directory / record.path}' does not exist")
    if manifest.mesh is not None and not (directory / manifest.mesh).is_file():
        raise FileNotFoundError(f"{manifest_path}: mesh: mesh file '{directory / manifest.mesh}' "
                                "does not exist")
    truth = None
    if manifest.truth is not None:
        truth_path = directory / manifest.truth
        if not truth_path.is_file():
            raise FileNotFoundError(f"{manifest_path}: truth: ground-truth file '{truth_path}' "
                                    "does not exist")
        document = read_json(truth_path)
        try:
            truth = TruthManifest.from_json(document)
            frames = {frame.index for frame in manifest.frames}
            for i, record in enumerate(truth.maps):
                if record.frame not in frames:
                    raise CaptureFormatError(f"maps[{i}].frame", f"frame {record.frame} is not in "
                                                                 "the capture")
                check_truth_channels(record.channels, truth.units, manifest.band_names,
                                     f"maps[{i}].channels")
        except CaptureFormatError as error:
            raise _with_source(error, truth_path) from None
        for i, record in enumerate(truth.maps):
            if not (directory / record.path).is_file():
                raise FileNotFoundError(f"{truth_path}: maps[{i}].path: map file "
                                        f"'{directory / record.path}' does not exist")
    capture = Capture(directory, manifest, truth)
    if check_images:
        for frame, record in manifest.records():
            if checked is None or frame.index in checked:
                _read_image(directory, manifest, record)
        if truth is not None:
            for record in truth.maps:
                _read_truth(directory, truth, record)
    return capture
