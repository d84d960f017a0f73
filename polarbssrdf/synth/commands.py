"""``polarbssrdf synth``: render a synthetic light-stage capture with ground truth."""

from __future__ import annotations

import time
from pathlib import Path

from polarbssrdf.errors import CommandError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "synth", help="render a synthetic capture (sphere or face) with ground-truth maps",
        description="Render a synthetic light-stage capture with ground truth: every camera of "
                    "a ring rig lit by its near-coaxial polarized light, per band, written in "
                    "the capture format (capture.json, images/, truth/).")
    parser.add_argument("outdir", type=Path, help="output directory (must be empty or new)")
    parser.add_argument("--object", choices=("sphere", "face"), default="face")
    parser.add_argument("--views", type=int, default=8, help="cameras (default 8)")
    parser.add_argument("--frames", type=int, default=1,
                        help="frames; hemoglobin changes over them (default 1)")
    parser.add_argument("--resolution", type=int, default=512, help="image size, px (default 512)")
    parser.add_argument("--texture", type=int, default=512, help="map size T (default 512)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--params", type=Path,
                        help="JSON file with truth settings (see polarbssrdf.synth.truth)")
    parser.add_argument("--bands", type=Path,
                        help="band curves (JSON, see polarbssrdf.spectral.read_bands); "
                             "default: the 6 bands shipped in polarbssrdf/spectral/data")
    parser.add_argument("--raw", action="store_true",
                        help="write noisy 12-bit polarization-sensor mosaics instead of I0..I135")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into a non-empty directory (never deletes other files)")
    parser.add_argument("--resume", action="store_true",
                        help="continue an interrupted run with the same settings")
    parser.add_argument("--variant", default="llvm_ad_mono_polarized",
                        help="Mitsuba variant: a mono polarized one (default llvm_ad_mono_polarized)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def run(args) -> int:
    import mitsuba as mi

    import polarbssrdf
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize
    from polarbssrdf.spectral import read_bands, shipped_default_bands
    from polarbssrdf.synth.truth import load_settings

    if args.variant not in mi.variants() or not args.variant.endswith("mono_polarized"):
        raise CommandError(f"variant {args.variant!r} is not an available mono polarized variant; "
                           "bands are rendered one at a time in a mono polarized variant "
                           f"(available: {', '.join(v for v in mi.variants() if 'polarized' in v)})")
    mi.set_variant(args.variant)
    polarbssrdf.register_plugins()
    settings = SynthesisSettings(object=args.object, views=args.views, frames=args.frames,
                                 resolution=args.resolution, texture=args.texture, spp=args.spp,
                                 seed=args.seed, raw=args.raw)
    truth_settings = load_settings(args.params) if args.params else None
    bands = read_bands(args.bands) if args.bands else shipped_default_bands()
    start = time.perf_counter()
    try:
        manifest = synthesize(args.outdir, settings, bands=bands, truth_settings=truth_settings,
                              overwrite=args.overwrite, resume=args.resume,
                              progress=not args.quiet)
    except FileExistsError as error:
        reason = str(error).split(";")[0]
        raise CommandError(f"{reason}: use --overwrite to write into it, or --resume to "
                           "continue an interrupted run") from error
    print(f"wrote {manifest} ({args.views} views x {args.frames} frames) in "
          f"{time.perf_counter() - start:.1f} s")
    return 0
