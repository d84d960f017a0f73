"""The ``polarbssrdf`` command line.

Each command lives in the module of its stage and adds itself through a
``register(subparsers)`` function, so this file only lists them. :func:`main`
turns the errors a user can fix, and Ctrl-C, into one line on stderr.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import polarbssrdf
from polarbssrdf.errors import (CommandError, is_interrupted_plugin, is_plugin_error,
                                plugin_error_message)

COMMAND_MODULES = (
    "polarbssrdf.render.commands",
    "polarbssrdf.skin.commands",
    "polarbssrdf.synth.commands",
    "polarbssrdf.calibration.commands",
    "polarbssrdf.inverse.commands",
    "polarbssrdf.report",
    "polarbssrdf.demo",
)

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C: 128 + SIGINT, as shells report it."""


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


def caused_by_interrupt(error: BaseException) -> bool:
    """Whether ``error`` is Ctrl-C, or an error raised because of it.

    Ctrl-C inside a C++ extension can surface as another exception whose cause
    is the ``KeyboardInterrupt``: e.g. during :func:`mitsuba.set_variant`,
    which imports modules, Python reports ``SystemError: <built-in function
    __import__> returned a result with an exception set``; inside a Python
    plugin's constructor Mitsuba reports it as a plugin error whose traceback
    ends in ``KeyboardInterrupt`` (:func:`polarbssrdf.errors.is_interrupted_plugin`).
    """
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt) or is_interrupted_plugin(error):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


USER_ERRORS = (CommandError, FileNotFoundError, FileExistsError, ValueError)
"""Exceptions whose message is for the user: printed on one line, exit status 2."""


def run_command(args) -> int:
    """Run the parsed command; errors a user can fix become one line on stderr and status 2."""
    try:
        return int(args.run(args) or 0)
    except Exception as error:
        if caused_by_interrupt(error):  # e.g. a CommandError wrapping a failed import
            raise
        if isinstance(error, USER_ERRORS):
            message = str(error)
        elif is_plugin_error(error):
            # A Python plugin rejected its parameters while Mitsuba built a scene: the
            # plugin's message is for the user, the traceback Mitsuba embeds is not.
            message = plugin_error_message(error)
        else:
            raise
        print(f"polarbssrdf {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USER_ERROR


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
