"""Run every ``bench/bench_*.py`` in its own subprocess and print what it prints.

Each benchmark runs with this interpreter from the repository root, one after
the other (benchmarks must not compete for the cores). The exit status is 0
when all of them succeed, 1 otherwise; a summary line lists the failures.

Usage: ``python bench/run_all.py [NAME_SUBSTRING ...]`` runs all benchmarks,
or only those whose file name contains one of the given substrings.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
REPO = BENCH_DIR.parent


def discover(filters: list[str]) -> list[Path]:
    """The benchmark files in ``bench/``, sorted, optionally filtered by name substrings."""
    files = sorted(BENCH_DIR.glob("bench_*.py"))
    if filters:
        files = [f for f in files if any(s in f.name for s in filters)]
    return files


def run_one(path: Path) -> tuple[int, float]:
    """Run one benchmark, streaming its output; returns (exit status, seconds)."""
    print(f"=== {path.relative_to(REPO)} ===", flush=True)
    start = time.perf_counter()
    status = subprocess.call([sys.executable, str(path)], cwd=REPO)
    seconds = time.perf_counter() - start
    print(f"=== {path.name}: {'ok' if status == 0 else f'FAILED (exit {status})'} "
          f"in {seconds:.1f} s ===\n", flush=True)
    return status, seconds


def main(argv: list[str] | None = None) -> int:
    """Run the selected benchmarks; 0 if all succeeded."""
    filters = sys.argv[1:] if argv is None else argv
    files = discover(filters)
    if not files:
        print(f"no benchmark files bench/bench_*.py match {filters or 'anything'}",
              file=sys.stderr)
        return 1
    failed = [path.name for path in files if run_one(path)[0] != 0]
    print(f"{len(files) - len(failed)} of {len(files)} benchmarks succeeded"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
