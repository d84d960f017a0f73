"""The ``polarbssrdf skin`` commands: ``spectrum``, ``fit``, ``bands`` (what a band set can tell
about the chromophores) and ``design-bands`` (band sets or comb-filter pairs that tell more)."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from . import band_information as info
from .chromophores import DEFAULT_REFRACTIVE_INDEX
from .inversion import fit_spectrum
from .model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM, skin_reflectance_spectrum
from .parameters import SkinParameters
from .reflectance_csv import format_reflectance_csv, parse_wavelength_range, read_reflectance_csv


def _add_layer_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gamma", type=float, default=DEFAULT_GAMMA, help="oxygenated hemoglobin fraction (default 0.75)")
    parser.add_argument("--thickness", type=float, default=DEFAULT_THICKNESS_MM, help="epidermis thickness in mm (default 0.25)")
    parser.add_argument("--eta", type=float, default=DEFAULT_REFRACTIVE_INDEX, help="refractive index of skin (default 1.4)")


def register(subparsers) -> None:
    """Add ``skin spectrum`` and ``skin fit`` to the top-level parser."""
    skin = subparsers.add_parser("skin", help="two-layer skin optics: spectra and their inversion",
                                 description="Two-layer (epidermis over dermis) skin model of the paper.")
    sub = skin.add_subparsers(dest="skin_command", required=True, metavar="SUBCOMMAND")

    spectrum = sub.add_parser("spectrum", help="print the total diffuse reflectance spectrum as CSV")
    spectrum.add_argument("--melanin", type=float, required=True, help="C_m, melanin fraction of the epidermis")
    spectrum.add_argument("--eumelanin", type=float, required=True, help="beta_m, eumelanin fraction of the melanin")
    spectrum.add_argument("--hb-epidermis", type=float, required=True, help="C_h_out, hemoglobin fraction of the epidermis")
    spectrum.add_argument("--hb-dermis", type=float, required=True, help="C_h_in, hemoglobin fraction of the dermis")
    spectrum.add_argument("--wavelengths", default="400:700:5", help="start:stop:step in nm (default 400:700:5)")
    spectrum.add_argument("--plot", metavar="PNG", help="also write a plot of the spectrum to this PNG file")
    _add_layer_options(spectrum)
    spectrum.set_defaults(run=run_spectrum)

    fit = sub.add_parser("fit", help="fit the four biophysical parameters to a reflectance CSV; prints JSON")
    fit.add_argument("file", metavar="FILE.csv", help="CSV with header wavelength_nm,reflectance")
    _add_layer_options(fit)
    fit.set_defaults(run=run_fit)

    bands = sub.add_parser(
        "bands", help="Cramér-Rao bound of each chromophore at each Table 2 row for a band set",
        description="The Cramér-Rao bound (J^T S^-1 J)^-1 of C_m, beta_m, C_h_out and C_h_in from the "
                    "per-band subsurface albedo, at each Table 2 row, for a band set and a noise model; "
                    "and which chromophore each band pins (docs/biophysical.md). Prints a table; "
                    "--out writes JSON.")
    source = bands.add_mutually_exclusive_group()
    source.add_argument("--bands", metavar="FILE.json", help="band curves (polarbssrdf.spectral.read_bands)")
    source.add_argument("--capture", metavar="DIR", help="the bands of a capture (its capture.json)")
    source.add_argument("--centres", metavar="NM", help="Gaussian bandpass filters at these centres "
                        "(comma list or start:stop:step, nm); widths from --widths")
    source.add_argument("--comb", nargs=2, type=float, metavar=("PERIOD", "PHASE"),
                        help="the 6 bands of the default camera behind a comb-filter pair (nm; the default "
                             "bands are 70 440)")
    bands.add_argument("--widths", default="10", metavar="NM",
                       help="FWHM of the --centres filters, one or one per centre (nm, default 10)")
    _add_noise_options(bands, covariance=True)
    bands.add_argument("--out", metavar="FILE.json", help="write the report as JSON (atomically)")
    bands.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    bands.set_defaults(run=run_bands)

    design = sub.add_parser(
        "design-bands", help="pick k bands (or a comb-filter pair) that minimize the chromophores' bound",
        description="Choose k of a set of candidate bandpass filters (or a comb-filter pair for the default "
                    "camera) to minimize a criterion of the Cramér-Rao bounds over the Table 2 rows, under "
                    "white noise. Prints the chosen set's table beside the default bands'.")
    design.add_argument("-k", type=int, default=6, help="number of bands to pick (default 6)")
    design.add_argument("--candidates", default="410:690:10", metavar="NM",
                        help="centres of the candidate filters (comma list or start:stop:step, nm; default "
                             "410:690:10, inside the hemoglobin data's 400-700 nm)")
    design.add_argument("--width", type=float, default=10.0, help="FWHM of the candidates (nm, default 10)")
    design.add_argument("--criterion", choices=sorted(info.CRITERIA), default="mean",
                        help="mean: mean over rows and chromophores of the bound as a fraction of the "
                             "chromophore's Table 2 range (default); worst: the largest")
    design.add_argument("--search", choices=("greedy", "exhaustive"), default="greedy",
                        help="greedy: the best 4 exhaustively, then one band at a time (default)")
    design.add_argument("--filter-pair", action="store_true",
                        help="design a comb-filter pair (grid of --periods x --phases) instead of k bands")
    design.add_argument("--periods", default="40:120:5", metavar="NM", help="comb periods (default 40:120:5)")
    design.add_argument("--phases", default="400:515:5", metavar="NM", help="comb phases (default 400:515:5)")
    _add_noise_options(design, covariance=False)
    design.add_argument("--out", metavar="FILE.json", help="write the design as JSON (atomically)")
    design.add_argument("--write-bands", metavar="FILE.json",
                        help="write the chosen bands as a band file (for synth --bands, skin bands --bands)")
    design.add_argument("--overwrite", action="store_true",
                        help="replace existing --out and --write-bands files")
    design.set_defaults(run=run_design)


def _add_noise_options(parser, covariance):
    noise = parser.add_mutually_exclusive_group()
    noise.add_argument("--noise", type=float, metavar="SIGMA",
                       help="white noise relative to the albedo per band (default 0.01, the fit's albedo_noise)")
    noise.add_argument("--noise-absolute", type=float, metavar="SIGMA",
                       help="white noise in lobe-albedo units per band")
    if covariance:
        noise.add_argument("--covariance", metavar="FILE.json",
                           help='band covariance of relative albedo errors: {"bands": [...], "covariance": '
                                "[[...]]}")
    parser.add_argument("--noise-common", type=float, metavar="SIGMA",
                        help="a relative error every band shares, beside --noise (default 0.01, the fit's "
                             "common_noise; 0 for independent bands)")
    parser.add_argument("--nuisances", default="default", metavar="SPEC",
                        help="the skin's other unknowns marginalized in the bound: 'default' (thickness_mm, "
                             "gamma and eta at the biophysical fit's prior spreads), 'none' (held at --thickness, "
                             "--gamma and each row's eta), or name=std pairs, e.g. "
                             "'thickness_mm=0.05,gamma=0.08,eta=0.015'")
    parser.add_argument("--prior", choices=("row", "rows"),
                        help="Bayesian bound with a Gaussian prior: each row's Table 2 (std), or the spread "
                             "of the eight Table 2 means")
    parser.add_argument("--thickness", type=float, default=DEFAULT_THICKNESS_MM,
                        help="epidermis thickness in mm (default 0.25)")
    parser.add_argument("--gamma", type=float, default=DEFAULT_GAMMA,
                        help="oxygenated hemoglobin fraction (default 0.75)")


def run_spectrum(args) -> int:
    params = SkinParameters(C_m=args.melanin, beta_m=args.eumelanin, C_h_out=args.hb_epidermis,
                            C_h_in=args.hb_dermis, gamma=args.gamma, thickness_mm=args.thickness, eta=args.eta)
    wavelengths = parse_wavelength_range(args.wavelengths)
    reflectance = skin_reflectance_spectrum(params, wavelengths)
    sys.stdout.write(format_reflectance_csv(wavelengths, reflectance))
    if args.plot:
        write_spectrum_plot(args.plot, wavelengths, reflectance, params)
    return 0


def write_spectrum_plot(path, wavelengths, reflectance, params: SkinParameters) -> None:
    """A PNG line plot of one spectrum (matplotlib, Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=120)
    ax.plot(wavelengths, reflectance, color="tab:red")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("total diffuse reflectance")
    ax.set_title(f"C_m={params.C_m:g} beta_m={params.beta_m:g} C_h_out={params.C_h_out:g} C_h_in={params.C_h_in:g}",
                 fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run_fit(args) -> int:
    wavelengths, reflectance = read_reflectance_csv(args.file)
    result = fit_spectrum(wavelengths, reflectance, gamma=args.gamma, thickness_mm=args.thickness, eta=args.eta)
    print(json.dumps(result, indent=2))
    return 0


def _noise(args):
    if getattr(args, "covariance", None) or args.noise_absolute is not None:
        if args.noise_common:
            raise ValueError("--noise-common goes with the relative --noise (a --covariance file holds its own "
                             "common part)")
        if getattr(args, "covariance", None):
            return info.read_covariance(args.covariance)
        return info.white_noise(args.noise_absolute, relative=False)
    return info.white_noise(0.01 if args.noise is None else args.noise,
                            common=0.01 if args.noise_common is None else args.noise_common)


def _nuisances(args):
    """``--nuisances`` as :func:`~polarbssrdf.skin.band_information.check_nuisances` takes it."""
    spec = args.nuisances.strip()
    if spec in ("default", "none"):
        return None if spec == "none" else "default"
    out = {}
    for item in spec.split(","):
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--nuisances: expected 'default', 'none' or name=std pairs, got {item!r}") from None
        if not sep:
            raise ValueError(f"--nuisances: expected 'default', 'none' or name=std pairs, got {item!r}")
    try:
        return info.check_nuisances(out)
    except ValueError as error:
        raise ValueError(f"--nuisances: {error}") from None


def _check_layers(args):
    if not (args.thickness > 0):
        raise ValueError(f"--thickness must be > 0 mm, got {args.thickness:g}")
    if not 0.0 <= args.gamma <= 1.0:
        raise ValueError(f"--gamma must be in [0, 1], got {args.gamma:g}")


def _band_set(args):
    """(bands, where) from the command's band source."""
    from polarbssrdf.spectral import bandpass_bands, comb_pair_bands, read_bands, shipped_default_bands

    if args.bands:
        return read_bands(args.bands), args.bands
    if args.capture:
        from polarbssrdf.io import load_capture

        return list(load_capture(args.capture, check_images=False).manifest.bands), f"{args.capture}/capture.json"
    if args.centres:
        centres = parse_wavelength_range(args.centres)
        widths = np.asarray([float(w) for w in args.widths.split(",")])
        if widths.size not in (1, centres.size):
            raise ValueError(f"--widths: give one width or one per centre ({centres.size}), got {widths.size}")
        return bandpass_bands(centres, widths if widths.size > 1 else widths[0]), "--centres"
    if args.comb:
        return comb_pair_bands(*args.comb), "--comb"
    return shipped_default_bands(), "the shipped default bands"


def _exit_fraction():
    # render sits above skin in the package; only the lobe albedo's c(eta) is needed from it
    from polarbssrdf.render.subsurface import subsurface_exit_fraction

    return subsurface_exit_fraction


def run_bands(args) -> int:
    _check_layers(args)
    bands, where = _band_set(args)
    noise = _noise(args)
    nuisances = _nuisances(args)
    try:
        bounds = info.band_bounds(bands, noise, prior=args.prior, thickness_mm=args.thickness, gamma=args.gamma,
                                  exit_fraction=_exit_fraction(), nuisances=nuisances)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    pins = info.band_pins(bounds, args.thickness, args.gamma, _exit_fraction())
    sys.stdout.write(info.format_report(bounds, pins))
    if args.out:
        info.write_report(args.out, info.report_json(bounds, pins), overwrite=args.overwrite)
        print(f"wrote {args.out}")
    return 0


def run_design(args) -> int:
    from polarbssrdf.spectral import bands_to_json, bandpass_bands, comb_pair_bands, shipped_default_bands

    _check_layers(args)
    noise = _noise(args)
    layers = {"thickness_mm": args.thickness, "gamma": args.gamma, "exit_fraction": _exit_fraction(),
              "nuisances": _nuisances(args)}
    default = info.band_bounds(shipped_default_bands(), noise, prior=args.prior, **layers)
    if args.filter_pair:
        periods, phases = parse_wavelength_range(args.periods), parse_wavelength_range(args.phases)
        if np.any(periods <= 0):
            raise ValueError(f"--periods must be > 0 nm, got {args.periods!r}")
        period, phase, value, grid = info.design_comb_pair(periods, phases, noise, args.criterion,
                                                           prior=args.prior, **layers)
        chosen = comb_pair_bands(period, phase)
        design = {"mode": "filter_pair", "period_nm": period, "phase_nm": phase, "value": value,
                  "grid": [{"period_nm": p, "phase_nm": q, "value": v} for p, q, v in grid],
                  "search": "grid", "evaluated": len(grid)}
    else:
        centres = parse_wavelength_range(args.candidates)
        if not args.width > 0:
            raise ValueError(f"--width must be > 0 nm, got {args.width:g}")
        candidates = bandpass_bands(centres, args.width)
        result = info.design_bands(candidates, args.k, noise, args.criterion, args.search, prior=args.prior,
                                   **layers)
        chosen = sorted(result.bands, key=lambda b: b.centroid_nm)
        design = {"mode": "bands", "k": args.k, "candidates_nm": centres.tolist(), "width_nm": args.width,
                  "chosen": [b.name for b in chosen], "value": result.value, "search": result.search,
                  "history": result.history, "evaluated": result.evaluated}
    bounds = info.band_bounds(chosen, noise, prior=args.prior, **layers)
    pins = info.band_pins(bounds, args.thickness, args.gamma, _exit_fraction())
    print(f"criterion ({args.criterion}): {info.CRITERIA[args.criterion]}")
    print(f"default bands: {100 * default.criterion(args.criterion):.1f}% of the range; chosen: "
          f"{100 * bounds.criterion(args.criterion):.1f}% ({design['search']} search, "
          f"{design['evaluated']} sets evaluated)\n")
    sys.stdout.write("chosen set\n" + info.format_report(bounds, pins))
    sys.stdout.write("\ndefault bands\n" + info.format_report(default))
    if args.write_bands:
        from polarbssrdf.io.atomic import atomic_write_text

        atomic_write_text(args.write_bands, bands_to_json(chosen), overwrite=args.overwrite)
        print(f"wrote {args.write_bands}")
    if args.out:
        data = {"schema": "polarbssrdf.band_design", "schema_version": 1, "criterion": args.criterion,
                "criterion_meaning": info.CRITERIA[args.criterion], "design": design,
                "chosen": info.report_json(bounds, pins), "default_bands": info.report_json(default)}
        info.write_report(args.out, data, overwrite=args.overwrite)
        print(f"wrote {args.out}")
    return 0
