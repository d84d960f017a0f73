"""The ``polarbssrdf`` command line.

Each command lives in the module of its stage and adds itself through a
``register(subparsers)`` function, so this file only lists them. :func:`main`
turns the errors a user can fix (:func:`polarbssrdf.errors.run_command`), and
Ctrl-C or SIGTERM, into one line on stderr.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading

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


class _TerminationAsInterrupt:
    """While active, SIGTERM (``kill PID``, a batch system's time limit) raises
    ``KeyboardInterrupt`` as Ctrl-C does, so the command stops the same way: atomic
    outputs, no traceback, the line saying how to resume. ``signal_number`` is the signal
    that arrived (None: none, or Ctrl-C), for the exit status 128 + N shells expect.

    Only the main thread may set handlers; elsewhere (an embedding application's worker
    thread) SIGTERM keeps its handler.
    """

    def __init__(self):
        self.signal_number, self._previous = None, None

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._interrupt)
        return self

    def __exit__(self, *exc_info):
        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)
        return False

    def _interrupt(self, number, frame):
        self.signal_number = number
        raise KeyboardInterrupt


def interrupted_message(args, signal_number=None) -> str:
    """The line printed after Ctrl-C (or SIGTERM: ``signal_number``); commands with
    ``--resume`` say how to continue.

    ``args`` is ``None`` if the interrupt came before the command line was parsed.
    """
    how = "" if signal_number is None else f" ({signal.Signals(signal_number).name})"
    if args is None:
        return f"polarbssrdf: interrupted{how}"
    message = f"polarbssrdf {args.command}: interrupted{how}"
    if hasattr(args, "resume"):
        message += "; rerun with --resume to continue"
    return message


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default: ``sys.argv[1:]``), run the command, return the exit status."""
    args = None
    with _TerminationAsInterrupt() as termination:
        try:
            args = build_parser().parse_args(argv)
            return run_command(args)
        except BaseException as error:
            if not caused_by_interrupt(error):
                raise
            # Ctrl-C is not an error of the program: no traceback. Outputs are written
            # atomically (temporary file + rename), so no partial file is left behind.
            print(interrupted_message(args, termination.signal_number), file=sys.stderr)
            if termination.signal_number is not None:
                return 128 + termination.signal_number  # 143 after SIGTERM, as shells report
            return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
