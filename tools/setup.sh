#!/usr/bin/env bash
# One-time set-up: a libLLVM that Dr.Jit's LLVM backend accepts (>= 16), Chromium for
# the report's browser test, and a virtual environment in .venv with the package
# installed in editable mode.
set -euo pipefail
cd "$(dirname "$0")/.."

have_llvm() {
    # Dr.Jit needs libLLVM >= 16; Debian 12 ships 14 and 15, which crash it.
    ldconfig -p 2>/dev/null | grep -Eq 'libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'
}

have_chromium() {
    # the browser test of the HTML report (tests/test_demo.py) uses Debian's Chromium
    command -v chromium >/dev/null 2>&1
}

missing=()
have_llvm || missing+=(libllvm19)
have_chromium || missing+=(chromium)
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing Debian's ${missing[*]} (Dr.Jit needs libLLVM >= 16; the" \
             "report test needs a browser)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            "${missing[@]}" >/dev/null
    elif ! have_llvm; then
        echo "setup: Dr.Jit needs libLLVM >= 16 and none was found." >&2
        echo "       Install it (Debian/Ubuntu: sudo apt-get install libllvm19)," >&2
        echo "       or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version 16 or newer." >&2
        exit 1
    else
        echo "setup: Chromium was not found and cannot be installed here (not root or no" \
             "apt-get); the report's browser test will fail until 'chromium' is on PATH." >&2
    fi
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
touch .venv/.installed
echo "setup: done (.venv)"
