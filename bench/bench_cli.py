"""Start-up time of the command line: ``polarbssrdf --help`` against ``import polarbssrdf``.

Each is run ``--repeat`` times in a fresh interpreter; the best wall time is
printed, with the ratio of the two (what the argument parser adds to importing
the package, which imports Mitsuba and Dr.Jit to register the plugins). The
target is ``--help`` under 1.5 s on 2 cores (issue 19).

    .venv/bin/python bench/bench_cli.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time


def best_seconds(code: str, repeat: int) -> float:
    """Best wall time of ``python -c code`` over ``repeat`` runs."""
    best = float("inf")
    for _ in range(repeat):
        started = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
        best = min(best, time.perf_counter() - started)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    package = best_seconds("import polarbssrdf", args.repeat)
    helptext = best_seconds("import sys, polarbssrdf.cli as c\n"
                            "try:\n    c.main(['--help'])\nexcept SystemExit:\n    pass",
                            args.repeat)
    print(f"import polarbssrdf: {package:.3f} s (best of {args.repeat})")
    print(f"polarbssrdf --help: {helptext:.3f} s (best of {args.repeat}); "
          f"{helptext / package:.2f}x the package import; target < 1.5 s: "
          f"{'met' if helptext < 1.5 else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
