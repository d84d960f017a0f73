"""The ``polarbssrdf`` command line.

Each command lives in the module of its stage and adds itself through a
``register(subparsers)`` function, so this file only lists them.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from polarbssrdf.errors import CommandError

COMMAND_MODULES = (
    "polarbssrdf.render.commands",
    "polarbssrdf.skin.commands",
    "polarbssrdf.synth.commands",
    "polarbssrdf.calibration.commands",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="polarbssrdf",
        description="Polarimetric BSSRDF acquisition of faces with Mitsuba 3.",
    )
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (CommandError, FileNotFoundError, FileExistsError, ValueError) as error:
        print(f"polarbssrdf {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
