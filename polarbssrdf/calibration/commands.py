"""The ``polarbssrdf calibrate`` commands: geometry, colour, spectral, sphere.

Inputs and outputs are documented in ``docs/calibration.md``. Outputs are
JSON with a ``schema`` and ``schema_version``, written atomically; an
existing output is only replaced with ``--overwrite``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from polarbssrdf.errors import CommandError

__all__ = ["register"]

COLOUR_SCHEMA = "polarbssrdf.calibration.colour"
SPECTRAL_SCHEMA = "polarbssrdf.calibration.spectral"
SPHERE_SCHEMA = "polarbssrdf.calibration.sphere"
SCHEMA_VERSION = 1


OVERWRITE_HELP = "replace the output files if they exist (default: refuse)"


def register(subparsers) -> None:
    """Add ``calibrate`` (with sub-commands) to the ``polarbssrdf`` parser."""
    # Light modules only: they quote their defaults in the help without importing
    # colour-science or OpenCV, which `polarbssrdf --help` must not pay for.
    from .colour_matrix import DEFAULT_CHECKER
    from .spectral_response import DEFAULT_SMOOTHNESS

    parser = subparsers.add_parser(
        "calibrate", help="calibrate cameras (ChArUco), colour, spectral response, sphere gains",
        description="Calibration toolkit (supplement section 3.2); see docs/calibration.md.")
    commands = parser.add_subparsers(dest="calibration", required=True, metavar="WHAT")

    geometry = commands.add_parser(
        "geometry", help="intrinsics and rig extrinsics from ChArUco images",
        description="DIR holds one folder per camera with images named by shot; the same shot "
                    "name in several folders is one simultaneous view. Writes CAMERAS.json "
                    "(world = first camera, mm).")
    geometry.add_argument("directory", metavar="DIR", type=Path,
                          help="folder of camera folders, each with one image per shot")
    geometry.add_argument("--board", required=True, type=Path, metavar="BOARD.json",
                          help="the ChArUco board: squares_x, squares_y, square_mm, marker_mm, "
                               "dictionary (see docs/calibration.md)")
    geometry.add_argument("--out", required=True, type=Path, metavar="CAMERAS.json",
                          help="output: intrinsics and extrinsics per camera (world = reference "
                               "camera, mm)")
    geometry.add_argument("--model", choices=("opencv", "pinhole"), default="opencv",
                          help="opencv: fx, fy, 5 distortion coefficients; pinhole: fx = fy, no "
                               "distortion (renderable by Mitsuba as is) (default: opencv)")
    geometry.add_argument("--reference", help="camera that defines the world frame "
                                              "(default: first folder in sorted order)")
    geometry.add_argument("--sensor", default="ideal",
                          help="sensor written per camera: ideal, IMX250MZR or IMX250MYR "
                               "(default: ideal)")
    geometry.add_argument("--min-views", type=int, default=4,
                          help="fewest views with a detected board per camera (default 4)")
    geometry.add_argument("--outlier-factor", type=float, default=3.0,
                          help="reject the worst view while its RMS exceeds max(FACTOR x median "
                               "view RMS, FLOOR) and recalibrate (default 3)")
    geometry.add_argument("--outlier-floor-px", type=float, default=1.0,
                          help="FLOOR of the outlier rule in px (default 1)")
    geometry.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    geometry.set_defaults(run=run_geometry)

    colour = commands.add_parser(
        "colour", help="3 x 3 colour matrix from colour-checker patches",
        description="PATCHES.csv: header 'patch,R,G,B', linear camera values per patch, in chart "
                    "order or named by the chart's patch names.")
    colour.add_argument("patches", metavar="PATCHES.csv", type=Path,
                        help="linear camera R, G, B per chart patch")
    colour.add_argument("--out", required=True, type=Path, metavar="COLOUR.json",
                        help="output: the 3 x 3 matrix and per-patch residuals")
    colour.add_argument("--checker", default=None,
                        help=f"colour-science chart name (default: {DEFAULT_CHECKER!r})")
    colour.add_argument("--space", choices=("sRGB", "XYZ"), default="sRGB",
                        help="reference space of the matrix: linear sRGB (D65) or CIE XYZ "
                             "(default: sRGB)")
    colour.add_argument("--weighting", choices=("relative", "none"), default="relative",
                        help="relative: every patch counts by its relative error (default); "
                             "none: plain least squares")
    colour.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    colour.set_defaults(run=run_colour)

    spectral = commands.add_parser(
        "spectral", help="camera spectral response, filter transmittance and bands",
        description="Response per channel from narrow-band images of a white reference.")
    spectral.add_argument("--lights", required=True, type=Path, metavar="LIGHTS.csv",
                          help="'wavelength_nm,<band>,...': light spectrum of each band")
    spectral.add_argument("--reference", required=True, type=Path, metavar="REFLECTANCE.csv",
                          help="'wavelength_nm,reflectance' of the white target")
    spectral.add_argument("--measurements", required=True, type=Path, metavar="MEASUREMENTS.csv",
                          help="'band,<channel>,...': camera value of the target per band")
    spectral.add_argument("--filter", action="append", default=[], metavar="NAME=FILTER.csv",
                          help="'wavelength_nm,incident,transmitted[,dark]' spectrometer readings "
                               "of a filter; repeat for several filters (default: no filter)")
    spectral.add_argument("--stage-light", type=Path, metavar="LIGHT.csv",
                          help="'wavelength_nm,value': the stage light for the bands "
                               "(default: the package's default LED)")
    spectral.add_argument("--smoothness", type=float, default=None,
                          help="weight of the second-difference penalty on the responses, "
                               f"dimensionless (default: {DEFAULT_SMOOTHNESS:g})")
    spectral.add_argument("--out", required=True, type=Path, metavar="SPECTRAL.json",
                          help="output: responses, filter transmittances and bands")
    spectral.add_argument("--bands-out", type=Path, metavar="BANDS.json",
                          help="also write the bands as a band file (polarbssrdf.spectral.read_bands) "
                               "(default: not written)")
    spectral.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    spectral.set_defaults(run=run_spectral)

    sphere = commands.add_parser(
        "sphere", help="cross-camera gains from images of a white reference sphere",
        description="DIR holds one linear image per camera, named <camera>.<ext> (EXR, or 16-bit "
                    "or float TIFF). 8-bit and PNG/JPEG images are display-encoded (sRGB) and "
                    "refused unless --decode-srgb.")
    sphere.add_argument("directory", metavar="DIR", type=Path,
                        help="folder with one white-sphere image per camera")
    sphere.add_argument("--out", required=True, type=Path, metavar="GAINS.json",
                        help="output: the gain per camera and channel")
    sphere.add_argument("--reference", help="camera with gain 1 (default: first in sorted order)")
    sphere.add_argument("--decode-srgb", action="store_true",
                        help="decode integer images (PNG, JPEG, TIFF, ...) from sRGB to linear "
                             "instead of refusing 8-bit and PNG/JPEG images; float images are "
                             "always taken as linear (default: off)")
    sphere.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    sphere.set_defaults(run=run_sphere)


# --------------------------------------------------------------------------- helpers
def _check_output(path: Path, overwrite: bool, inputs=()) -> None:
    path = Path(path)
    if not path.parent.is_dir():
        raise CommandError(f"output directory '{path.parent}' does not exist")
    for item in inputs:
        if item is not None and Path(item).exists() and Path(item).resolve() == path.resolve():
            raise CommandError(f"output '{path}' is one of the inputs; refusing to overwrite it")
    if path.exists() and not overwrite:
        raise CommandError(f"'{path}' already exists; refusing to overwrite it (pass --overwrite)")


def _write_json(path: Path, document: dict, overwrite: bool) -> None:
    from polarbssrdf.io.atomic import atomic_write_text

    try:
        atomic_write_text(path, json.dumps(document, indent=2) + "\n", overwrite=overwrite)
    except FileExistsError as error:
        raise CommandError(str(error)) from None


# --------------------------------------------------------------------------- geometry
def run_geometry(args) -> int:
    """``calibrate geometry``: detect, calibrate, print per-image errors, write CAMERAS.json."""
    from .board import read_board
    from .geometry import calibrate_rig
    from .rig_io import cameras_document, detect_image_tree, write_cameras

    _check_output(args.out, args.overwrite, [args.board])
    if args.min_views < 3:
        raise CommandError(f"--min-views must be >= 3, got {args.min_views}")
    board = read_board(args.board)
    detections = detect_image_tree(args.directory, board)
    rig = calibrate_rig(detections, board, reference=args.reference, model=args.model,
                        sensor=args.sensor, min_views=args.min_views,
                        outlier_factor=args.outlier_factor, outlier_floor_px=args.outlier_floor_px)
    document = cameras_document(rig, board, detections)
    for entry in document["cameras"]:
        print(f"{entry['name']}: rms {entry['rms_px']:.3f} px over {len(entry['views']) - len(entry['rejected_views'])} "
              f"views; fx {entry['K'][0][0]:.2f} fy {entry['K'][1][1]:.2f} "
              f"cx {entry['K'][0][2]:.2f} cy {entry['K'][1][2]:.2f}")
        for shot, rms in entry["views"].items():
            flag = "  REJECTED (outlier)" if shot in entry["rejected_views"] else ""
            print(f"  {shot}: {rms:.3f} px{flag}")
        for shot in entry["no_board"]:
            print(f"  {shot}: no board detected")
    for link in rig.links:
        print(f"{link['from']} -> {link['to']}: {link['shared_views']} shared views, "
              f"stereo rms {link['rms_px']:.3f} px")
    try:
        write_cameras(args.out, document, overwrite=args.overwrite)
    except FileExistsError as error:
        raise CommandError(str(error)) from None
    print(f"wrote {args.out}")
    return 0


# --------------------------------------------------------------------------- colour
def run_colour(args) -> int:
    """``calibrate colour``: fit the 3 x 3 matrix to a chart's reference values."""
    from .colour_matrix import DEFAULT_CHECKER, checker_reference, fit_colour_matrix
    from .tables import read_labelled_table

    _check_output(args.out, args.overwrite, [args.patches])
    checker = args.checker or DEFAULT_CHECKER
    labels, columns, values = read_labelled_table(args.patches, "patch")
    if [c.upper() for c in columns] != ["R", "G", "B"]:
        raise ValueError(f"{args.patches}: columns must be patch,R,G,B, got patch,{','.join(columns)}")
    names, reference = checker_reference(checker, args.space)
    if set(labels) <= set(names):
        reference = reference[[names.index(label) for label in labels]]
        used = labels
    elif len(labels) == len(names):
        used = names
    else:
        raise ValueError(f"{args.patches}: {len(labels)} patches; give all {len(names)} patches of "
                         f"{checker!r} in chart order, or name them with the chart's patch names "
                         f"(e.g. {names[0]!r})")
    fit = fit_colour_matrix(values, reference, weighting=args.weighting)
    document = {"schema": COLOUR_SCHEMA, "schema_version": SCHEMA_VERSION, "checker": checker,
                "space": args.space, "method": "colour.characterisation.matrix_colour_correction "
                "(Cheung 2004, 3 terms)", "weighting": args.weighting, "matrix": fit.matrix.tolist(),
                "convention": "reference = camera_rgb @ matrix^T (linear values)",
                "rms": fit.rms, "patches": {name: residual.tolist()
                                            for name, residual in zip(used, fit.residuals)}}
    _write_json(args.out, document, args.overwrite)
    print(f"colour matrix ({args.space}), rms residual {fit.rms:.4g}:")
    for row in fit.matrix:
        print("  " + "  ".join(f"{value: .5f}" for value in row))
    print(f"wrote {args.out}")
    return 0


# --------------------------------------------------------------------------- spectral
def _on_grid(path, wavelengths, values, target, what):
    if target[0] < wavelengths[0] - 1e-9 or target[-1] > wavelengths[-1] + 1e-9:
        raise ValueError(f"{path}: {what} covers {wavelengths[0]:g}-{wavelengths[-1]:g} nm, "
                         f"the light spectra need {target[0]:g}-{target[-1]:g} nm")
    return np.interp(target, wavelengths, values)


def run_spectral(args) -> int:
    """``calibrate spectral``: responses, filter transmittances and bands."""
    from polarbssrdf.spectral.bands import BAND_SCHEMA_VERSION, bands_to_json

    from .spectral_response import (DEFAULT_SMOOTHNESS, calibrated_bands, estimate_response,
                                    filter_transmittance)
    from .tables import read_labelled_table, read_spectra_table

    filter_files = {}
    for item in args.filter:
        name, sep, file = item.partition("=")
        if not sep or not name or not file:
            raise CommandError(f"--filter expects NAME=FILE.csv, got {item!r}")
        if name in filter_files:
            raise CommandError(f"--filter {name!r} given twice")
        filter_files[name] = Path(file)
    inputs = [args.lights, args.reference, args.measurements, args.stage_light, *filter_files.values()]
    _check_output(args.out, args.overwrite, inputs)
    if args.bands_out is not None:
        _check_output(args.bands_out, args.overwrite, inputs)
    wl, lights = read_spectra_table(args.lights)
    ref_wl, ref = read_spectra_table(args.reference, ("reflectance",))
    reflectance = _on_grid(args.reference, ref_wl, ref["reflectance"], wl, "the reflectance")
    bands, channels, values = read_labelled_table(args.measurements, "band")
    missing = [band for band in bands if band not in lights]
    if missing:
        raise ValueError(f"{args.measurements}: band(s) {', '.join(missing)} have no light spectrum "
                         f"in {args.lights} (its columns: {', '.join(lights)})")
    smoothness = DEFAULT_SMOOTHNESS if args.smoothness is None else args.smoothness
    responses = estimate_response(wl, np.array([lights[b] for b in bands]), reflectance, values,
                                  smoothness=smoothness)
    response_by_channel = dict(zip(channels, responses))
    filters, filter_json = {}, {}
    for name, path in filter_files.items():
        f_wl, columns = read_spectra_table(path, ("incident", "transmitted"))
        dark = columns.get("dark")
        transmittance, valid = filter_transmittance(f_wl, columns["incident"], columns["transmitted"],
                                                    dark=dark)
        filters[name] = _on_grid(path, f_wl, transmittance, wl, "the filter reading")
        filter_json[name] = {"wavelengths_nm": f_wl.tolist(), "transmittance": transmittance.tolist(),
                             "valid": valid.tolist()}
    light = None
    if args.stage_light is not None:
        l_wl, l_columns = read_spectra_table(args.stage_light, ("value",))
        light = (l_wl, l_columns["value"])
    else:
        from polarbssrdf.spectral.bands import default_light

        light = default_light()
    band_list = calibrated_bands(wl, response_by_channel, filters, light)
    bands_document = json.loads(bands_to_json(band_list))
    document = {"schema": SPECTRAL_SCHEMA, "schema_version": SCHEMA_VERSION,
                "units": {"wavelength": "nm"}, "smoothness": smoothness,
                "wavelengths_nm": wl.tolist(),
                "responses": {c: r.tolist() for c, r in response_by_channel.items()},
                "filters": filter_json,
                "stage_light": str(args.stage_light) if args.stage_light else "default (CIE LED-B3)",
                "bands": bands_document}
    _write_json(args.out, document, args.overwrite)
    if args.bands_out is not None:
        _write_json(args.bands_out, bands_document, args.overwrite)
    for channel, response in response_by_channel.items():
        peak = int(np.argmax(response))
        print(f"channel {channel}: peak {response[peak]:.4g} at {wl[peak]:g} nm")
    print(f"{len(band_list)} band(s): {', '.join(b.name for b in band_list)} "
          f"(band schema {BAND_SCHEMA_VERSION})")
    print(f"wrote {args.out}" + (f" and {args.bands_out}" if args.bands_out else ""))
    return 0


# --------------------------------------------------------------------------- sphere
def run_sphere(args) -> int:
    """``calibrate sphere``: per-camera gains from one white-sphere image per camera."""
    from .detect import IMAGE_SUFFIXES
    from .normalization import sphere_gains

    _check_output(args.out, args.overwrite)
    directory = Path(args.directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"image directory not found: {directory}")
    files = sorted(p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"{directory}: no images ({', '.join(IMAGE_SUFFIXES)})")
    images = {}
    for path in files:
        if path.stem in images:
            raise ValueError(f"{directory}: two images for camera {path.stem!r}")
        images[path.stem] = _read_sphere_image(path, args.decode_srgb)
    gains = sphere_gains(images, reference=args.reference)
    document = {"schema": SPHERE_SCHEMA, "schema_version": SCHEMA_VERSION,
                "reference_camera": args.reference or sorted(images)[0],
                "convention": "normalized image = image / gain",
                "gains": {name: gain.tolist() for name, gain in gains.items()}}
    _write_json(args.out, document, args.overwrite)
    for name, gain in gains.items():
        print(f"{name}: gain {', '.join(f'{g:.4f}' for g in gain)}")
    print(f"wrote {args.out}")
    return 0


DISPLAY_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
"""Integer image formats that cameras and viewers write display-encoded (sRGB), not linear."""


def _read_sphere_image(path: Path, decode_srgb: bool = False) -> np.ndarray:
    """A sphere image as linear float values.

    Integer PNG, JPEG and BMP files, and 8-bit files of any format, are almost
    always display-encoded (sRGB): their values are roughly radiance^(1/2.2),
    and gains computed from them are silently wrong. They are refused unless
    ``decode_srgb``, which decodes every integer image from sRGB (its values
    scaled to [0, 1] by the type's maximum) to linear. Float images (EXR,
    float TIFF) and 16-bit TIFF/PGM files are taken as linear.
    """
    from .normalization import srgb_to_linear

    image = _read_image(path)
    if not np.issubdtype(image.dtype, np.integer):
        return image.astype(np.float64)
    if decode_srgb:
        return srgb_to_linear(image / float(np.iinfo(image.dtype).max))
    bits = 8 * image.dtype.itemsize
    if path.suffix.lower() in DISPLAY_SUFFIXES or bits == 8:
        raise CommandError(
            f"{path}: a {bits}-bit {path.suffix.lstrip('.').upper()} image holds display-encoded "
            f"(sRGB) values, not linear radiance, so gains from it would be wrong (sRGB 0.5 is "
            f"linear 0.21); give linear images (EXR, or 16-bit or float TIFF from a raw "
            f"developer), or pass --decode-srgb to decode these images from sRGB to linear")
    return image.astype(np.float64)


def _read_image(path: Path) -> np.ndarray:
    """An image in its stored type (EXR: float channels in name order; others: OpenCV, RGB)."""
    if path.suffix.lower() == ".exr":
        from polarbssrdf.io.exr import read_exr

        channels, _ = read_exr(path)
        names = sorted(channels)
        return np.stack([np.asarray(channels[n], dtype=np.float64) for n in names], axis=-1)
    from .board import _cv2

    cv2 = _cv2()
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: OpenCV cannot read this image")
    # OpenCV orders colour channels BGR(A): reverse the first three to RGB.
    return image[..., 2::-1] if image.ndim == 3 and image.shape[2] >= 3 else image
