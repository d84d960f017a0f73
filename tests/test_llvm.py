"""libLLVM for Dr.Jit (issue 21, item 20): an old or missing library is one line, not an abort.

On a machine whose newest libLLVM is 15, the first kernel used to abort the process inside
LLVM (exit -6). The checks run in child processes with a fake library directory or
environment, since the real one is configured once per process when polarbssrdf is imported.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from polarbssrdf import _llvm


def _command(environment_changes, *arguments):
    environment = {**os.environ, **environment_changes}
    return subprocess.run([sys.executable, "-m", "polarbssrdf", *arguments],
                          capture_output=True, text=True, env=environment, timeout=120)


@pytest.mark.parametrize("name, expected", [
    ("libLLVM-15.so", "is libLLVM 15; Dr.Jit's LLVM backend needs libLLVM >= 16"),
    ("libLLVM.so", "cannot be loaded as a library"),
    ("missing/libLLVM-19.so", "does not exist"),
])
def test_an_unusable_drjit_libllvm_path_is_one_line(tmp_path, name, expected):
    (tmp_path / "libLLVM-15.so").write_bytes(b"")  # named like LLVM 15
    (tmp_path / "libLLVM.so").write_bytes(b"not an ELF library")
    chosen = tmp_path / name
    result = _command({"DRJIT_LIBLLVM_PATH": str(chosen)}, "--version")
    assert result.returncode == 1, result.stdout
    assert result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.startswith(f"polarbssrdf: error: DRJIT_LIBLLVM_PATH={chosen} ")
    assert expected in result.stderr
    assert "apt-get install libllvm19" in result.stderr and result.stdout == ""


def test_a_usable_library_is_kept(tmp_path):
    library = os.environ["DRJIT_LIBLLVM_PATH"]  # what importing polarbssrdf chose here
    assert _llvm.library_major_version(library) >= _llvm.MINIMUM_LLVM_MAJOR
    result = _command({"DRJIT_LIBLLVM_PATH": library}, "--version")
    assert result.returncode == 0 and result.stderr == "", result.stderr


def test_the_version_of_an_unversioned_name_comes_from_the_library(tmp_path):
    """A symlink is resolved; a copy without a version in its name is asked (LLVMGetVersion,
    LLVM >= 16) and must agree with the version its real name says."""
    import shutil

    real = os.path.realpath(os.environ["DRJIT_LIBLLVM_PATH"])
    expected = _llvm._major_from_name(real)
    assert expected is not None and expected >= _llvm.MINIMUM_LLVM_MAJOR
    link = tmp_path / "libLLVM.so"
    link.symlink_to(real)
    assert _llvm.library_major_version(str(link)) == expected
    copy = tmp_path / "renamed.so"
    shutil.copy(real, copy)
    assert _llvm._major_from_name(str(copy)) is None
    assert _llvm.library_major_version(str(copy)) == expected


def test_the_search_takes_the_newest_usable_library_or_says_what_it_found(tmp_path,
                                                                          monkeypatch):
    old = tmp_path / "old"
    old.mkdir()
    for name in ("libLLVM-14.so.1", "libLLVM-15.so", "libLLVM.so.15.0"):
        (old / name).write_bytes(b"")
    monkeypatch.setattr(_llvm, "_SEARCH_DIRS", (str(old),))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    monkeypatch.delenv("LD_LIBRARY_PATH", raising=False)
    with pytest.raises(_llvm.LibLLVMError) as caught:
        _llvm.configure_libllvm()
    message = str(caught.value)
    assert "needs libLLVM >= 16" in message and "\n" not in message
    assert f"libLLVM 15 ({old / 'libLLVM-15.so'})" in message
    assert f"libLLVM 14 ({old / 'libLLVM-14.so.1'})" in message
    assert "apt-get install libllvm19" in message and "DRJIT_LIBLLVM_PATH" in message
    assert "DRJIT_LIBLLVM_PATH" not in os.environ

    new = tmp_path / "new"  # on LD_LIBRARY_PATH, as the dynamic loader would look
    new.mkdir()
    (new / "libLLVM-19.so").write_bytes(b"")
    monkeypatch.setenv("LD_LIBRARY_PATH", str(new))
    _llvm.configure_libllvm()
    assert os.environ["DRJIT_LIBLLVM_PATH"] == str(new / "libLLVM-19.so")
