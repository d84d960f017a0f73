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

from polarbssrdf.errors import CommandError

EXR_FILE = "polarization.exr"
"""Name of the EXR image written into OUTDIR."""

METADATA_FILE = "render.json"
"""Name of the JSON record written into OUTDIR (last, once everything else is written)."""

RENDER_SCHEMA_VERSION = 1
"""Schema version of ``render.json`` and of the EXR's metadata."""

DEFAULT_VARIANT = "llvm_ad_mono_polarized"

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
        message = re.sub(r"^\[[^\]]*\]\s*", "", str(error).strip())
        raise CommandError(f"cannot load scene '{path}': {message}") from None


def check_scene(scene, path: Path) -> None:
    """Check that the scene renders Stokes images: a ``stokes`` integrator and a usable film.

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
    film = scene.sensors()[0].film()
    if film.class_name() == "SpecFilm":
        raise CommandError(f"scene '{path}' uses a 'specfilm', which does not work with "
                           "'stokes'; use 'hdrfilm'")


def render_scene(scene, spp: int | None, seed: int):
    """Render the scene's first sensor and wait for the result.

    Parameters
    ----------
    scene:
        A scene with a ``stokes`` integrator.
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

    sensor = scene.sensors()[0]
    spp = int(spp) if spp is not None else int(sensor.sampler().sample_count())
    start = time.perf_counter()
    image = mi.render(scene, sensor=sensor, seed=seed, spp=spp)
    dr.eval(image)
    dr.sync_thread()
    seconds = time.perf_counter() - start
    return np.array(image), render_channel_names(sensor.film()), spp, seconds


def run_metadata(args, scene_path: Path, defines: dict, spp: int, shape: tuple[int, int],
                 channels: list[str], timing: dict) -> dict:
    """The JSON record of a run (written to ``render.json`` and into the EXR).

    Parameters
    ----------
    args:
        The parsed command line.
    scene_path:
        The scene file.
    defines:
        The ``-D`` scene parameters.
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


def run(args) -> int:
    """Execute ``polarbssrdf render`` for parsed arguments; returns the exit status 0."""
    from polarbssrdf.io import atomic_write_text, write_exr
    from polarbssrdf.render.stokes_images import polarization_channels, write_previews

    start = time.perf_counter()
    scene_path, outdir = Path(args.scene), Path(args.outdir)
    defines = parse_defines(args.define)
    paths = output_paths(outdir)
    if not scene_path.exists():
        raise FileNotFoundError(f"scene file '{scene_path}' does not exist")
    check_outputs(outdir, paths, scene_path, args.overwrite)
    select_variant(args.variant)

    import mitsuba as mi

    load_start = time.perf_counter()
    scene = load_scene(scene_path, defines)
    check_scene(scene, scene_path)
    load_seconds = time.perf_counter() - load_start
    image, names, spp, render_seconds = render_scene(scene, args.spp, args.seed)
    channels = polarization_channels(image, names, monochrome=bool(mi.is_monochromatic))

    write_start = time.perf_counter()
    outdir.mkdir(parents=True, exist_ok=True)
    timing = {"load": round(load_seconds, 4), "render": round(render_seconds, 4)}
    metadata = run_metadata(args, scene_path, defines, spp, image.shape[:2], list(channels),
                            timing)
    write_exr(paths["exr"], channels, metadata, overwrite=args.overwrite)
    previews, settings = write_previews(outdir, channels, overwrite=args.overwrite)
    metadata["previews"] = {name: path.name for name, path in previews.items()}
    metadata["preview_settings"] = settings
    metadata["files"] = {"exr": paths["exr"].name}
    timing["write"] = round(time.perf_counter() - write_start, 4)
    timing["total"] = round(time.perf_counter() - start, 4)
    atomic_write_text(paths["json"], json.dumps(metadata, indent=2) + "\n",
                      overwrite=args.overwrite)

    height, width = image.shape[:2]
    print(f"polarbssrdf render: {width}x{height}, {spp} spp, {args.variant}: "
          f"wrote {paths['exr']}, {paths['json']}, {previews['preview']} and "
          f"{len(previews) - 1} more previews in {outdir} "
          f"(render {render_seconds:.2f} s, total {timing['total']:.2f} s)")
    return 0
