"""The ``polarbssrdf render`` command: render a polarized scene to EXR and PNG previews.

``polarbssrdf render SCENE.xml OUTDIR`` loads a Mitsuba scene whose
integrator is ``stokes`` (with the package's plugins registered), renders it
and writes into ``OUTDIR``:

* ``polarization.exr``: float32 channels ``I0, I45, I90, I135, S0, S1, S2,
  S3`` (``.R/.G/.B``-suffixed in RGB and spectral variants) in the image
  Stokes frame (x = image right, y = image up), with the run's metadata;
* ``render.json``: the run's parameters, timing and channel list;
* PNG previews (:data:`polarbssrdf.render.stokes_images.PREVIEW_FILES`) and
  the contact sheet ``preview.png``.

``--sensor`` picks the camera: its ``id`` in the XML, its index in the
scene's sensor list (default 0, the first), or ``all``, which renders every
sensor into its own subdirectory ``OUTDIR/<sensor id>/`` (``sensorNN`` for a
sensor without an id) holding the same files. ``render.json`` records the
sensor's index and id.

Earlier results in ``OUTDIR`` are only replaced with ``--overwrite``; other
files there are never touched. Every file is written atomically.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import time
from pathlib import Path

from polarbssrdf.errors import CommandError, plugin_error_message

EXR_FILE = "polarization.exr"
"""Name of the EXR image written into OUTDIR."""

METADATA_FILE = "render.json"
"""Name of the JSON record written into OUTDIR (last, once everything else is written)."""

RENDER_SCHEMA_VERSION = 1
"""Schema version of ``render.json`` and of the EXR's metadata."""

DEFAULT_VARIANT = "llvm_ad_mono_polarized"

ALL_SENSORS = "all"
"""``--sensor`` value that renders every sensor of the scene, each into ``OUTDIR/<id>/``."""

_DEFINE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _integer_at_least(minimum: int):
    """argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got '{text}'") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
        return value

    return parse


def register(subparsers) -> None:
    """Add the ``render`` command to the ``polarbssrdf`` argument parser.

    Parameters
    ----------
    subparsers:
        The object returned by ``ArgumentParser.add_subparsers``.
    """
    parser = subparsers.add_parser(
        "render",
        help="render a polarized Mitsuba scene to Stokes/analyser EXR and PNG previews",
        description=(
            "Render a Mitsuba scene whose integrator is 'stokes' (with the pbssrdf and ppoint "
            f"plugins registered) and write {EXR_FILE} (I0, I45, I90, I135, S0..S3), "
            f"{METADATA_FILE} and PNG previews into OUTDIR."),
    )
    parser.add_argument("scene", metavar="SCENE.xml", help="Mitsuba scene file")
    parser.add_argument("outdir", metavar="OUTDIR",
                        help="output directory (created if missing)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help=f"polarized Mitsuba variant (default: {DEFAULT_VARIANT})")
    parser.add_argument("--spp", type=_integer_at_least(1), default=None,
                        help="samples per pixel (default: the scene's sampler)")
    parser.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                        help="set a scene <default> parameter, e.g. -D resolution=64 "
                             "(repeatable; the last value of a name wins)")
    parser.add_argument("--seed", type=_integer_at_least(0), default=0,
                        help="sampler seed (default: 0)")
    parser.add_argument("--sensor", default="0", metavar="ID|INDEX|all",
                        help="the camera to render: its id in the XML, its index among the "
                             "scene's sensors (default: 0, the first), or 'all' to render "
                             "each sensor into OUTDIR/<sensor id>/")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results of an earlier run in OUTDIR")
    parser.set_defaults(run=run)


def parse_defines(items: list[str]) -> dict[str, str]:
    """Scene parameters from ``-D NAME=VALUE`` arguments.

    Parameters
    ----------
    items:
        Strings ``"NAME=VALUE"``; NAME is an identifier, VALUE any string.

    Returns
    -------
    dict
        NAME -> VALUE (strings, as Mitsuba's XML parser takes them).
    """
    defines = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not _DEFINE_NAME.match(name):
            raise CommandError(f"invalid -D '{item}': expected NAME=VALUE with NAME an "
                               "identifier, e.g. -D spp=64")
        defines[name] = value
    return defines


def output_paths(outdir: Path) -> dict[str, Path]:
    """Every file a run writes into ``outdir``: ``exr``, ``json`` and the PNG previews."""
    from polarbssrdf.render.stokes_images import CONTACT_SHEET_FILE, PREVIEW_FILES

    paths = {"exr": outdir / EXR_FILE, "json": outdir / METADATA_FILE,
             "preview": outdir / CONTACT_SHEET_FILE}
    paths.update({name: outdir / file for name, file in PREVIEW_FILES.items()})
    return paths


def check_outputs(outdir: Path, paths: dict[str, Path], scene: Path, overwrite: bool) -> None:
    """Refuse to clobber earlier results (unless ``overwrite``) or the scene itself.

    Parameters
    ----------
    outdir:
        The output directory (may not exist yet).
    paths:
        The files the run will write (:func:`output_paths`).
    scene:
        The scene file, an input that is never overwritten.
    overwrite:
        Allow replacing earlier results.
    """
    if outdir.exists() and not outdir.is_dir():
        raise CommandError(f"output directory '{outdir}' exists and is not a directory")
    scene_resolved = scene.resolve()
    for path in paths.values():
        if path.resolve() == scene_resolved:
            raise CommandError(f"output '{path}' would overwrite the scene file; "
                               "choose another OUTDIR")
    existing = [path.name for path in paths.values() if path.exists()]
    if existing and not overwrite:
        raise CommandError(
            f"output directory '{outdir}' already holds results of an earlier run "
            f"({', '.join(sorted(existing))}); pass --overwrite to replace them "
            "(other files in it are never touched)")


def select_variant(variant: str) -> None:
    """Activate a polarized Mitsuba variant and register the package's plugins in it.

    Parameters
    ----------
    variant:
        A Mitsuba variant name containing ``polarized``.
    """
    import mitsuba as mi

    import polarbssrdf

    available = list(mi.variants())
    polarized = [v for v in available if "polarized" in v]
    if variant not in available:
        raise CommandError(f"unknown Mitsuba variant '{variant}'; polarized variants "
                           f"available: {', '.join(polarized)}")
    if "polarized" not in variant:
        raise CommandError(f"variant '{variant}' is not polarized: rendering Stokes images "
                           "needs the 'stokes' integrator, which only works in polarized "
                           f"variants ({', '.join(polarized)})")
    try:
        mi.set_variant(variant)
    except (ImportError, RuntimeError) as error:  # e.g. a CUDA variant without a GPU
        raise CommandError(f"cannot activate Mitsuba variant '{variant}': {error}") from None
    polarbssrdf.register_plugins()


def load_scene(path: Path, defines: dict[str, str]):
    """Load a Mitsuba scene file in the active variant.

    Parameters
    ----------
    path:
        The scene XML file.
    defines:
        Values for the scene's ``<default>`` parameters.

    Returns
    -------
    mitsuba.Scene
    """
    import mitsuba as mi

    if not path.exists():
        raise FileNotFoundError(f"scene file '{path}' does not exist")
    if not path.is_file():
        raise CommandError(f"scene '{path}' is not a file")
    try:
        return mi.load_file(str(path), **defines)
    except RuntimeError as error:
        raise CommandError(f"cannot load scene '{path}': {plugin_error_message(error)}") from None


def check_integrator(scene, path: Path) -> None:
    """Check that the scene renders Stokes images: a ``stokes`` integrator and a sensor.

    Parameters
    ----------
    scene:
        The loaded scene.
    path:
        Its file, for the error messages.
    """
    integrator = scene.integrator()
    name = integrator.class_name() if integrator is not None else "none"
    if name != "StokesIntegrator":
        raise CommandError(
            f"scene '{path}' uses the integrator {name}, not 'stokes': wrap it, e.g. "
            '<integrator type="stokes"><integrator type="direct"/></integrator>')
    if len(scene.sensors()) == 0:
        raise CommandError(f"scene '{path}' has no sensor")


def sensor_name(sensor, index: int) -> str:
    """The sensor's ``id`` in the XML, or ``sensorNN`` (its index) if it has none."""
    return sensor.id() or f"sensor{index:02d}"


def _sensor_list(sensors) -> str:
    """``0 cam00, 1 cam01, ...``: the sensors a user can pick, for error messages."""
    return ", ".join(f"{k} {sensor_name(s, k)}" for k, s in enumerate(sensors))


def select_sensors(scene, choice: str, path: Path) -> list[tuple[int, str]]:
    """The sensors that ``--sensor`` picks, as ``(index, name)`` pairs.

    Parameters
    ----------
    scene:
        The loaded scene (with at least one sensor).
    choice:
        A sensor id from the XML, an index into ``scene.sensors()``, or
        :data:`ALL_SENSORS`. An id wins over an index of the same spelling.
    path:
        The scene file, for the error messages.
    """
    sensors = scene.sensors()
    names = [sensor_name(s, k) for k, s in enumerate(sensors)]
    text = choice.strip()
    if text == ALL_SENSORS:
        if len(set(names)) != len(names):  # each needs its own subdirectory
            raise CommandError(f"scene '{path}': sensor ids are not unique ({', '.join(names)}); "
                               "--sensor all writes OUTDIR/<sensor id>/ per sensor")
        return list(enumerate(names))
    if text in names:
        index = names.index(text)
        return [(index, names[index])]
    if text.isdigit() and int(text) < len(sensors):
        return [(int(text), names[int(text)])]
    raise CommandError(f"scene '{path}' has no sensor '{choice}'; its sensors are (index id): "
                       f"{_sensor_list(sensors)}; pass --sensor ID, INDEX or all")


def check_film(sensor, label: str, path: Path, defines: dict[str, str]) -> None:
    """Check that the sensor's film can be rendered: at least 1 x 1 pixels, not a ``specfilm``.

    Parameters
    ----------
    sensor:
        A sensor of the loaded scene (its film already has the ``-D`` values).
    label:
        How to name it in the error messages, e.g. ``"3 (cam03)"``.
    path:
        The scene file, for the error messages.
    defines:
        The ``-D`` scene parameters, named in the message when a size is wrong.
    """
    film = sensor.film()
    if film.class_name() == "SpecFilm":
        raise CommandError(f"scene '{path}' uses a 'specfilm', which does not work with "
                           "'stokes'; use 'hdrfilm'")
    # A zero-sized film loads fine but crashes Dr.Jit in the render ("incompatible sizes").
    for part, (width, height) in (("film", film.size()), ("film crop", film.crop_size())):
        if width < 1 or height < 1:
            given = ", ".join(f"-D {k}={v}" for k, v in defines.items())
            hint = f" (with {given})" if given else ""
            raise CommandError(f"scene '{path}': sensor {label} has a {part} of "
                               f"{width} x {height} pixels{hint}; width and height must be "
                               "at least 1")


def render_sensor(scene, index: int, spp: int | None, seed: int):
    """Render one sensor of the scene and wait for the result.

    Parameters
    ----------
    scene:
        A scene with a ``stokes`` integrator.
    index:
        Index of the sensor in ``scene.sensors()``.
    spp:
        Samples per pixel, or ``None`` for the sampler's own count.
    seed:
        Sampler seed.

    Returns
    -------
    image : numpy.ndarray
        H x W x C render.
    channel_names : list of str
        Its C channel names.
    spp : int
        The samples per pixel actually used.
    seconds : float
        Wall-clock render time including kernel compilation and execution.
    """
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    from polarbssrdf.render.stokes_images import render_channel_names

    sensor = scene.sensors()[index]
    spp = int(spp) if spp is not None else int(sensor.sampler().sample_count())
    start = time.perf_counter()
    image = mi.render(scene, sensor=sensor, seed=seed, spp=spp)
    dr.eval(image)
    dr.sync_thread()
    seconds = time.perf_counter() - start
    return np.array(image), render_channel_names(sensor.film()), spp, seconds


def run_metadata(args, scene_path: Path, defines: dict, sensor: dict, spp: int,
                 shape: tuple[int, int], channels: list[str], timing: dict) -> dict:
    """The JSON record of a run (written to ``render.json`` and into the EXR).

    Parameters
    ----------
    args:
        The parsed command line.
    scene_path:
        The scene file.
    defines:
        The ``-D`` scene parameters.
    sensor:
        ``{"index": k, "id": name}`` of the rendered sensor.
    spp:
        Samples per pixel used.
    shape:
        Image (height, width) in pixels.
    channels:
        EXR channel names, in order.
    timing:
        Durations in seconds.
    """
    import drjit as dr
    import mitsuba as mi

    import polarbssrdf

    return {
        "schema_version": RENDER_SCHEMA_VERSION,
        "kind": "polarbssrdf.render",
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "scene": str(scene_path.resolve()),
        "variant": args.variant,
        "sensor": sensor,
        "spp": spp,
        "seed": args.seed,
        "defines": defines,
        "resolution": {"width": shape[1], "height": shape[0]},
        "channels": channels,
        "stokes_frame": "x = image right, y = image up; I(theta) = (S0 + S1 cos 2theta + "
                        "S2 sin 2theta) / 2, theta counter-clockwise from image right",
        "units": "radiance of the scene (lengths in mm)",
        "timing_s": timing,
        "versions": {"polarbssrdf": polarbssrdf.__version__, "mitsuba": mi.__version__,
                     "drjit": dr.__version__},
    }


def sensor_outdirs(outdir: Path, sensors: list[tuple[int, str]], choice: str
                   ) -> dict[int, Path]:
    """Sensor index -> the directory its results go to: OUTDIR, or OUTDIR/<id>/ for ``all``."""
    if choice.strip() != ALL_SENSORS:
        return {index: outdir for index, _ in sensors}
    for _, name in sensors:
        if name in (".", "..") or "/" in name or "\\" in name:
            raise CommandError(f"sensor id '{name}' cannot name a subdirectory of '{outdir}' "
                               "(--sensor all); render it by index instead")
    return {index: outdir / name for index, name in sensors}


def render_one(args, scene, scene_path: Path, defines: dict, index: int, name: str,
               outdir: Path, load_seconds: float, started: float) -> None:
    """Render sensor ``index`` and write its EXR, previews and ``render.json`` into ``outdir``.

    ``render.json`` is written last, so a directory with it holds a complete result.
    ``started`` is the command's start (``time.perf_counter()``): ``timing_s.total``
    counts from there, set-up included.
    """
    import mitsuba as mi

    from polarbssrdf.io import atomic_write_text, write_exr
    from polarbssrdf.render.stokes_images import polarization_channels, write_previews

    paths = output_paths(outdir)
    image, names, spp, render_seconds = render_sensor(scene, index, args.spp, args.seed)
    channels = polarization_channels(image, names, monochrome=bool(mi.is_monochromatic))

    write_start = time.perf_counter()
    outdir.mkdir(parents=True, exist_ok=True)
    timing = {"load": round(load_seconds, 4), "render": round(render_seconds, 4)}
    metadata = run_metadata(args, scene_path, defines, {"index": index, "id": name}, spp,
                            image.shape[:2], list(channels), timing)
    write_exr(paths["exr"], channels, metadata, overwrite=args.overwrite)
    previews, settings = write_previews(outdir, channels, overwrite=args.overwrite)
    metadata["previews"] = {key: path.name for key, path in previews.items()}
    metadata["preview_settings"] = settings
    metadata["files"] = {"exr": paths["exr"].name}
    timing["write"] = round(time.perf_counter() - write_start, 4)
    timing["total"] = round(time.perf_counter() - started, 4)
    atomic_write_text(paths["json"], json.dumps(metadata, indent=2) + "\n",
                      overwrite=args.overwrite)

    height, width = image.shape[:2]
    print(f"polarbssrdf render: sensor {index} ({name}), {width}x{height}, {spp} spp, "
          f"{args.variant}: wrote {paths['exr']}, {paths['json']}, {previews['preview']} and "
          f"{len(previews) - 1} more previews in {outdir} "
          f"(render {render_seconds:.2f} s, total {timing['total']:.2f} s)")


def run(args) -> int:
    """Execute ``polarbssrdf render`` for parsed arguments; returns the exit status 0."""
    started = time.perf_counter()
    scene_path, outdir = Path(args.scene), Path(args.outdir)
    defines = parse_defines(args.define)
    if not scene_path.exists():
        raise FileNotFoundError(f"scene file '{scene_path}' does not exist")
    if args.sensor.strip() != ALL_SENSORS:  # fail before the slow variant set-up
        check_outputs(outdir, output_paths(outdir), scene_path, args.overwrite)
    select_variant(args.variant)

    load_start = time.perf_counter()
    scene = load_scene(scene_path, defines)
    check_integrator(scene, scene_path)
    sensors = select_sensors(scene, args.sensor, scene_path)
    for index, name in sensors:
        check_film(scene.sensors()[index], f"{index} ({name})", scene_path, defines)
    outdirs = sensor_outdirs(outdir, sensors, args.sensor)
    check_outputs(outdir, {}, scene_path, args.overwrite)  # OUTDIR itself must be a directory
    for directory in outdirs.values():  # all of them before the first render
        check_outputs(directory, output_paths(directory), scene_path, args.overwrite)
    load_seconds = time.perf_counter() - load_start
    for index, name in sensors:
        render_one(args, scene, scene_path, defines, index, name, outdirs[index], load_seconds,
                   started)
    return 0
