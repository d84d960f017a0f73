"""``polarbssrdf synth``: render a synthetic light-stage capture with ground truth."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from polarbssrdf.errors import CommandError

SETTINGS_DOC = "docs/synth.md"
"""Where the settings file given with ``--params`` is documented."""


def _integer_in(minimum: int, limit: int | None = None, limit_text: str = ""):
    """argparse type: an integer >= ``minimum`` (and < ``limit``, shown as ``limit_text``)."""
    wanted = f"an integer >= {minimum}" + (f" and < {limit_text}" if limit is not None else "")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got '{text}'") from None
        if value < minimum or (limit is not None and value >= limit):
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {value}")
        return value

    return parse


def register(subparsers) -> None:
    from polarbssrdf.synth.synthesize import SEED_LIMIT

    parser = subparsers.add_parser(
        "synth", help="render a synthetic capture (sphere or face) with ground-truth maps",
        description="Render a synthetic light-stage capture with ground truth: every camera of "
                    "a ring rig lit by its near-coaxial polarized light, per band, written in "
                    f"the capture format (capture.json, images/, truth/). See {SETTINGS_DOC}.")
    parser.add_argument("outdir", type=Path,
                        help="output directory: new or empty, or an earlier capture with "
                             "--overwrite (start over) or --resume (continue)")
    parser.add_argument("--object", choices=("sphere", "face"), default="face",
                        help="what to render (default: %(default)s)")
    parser.add_argument("--views", type=int, default=8,
                        help="cameras, each with its coaxial light (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=1,
                        help="frames; hemoglobin changes over them (default: %(default)s)")
    parser.add_argument("--resolution", type=int, default=512,
                        help="image width and height, px (default: %(default)s)")
    parser.add_argument("--texture", type=int, default=512,
                        help="truth map size T, texels (default: %(default)s)")
    parser.add_argument("--spp", type=int, default=16,
                        help="samples per pixel (default: %(default)s)")
    parser.add_argument("--seed", type=_integer_in(0, SEED_LIMIT, "2**64"), default=0,
                        help="seed of the truth maps, render and sensor noise; an integer in "
                             "[0, 2**64) (default: %(default)s)")
    parser.add_argument("--interreflection", action="store_true",
                        help="let glossy lobes reflect the subsurface glow of other texels "
                             "(default: off, so images follow the per-texel model the inverse "
                             "stages fit)")
    parser.add_argument("--no-subsurface-diffusion", dest="subsurface_diffusion",
                        action="store_false",
                        help="leave subsurface light in the texel it entered (exitance R_bar E "
                             "per texel, the inverse stages' per-texel model) instead of "
                             "diffusing it through the skin's profiles (default: diffused)")
    parser.add_argument("--spectral", choices=("integral", "effective"), default="integral",
                        help="how a band's image is formed: 'integral' records the band integral of "
                             "the diffused spectral light, as a camera behind the filter does; "
                             "'effective' renders the band once with band-averaged coefficients, an "
                             "approximation up to 19%% off, for measuring what it costs "
                             "(default: %(default)s)")
    parser.add_argument("--params", type=Path,
                        help=f"JSON file with truth settings (keys, units and defaults: "
                             f"{SETTINGS_DOC}; default: the built-in settings)")
    parser.add_argument("--bands", type=Path,
                        help="band curves (JSON, see polarbssrdf.spectral.read_bands); "
                             "default: the 6 bands shipped in polarbssrdf/spectral/data")
    parser.add_argument("--raw", action="store_true",
                        help="write noisy 12-bit polarization-sensor mosaics instead of I0..I135")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--overwrite", action="store_true",
                          help="start over in a directory with an earlier capture: everything "
                               "is rendered anew; files the new capture does not name are kept")
    existing.add_argument("--resume", action="store_true",
                          help="continue an interrupted run; needs the same settings")
    parser.add_argument("--variant", default="llvm_ad_mono_polarized",
                        help="Mitsuba variant, a mono polarized one (default: %(default)s)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def mono_polarized_variants(available) -> list[str]:
    """The variants ``synth`` can render in: bands are rendered one at a time in mono."""
    return [variant for variant in available if variant.endswith("mono_polarized")]


def check_variant(variant: str, available) -> None:
    """Raise ``CommandError`` unless ``variant`` is an available mono polarized variant."""
    usable = mono_polarized_variants(available)
    choices = (", ".join(usable) if usable
               else "none: this Mitsuba build has no mono polarized variant")
    if variant in usable:
        return
    per_band = ("synth renders each band separately in a mono polarized variant, with "
                "band-integrated parameters: the skin model and the texture-space diffusion "
                "work per band")
    if "spectral" in variant:
        reason = (f"variant {variant!r} is not accepted: {per_band} (and Mitsuba's stokes "
                  "integrator cannot write a spectral film)")
    elif "rgb" in variant:
        reason = f"variant {variant!r} is not accepted: {per_band}, not in RGB"
    elif variant not in available:
        reason = f"variant {variant!r} is not available in this Mitsuba build"
    else:
        reason = f"variant {variant!r} is not polarized; synth needs Stokes vectors"
    raise CommandError(f"{reason}; use one of: {choices}")


def setting_name(path: str) -> str:
    """Command-line name of a differing plan field, e.g. ``--spp`` for ``...settings.spp``."""
    settings = "manifest.metadata.settings."
    if path.startswith(settings):
        return "--" + path[len(settings):].split(".")[0].split("[")[0]
    if path.startswith(("manifest.metadata.truth_settings", "manifest.metadata.skin")):
        return "--params " + path.removeprefix("manifest.metadata.").removeprefix("truth_settings.")
    if path.startswith("manifest.bands"):
        return "--bands"
    if path == "manifest.metadata.generator":
        return "polarbssrdf version"
    return path


def describe_differences(differences) -> str:
    """``--spp: 4 (first run) vs 2 (now); ...`` naming each differing setting once.

    Cameras, lights and frames follow from the settings; they are listed only
    when no setting explains the difference.
    """
    from polarbssrdf.io.capture import short_json

    named = {}
    for path, old, new in differences:
        name = setting_name(path)
        if name != path:
            named.setdefault(name, (old, new))
    if not named:
        named = {path: (old, new) for path, old, new in differences[:5]}

    def describe(name, old, new):
        if name == "--bands":  # whole curves are too long to show
            return "--bands: other band curves"
        return f"{name}: {short_json(old)} (first run) vs {short_json(new)} (now)"

    return "; ".join(describe(name, old, new) for name, (old, new) in named.items())


def new_directory(outdir: Path) -> str | None:
    """``"absent"`` or ``"empty"`` when ``outdir`` holds nothing yet (a failed run may then
    remove what it wrote), None otherwise."""
    if not outdir.exists():
        return "absent"
    if outdir.is_dir() and not any(outdir.iterdir()):
        return "empty"
    return None


def settings_error(error: BaseException) -> bool:
    """Whether ``error`` says the settings cannot be rendered (a plugin or the skin model
    refused a value), as opposed to an interrupt or a failing disk (which --resume fixes)."""
    from polarbssrdf.errors import caused_by_interrupt, is_plugin_error

    if caused_by_interrupt(error):
        return False
    return isinstance(error, ValueError) or is_plugin_error(error)


def remove_new_capture(outdir: Path, state: str) -> None:
    """Remove what a failed run wrote into ``outdir``, which was ``state`` ("absent" or
    "empty") before it: nothing else can be there."""
    import shutil

    if state == "absent":
        shutil.rmtree(outdir, ignore_errors=True)
        return
    for path in outdir.iterdir():
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


SKIN_MODEL_KEYS = {
    "C_m + C_h_out": "biophysical / biophysical_std C_m and C_h_out (with features and the "
                     "hemoglobin_swing over frames)",
}
"""The settings behind the skin model's refusals of drawn maps, by the refusal's text."""


def settings_error_message(error: ValueError, params: Path | None) -> str:
    """One line naming the settings file (or the built-in settings) and, for the skin
    model's refusals of drawn maps, the keys that drew them."""
    text = str(error)
    source = f"{params}" if params else "the built-in truth settings"
    if params and text.startswith(f"{params}:"):
        return text
    keys = next((keys for marker, keys in SKIN_MODEL_KEYS.items() if marker in text), None)
    if keys is None:
        return f"{source}: {text}"
    return (f"{source}: the drawn truth maps break the skin model ({text}) at some texels: "
            f"lower the bases or spreads of {keys}")


def run(args) -> int:
    import mitsuba as mi

    import polarbssrdf
    from polarbssrdf.io.capture import PlanMismatchError
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize
    from polarbssrdf.spectral import read_bands, shipped_default_bands
    from polarbssrdf.synth.checks import load_checked_settings

    check_variant(args.variant, mi.variants())
    mi.set_variant(args.variant)
    polarbssrdf.register_plugins()
    settings = SynthesisSettings(object=args.object, views=args.views, frames=args.frames,
                                 resolution=args.resolution, texture=args.texture, spp=args.spp,
                                 seed=args.seed, raw=args.raw,
                                 interreflection=args.interreflection,
                                 subsurface_diffusion=args.subsurface_diffusion,
                                 spectral=args.spectral)
    truth_settings = load_checked_settings(args.params) if args.params else None
    bands = read_bands(args.bands) if args.bands else shipped_default_bands()
    start = time.perf_counter()
    fresh = new_directory(args.outdir)
    try:
        manifest = synthesize(args.outdir, settings, bands=bands, truth_settings=truth_settings,
                              overwrite=args.overwrite, resume=args.resume,
                              progress=not args.quiet)
    except PlanMismatchError as error:
        raise CommandError(f"cannot resume in '{args.outdir}': its capture was started with other "
                           f"settings ({describe_differences(error.differences)}); rerun with "
                           "the original settings to continue it, or pass --overwrite instead of "
                           "--resume to start over with the new ones") from error
    except FileExistsError as error:
        if args.resume:
            raise
        reason = str(error).split(";")[0]
        raise CommandError(f"{reason}: use --overwrite to start over in it, or --resume to "
                           "continue an interrupted run") from error
    except Exception as error:
        if fresh is not None and settings_error(error):
            # nothing a corrected rerun could resume (it needs other settings): leave the
            # directory as it was, so the rerun is not refused as "not empty"
            remove_new_capture(args.outdir, fresh)
            if isinstance(error, ValueError):
                raise CommandError(settings_error_message(error, args.params)) from None
        raise
    print(f"wrote {manifest} ({args.views} views x {args.frames} frames) in "
          f"{time.perf_counter() - start:.1f} s")
    return 0
