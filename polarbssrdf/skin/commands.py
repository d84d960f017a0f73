"""The ``polarbssrdf skin`` commands: ``spectrum`` and ``fit``."""

from __future__ import annotations

import argparse
import json
import sys

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
