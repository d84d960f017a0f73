"""Point Dr.Jit's LLVM backend at a libLLVM it can use.

Dr.Jit needs libLLVM >= 16. Debian 12 ships 14 and 15 next to whatever the
set-up installed, and Dr.Jit crashes on those ("Cannot select fminimum"), so
when ``DRJIT_LIBLLVM_PATH`` is unset we pick the newest suitable library
before :mod:`drjit` is first imported.
"""

from __future__ import annotations

import glob
import os
import re

_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
)
MINIMUM_LLVM_MAJOR = 16


def _major_version(path: str) -> int | None:
    match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    return int(match.group(1)) if match else None


def find_libllvm(minimum_major: int = MINIMUM_LLVM_MAJOR) -> str | None:
    """Return the path of the newest libLLVM with major version >= ``minimum_major``."""
    candidates = []
    for directory in _SEARCH_DIRS:
        for path in glob.glob(os.path.join(directory, "libLLVM*.so*")):
            major = _major_version(path)
            if major is not None and major >= minimum_major:
                candidates.append((major, path))
    return max(candidates)[1] if candidates else None


def configure_libllvm() -> None:
    """Set ``DRJIT_LIBLLVM_PATH`` unless the user already chose a library."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return
    path = find_libllvm()
    if path is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
