"""The Python examples in README.md and docs/*.md run as written."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def python_blocks(path):
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.name)
def test_python_examples_run(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for block in python_blocks(path):
        exec(compile(block, str(path), "exec"), {"__name__": "__doc_example__"})


MEASURED = re.compile(r"final loss \d|\bin \d+(\.\d+)? s\b|\d[\d,]* texel-views|\d+(\.\d+)? s\)")
"""What a run measures and prints (losses, times, counts of texel-views): it changes with the
code and the machine, so example output shows it as '...' (measured figures live in
bench/RESULTS.md with their date and machine)."""


def console_output_lines(path):
    """Output lines of the ```console examples (lines after a '$ ' command)."""
    for block in re.findall(r"```console\n(.*?)```", path.read_text(), flags=re.S):
        if "$ " not in block:
            continue  # a list of commands, no output
        for line in block.splitlines():
            if not line.startswith("$ "):
                yield line


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.name)
def test_example_output_quotes_no_measured_figures(path):
    """docs/reconstruct.md's example said 'final loss 3.859' where runs print 1.426
    (issue 21, item 15)."""
    stale = [line for line in console_output_lines(path) if MEASURED.search(line)]
    assert not stale, f"{path.name}: measured figures in example output: {stale}"
