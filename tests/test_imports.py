"""The package's import graph: no circle, and every file imports only from rooms below it.

The graph is read from the source with ``ast`` (every ``import`` statement, also
those deferred into function bodies), so a circle that only closes at run time
is found too. Within ``polarbssrdf.inverse`` the rooms are ranked in the order
data flows; a module may import its own room or a lower rank, never a higher
one and never another room of its rank.
"""

from __future__ import annotations

import ast
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

INVERSE_RANKS = {
    "polarbssrdf.inverse.results": 0,
    "polarbssrdf.inverse.observations": 0,
    "polarbssrdf.inverse.frames": 0,
    "polarbssrdf.inverse.resources": 0,
    "polarbssrdf.inverse.polarimetric": 1,
    "polarbssrdf.inverse.biophysical": 2,
    "polarbssrdf.inverse.evaluation": 3,
    "polarbssrdf.inverse.config": 3,
    "polarbssrdf.inverse.pipeline": 4,
    "polarbssrdf.inverse.commands": 5,
}
"""Rooms of the acquisition, bottom first (see polarbssrdf/inverse/__init__.py)."""

TOP = ("polarbssrdf.inverse", "polarbssrdf.report", "polarbssrdf.demo", "polarbssrdf.cli")
"""What only the acquisition, the report, the demo and the command line may import."""


def module_files():
    """``module name -> path`` of every module of the package (plugins as polarbssrdf.plugins)."""
    modules = {}
    for base, prefix in ((ROOT / "polarbssrdf", "polarbssrdf"), (ROOT / "plugins",
                                                                 "polarbssrdf.plugins")):
        for path in base.rglob("*.py"):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join([prefix, *parts])] = path
    return modules


def import_graph(modules):
    """``module -> {imported package modules}`` from every import statement."""
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                # "from package import module" imports the module
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                           for alias in node.names]
            else:
                continue
            edges |= {target for target in targets if target in modules and target != name}
        graph[name] = edges
    return graph


def cycles(graph):
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], [0]

    def visit(node):
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def room(name):
    """The ranked room of an ``inverse`` module (None outside them, e.g. the package itself)."""
    for prefix in sorted(INVERSE_RANKS, key=len, reverse=True):
        if name == prefix or name.startswith(prefix + "."):
            return prefix
    return None


@pytest.fixture(scope="module")
def graph():
    return import_graph(module_files())


def test_the_graph_is_read_from_every_module(graph):
    # a few known edges, so that an empty or broken graph cannot pass the tests below
    assert "polarbssrdf.inverse.polarimetric.fit" in graph["polarbssrdf.inverse.polarimetric.static"]
    assert "polarbssrdf.optics.pbrdf" in graph["polarbssrdf.plugins.pbssrdf"]
    assert "polarbssrdf.inverse.pipeline" in graph["polarbssrdf.inverse.commands"]  # deferred


def test_cycles_are_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle(graph):
    assert cycles(graph) == []


def test_results_and_observations_import_no_stage(graph):
    bottom = ("polarbssrdf.inverse.results", "polarbssrdf.inverse.observations")
    wrong = [(source, target) for source, targets in graph.items() for target in targets
             if room(source) in bottom and room(target) not in (None, room(source))]
    assert wrong == []


def test_inverse_rooms_import_only_lower_ranks(graph):
    wrong = []
    for source, targets in graph.items():
        if room(source) is None:
            continue
        for target in targets:
            if room(target) is None or room(target) == room(source):
                continue
            if INVERSE_RANKS[room(target)] >= INVERSE_RANKS[room(source)]:
                wrong.append((source, target))
    assert wrong == []


def test_lower_rooms_do_not_import_the_acquisition_report_or_cli(graph):
    def upper(name):
        return name.startswith(TOP) or name in TOP

    wrong = [(source, target) for source, targets in graph.items() for target in targets
             if not upper(source) and upper(target)
             and source != "polarbssrdf.__main__"]
    assert wrong == []
    # the report may read the acquisition, never the other way round
    assert not [(s, t) for s, targets in graph.items() for t in targets
                if s.startswith("polarbssrdf.inverse") and t.startswith(("polarbssrdf.report",
                                                                          "polarbssrdf.demo"))]


def test_the_command_line_imports_no_stage():
    """``polarbssrdf --help`` builds its parser without the stages, Dask, matplotlib or
    colour-science (its time is measured by bench/bench_cli.py)."""
    code = ("import sys, polarbssrdf.cli as cli\n"
            "try:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('polarbssrdf.inverse.pipeline', 'polarbssrdf.report.page', "
            "'zarr', 'dask.distributed', 'matplotlib', 'colour') if m in sys.modules]\n"
            "print('HEAVY', heavy)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "HEAVY []" in out, out[-300:]
