"""Point Dr.Jit's LLVM backend at a libLLVM it can use, or say in one line why there is none.

Dr.Jit needs libLLVM >= 16: on 14 and 15 (Debian 12's default) the first
kernel aborts the process inside LLVM ("Cannot select fminimum", exit -6).
:func:`configure_libllvm` runs before :mod:`drjit` is first imported: it
checks the library ``DRJIT_LIBLLVM_PATH`` names, or picks the newest
suitable one on the library path, and raises :class:`LibLLVMError` (what is
needed, what was found, how to install it) when there is none.
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
import sys

_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
)
MINIMUM_LLVM_MAJOR = 16
INSTALL_HINT = "Debian/Ubuntu: apt-get install libllvm19"


class LibLLVMError(ImportError):
    """No libLLVM that Dr.Jit's LLVM backend can use (the message says what to do)."""


def _major_from_name(path: str) -> int | None:
    match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    return int(match.group(1)) if match else None


def library_major_version(path: str) -> int | None:
    """The major version of the libLLVM at ``path``: from its file name (symlinks
    resolved), else from the library's ``LLVMGetVersion``, which LLVM has since 16
    (so a loadable library without it is reported as 15). None: it cannot be loaded."""
    major = _major_from_name(os.path.realpath(path)) or _major_from_name(path)
    if major is not None:
        return major
    try:
        library = ctypes.CDLL(path)
    except OSError:
        return None
    if not hasattr(library, "LLVMGetVersion"):
        return MINIMUM_LLVM_MAJOR - 1
    numbers = [ctypes.c_uint() for _ in range(3)]
    library.LLVMGetVersion(*(ctypes.byref(n) for n in numbers))
    return int(numbers[0].value)


def _search_dirs() -> list[str]:
    extra = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d]
    return extra + [d for d in _SEARCH_DIRS if d not in extra]


def installed_libllvms() -> list[tuple[int, str]]:
    """``(major version, path)`` of every libLLVM on the library path, newest first."""
    found = {}
    for directory in _search_dirs():
        for path in glob.glob(os.path.join(directory, "libLLVM*.so*")):
            major = _major_from_name(path)
            if major is not None:
                found.setdefault(os.path.realpath(path), (major, path))
    return sorted(found.values(), reverse=True)


def find_libllvm(minimum_major: int = MINIMUM_LLVM_MAJOR) -> str | None:
    """Return the path of the newest libLLVM with major version >= ``minimum_major``."""
    candidates = [(major, path) for major, path in installed_libllvms() if major >= minimum_major]
    return max(candidates)[1] if candidates else None


def configure_libllvm() -> None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a usable libLLVM, or raise :class:`LibLLVMError`.

    A library the user chose (``DRJIT_LIBLLVM_PATH``) must exist and be >= 16;
    otherwise the newest suitable one on the library path is taken.
    """
    needed = (f"Dr.Jit's LLVM backend needs libLLVM >= {MINIMUM_LLVM_MAJOR} (older ones crash "
              "the first kernel)")
    chosen = os.environ.get("DRJIT_LIBLLVM_PATH")
    if chosen:
        if not os.path.isfile(chosen):
            raise LibLLVMError(f"DRJIT_LIBLLVM_PATH={chosen} does not exist; {needed}: point "
                               f"it to one ({INSTALL_HINT}) or unset it")
        major = library_major_version(chosen)
        if major is None:
            raise LibLLVMError(f"DRJIT_LIBLLVM_PATH={chosen} cannot be loaded as a library; "
                               f"{needed}: point it to one ({INSTALL_HINT}) or unset it")
        if major < MINIMUM_LLVM_MAJOR:
            raise LibLLVMError(f"DRJIT_LIBLLVM_PATH={chosen} is libLLVM {major}; {needed}: "
                               f"point it to a newer one ({INSTALL_HINT}) or unset it")
        return
    path = find_libllvm()
    if path is None:
        found = ", ".join(f"libLLVM {major} ({path})" for major, path in installed_libllvms())
        raise LibLLVMError(f"{needed}; found {found or 'none'} in {', '.join(_search_dirs())}: "
                           f"install one ({INSTALL_HINT}) or set DRJIT_LIBLLVM_PATH to its "
                           "file")
    os.environ["DRJIT_LIBLLVM_PATH"] = path


def one_line_if_uncaught(error: LibLLVMError) -> None:
    """Make ``error`` print as one line if nothing catches it (a command, a script).

    It is raised while ``polarbssrdf`` is imported, before the command line's own
    error handling exists, and a traceback would bury the one line that says what
    to install. Other exceptions keep the hook that was there.
    """
    previous = sys.excepthook

    def hook(kind, value, traceback):
        if value is error:
            print(f"polarbssrdf: error: {value}", file=sys.stderr)
        else:
            previous(kind, value, traceback)

    sys.excepthook = hook
