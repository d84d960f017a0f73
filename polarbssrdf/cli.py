"""The ``polarbssrdf`` command line.

Each command lives in the module of its stage and adds itself through a
``register(subparsers)`` function, so this file only lists them. :func:`main`
turns the errors a user can fix (:func:`polarbssrdf.errors.run_command`), and
Ctrl-C, into one line on stderr.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import polarbssrdf
from polarbssrdf.errors import EXIT_INTERRUPTED, caused_by_interrupt, run_command

COMMAND_MODULES = (
    "polarbssrdf.render.commands",
    "polarbssrdf.render.scenes",
    "polarbssrdf.skin.commands",
    "polarbssrdf.synth.commands",
    "polarbssrdf.calibration.commands",
    "polarbssrdf.inverse.commands",
    "polarbssrdf.report.commands",
    "polarbssrdf.demo",
)


def version_text() -> str:
    """``polarbssrdf X.Y.Z (Mitsuba A.B.C, Dr.Jit D.E.F)``.

    Importing the package has already imported Mitsuba and Dr.Jit (it
    registers the plugins), so their versions cost nothing more.
    """
    import drjit as dr
    import mitsuba as mi

    return (f"polarbssrdf {polarbssrdf.__version__} "
            f"(Mitsuba {mi.__version__}, Dr.Jit {dr.__version__})")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="polarbssrdf",
        description="Polarimetric BSSRDF acquisition of faces with Mitsuba 3.",
    )
    parser.add_argument("--version", action="version", version=version_text())
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name == name:
                continue  # stage not built yet
            raise
        module.register(subparsers)
    return parser


def interrupted_message(args) -> str:
    """The line printed after Ctrl-C; commands with ``--resume`` say how to continue.

    ``args`` is ``None`` if the interrupt came before the command line was parsed.
    """
    if args is None:
        return "polarbssrdf: interrupted"
    message = f"polarbssrdf {args.command}: interrupted"
    if hasattr(args, "resume"):
        message += "; rerun with --resume to continue"
    return message


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default: ``sys.argv[1:]``), run the command, return the exit status."""
    args = None
    try:
        args = build_parser().parse_args(argv)
        return run_command(args)
    except BaseException as error:
        if not caused_by_interrupt(error):
            raise
        # Ctrl-C is not an error of the program: no traceback. Outputs are written
        # atomically (temporary file + rename), so no partial file is left behind.
        print(interrupted_message(args), file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
