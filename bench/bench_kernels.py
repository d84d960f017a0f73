"""Which tests compile how many Dr.Jit kernels, with Dr.Jit's kernel cache cold and then warm.

Runs the test suite (or the pytest arguments given after ``--``) twice in a
fresh ``HOME`` (so ``~/.drjit`` starts empty; the pip cache is not involved):
the first run is cold, the second an identical rerun with the cache the first
left. With the plugin :mod:`kernel_census` it records per test the kernels
launched, compiled by LLVM (in neither the in-memory nor the on-disk cache),
loaded from disk, and the growth of ``~/.drjit`` (child processes included),
and prints

* the totals of each run and its wall time;
* the tests that compile the most kernels cold, with their warm figures: a
  kernel compiled again on the warm rerun has a hash that an identical run
  did not produce before (a value baked into it as a literal that changed);
* the same per test file.

    .venv/bin/python bench/bench_kernels.py [--runs 2] [--top 25] [--keep DIR] [--repo DIR]
                                            [--home DIR] [-- PYTEST ARGS]

``--repo`` runs another checkout's tests with its own ``.venv`` (to measure a
branch against ``main``). The per-test records (JSON lines) stay in ``--keep``;
``bench_kernels.py --compare BEFORE_DIR AFTER_DIR [N]`` prints two such record
directories side by side as Markdown (totals, and the N test files that compile
the most; a cell is kernels compiled, or files added to ``~/.drjit`` where child
processes compiled more, and the file's test seconds).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent


def run_suite(repo, home, out, pytest_args):
    """One pytest run of ``repo`` with the census plugin; (wall seconds, exit status)."""
    env = dict(os.environ, HOME=str(home), KERNEL_CENSUS_OUT=str(out),
               PYTHONPATH=os.pathsep.join([str(BENCH_DIR)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    python = Path(repo) / ".venv" / "bin" / "python"
    command = [str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "kernel_census",
               *pytest_args]
    start = time.perf_counter()
    done = subprocess.run(command, cwd=repo, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, check=False)
    seconds = time.perf_counter() - start
    tail = [line for line in done.stdout.splitlines() if line.strip()][-1:]
    print(f"  {tail[0] if tail else '(no output)'}", flush=True)
    return seconds, done.returncode


def read_rows(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def totals(rows):
    keys = ("launches", "compiled", "from_disk", "new_files", "backend_ms")
    out = {k: sum(r[k] for r in rows) for k in keys}
    out["distinct"] = len({h for r in rows for h in r["compiled_hashes"]})
    return out


def by_file(rows):
    groups = collections.defaultdict(list)
    for r in rows:
        groups[r["test"].split("::")[0]].append(r)
    return {name: {**totals(group), "seconds": sum(r["seconds"] for r in group), "tests": len(group)}
            for name, group in groups.items()}


def compare(before_dir, after_dir, top):
    """Markdown tables of two kept record directories (e.g. main and a branch): totals, per file."""
    runs = {}
    for side, directory in (("before", before_dir), ("after", after_dir)):
        for label in ("cold", "warm"):
            path = Path(directory) / f"{label}.jsonl"
            if path.exists():
                runs[side, label] = read_rows(path)
    print("| run | tests | test seconds | kernels launched | compiled | LLVM s | ~/.drjit files added |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for (side, label), rows in runs.items():
        t = totals(rows)
        print(f"| {side}, {label} | {len(rows)} | {sum(r['seconds'] for r in rows):.0f} | {t['launches']:,} | "
              f"{t['compiled']:,} | {t['backend_ms'] / 1000:.0f} | {t['new_files']:,} |")
    files = {key: by_file(rows) for key, rows in runs.items()}
    cold = files.get(("before", "cold"), {})
    print("\n| test file | " + " | ".join(f"{side} {label}" for side, label in runs) + " |")
    print("|---|" + "---:|" * len(runs))
    for name in sorted(cold, key=lambda n: -max(cold[n]["compiled"], cold[n]["new_files"]))[:top]:
        cells = []
        for key in runs:
            f = files[key].get(name)
            cells.append("-" if f is None else f"{max(f['compiled'], f['new_files']):,} ({f['seconds']:.0f} s)")
        print(f"| `{name}` | " + " | ".join(cells) + " |")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--compare"]:
        compare(argv[1], argv[2], int(argv[3]) if len(argv) > 3 else 15)
        return 0
    pytest_args = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="runs in the same HOME (1 = cold only)")
    parser.add_argument("--top", type=int, default=25, help="rows of the per-test table")
    parser.add_argument("--keep", type=Path, default=None, help="directory for the per-test records")
    parser.add_argument("--repo", type=Path, default=BENCH_DIR.parent, help="checkout whose tests to run")
    parser.add_argument("--home", type=Path, default=None,
                        help="run in this HOME (its ~/.drjit as it is: the first run is then warm)")
    args = parser.parse_args(argv)
    keep = args.keep or Path(tempfile.mkdtemp(prefix="kernels-"))
    keep.mkdir(parents=True, exist_ok=True)
    home = args.home or Path(tempfile.mkdtemp(prefix="kernels-home-"))
    labels = (["cold"] if args.home is None else []) + ["warm"] + [f"warm{i}" for i in range(2, args.runs + 1)]
    runs = []
    for index in range(args.runs):
        label = labels[index]
        out = keep / f"{label}.jsonl"
        out.unlink(missing_ok=True)
        print(f"{label} run of {args.repo} (HOME={home}) ...", flush=True)
        seconds, status = run_suite(args.repo, home, out, pytest_args)
        rows = read_rows(out) if out.exists() else []
        runs.append((label, rows))
        t = totals(rows)
        for r in rows:
            if r.get("outcome", "passed") != "passed":
                print(f"  {r['outcome']}: {r['test']}")
        print(f"  {label}: {len(rows)} tests in {seconds:.0f} s (exit {status}); kernels launched "
              f"{t['launches']:,}, compiled {t['compiled']:,} ({t['distinct']:,} distinct, LLVM "
              f"{t['backend_ms'] / 1000:.0f} s), loaded from disk {t['from_disk']:,}; ~/.drjit grew "
              f"by {t['new_files']:,} files", flush=True)
    label0, cold = runs[0]
    later = {label: {r["test"]: r for r in rows} for label, rows in runs[1:]}
    columns = "".join(f" {label + ' compiled':>14s}" for label in later)
    print(f"\nTests that compile the most kernels ({label0}; a kernel compiled again warm has a new hash):")
    print(f"{'compiled':>9s} {'new files':>9s} {'LLVM s':>7s} {'test s':>7s}{columns}  test")
    for r in sorted(cold, key=lambda r: -max(r["compiled"], r["new_files"]))[:args.top]:
        warm = "".join(f" {later[label].get(r['test'], {}).get('compiled', float('nan')):14}" for label in later)
        print(f"{r['compiled']:9d} {r['new_files']:9d} {r['backend_ms'] / 1000:7.1f} {r['seconds']:7.1f}{warm}"
              f"  {r['test']}")
    print(f"\nPer test file ({label0}, then each rerun's compiled kernels and new files):")
    files = by_file(cold)
    later_files = {label: by_file(list(rows.values())) for label, rows in later.items()}
    for name, f in sorted(files.items(), key=lambda kv: -max(kv[1]["compiled"], kv[1]["new_files"]))[:args.top]:
        warm = "".join(f"  {label} {later_files[label].get(name, {}).get('compiled', 0):5d} / "
                       f"{later_files[label].get(name, {}).get('new_files', 0):5d}" for label in later)
        print(f"{f['compiled']:7d} compiled {f['new_files']:6d} new files {f['seconds']:7.1f} s "
              f"{f['tests']:4d} tests{warm}  {name}")
    print(f"\nrecords: {keep}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
