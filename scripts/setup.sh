#!/usr/bin/env bash
# Installs everything sgdr needs on a fresh Debian machine (run as root): libLLVM for Dr.Jit's
# LLVM backend, then sgdr with its pinned dependencies in editable mode. Idempotent: a second
# run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

# Dr.Jit's LLVM backend needs libLLVM >= 16 (Debian bookworm's 14/15 abort on dr.maximum).
if ! ls /usr/lib/*/libLLVM-19.so* /usr/lib/libLLVM-19.so* >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19
    else
        echo "setup: libLLVM 19 not found and apt-get is unavailable; install LLVM >= 16 and set DRJIT_LIBLLVM_PATH" >&2
        exit 1
    fi
fi

# Editable install with pinned dependencies; skipped when the same pyproject is already installed.
stamp=.setup-stamp
sum=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$sum" ] && $PY -c "import sgdr, drjit, mitsuba" 2>/dev/null; then
    echo "setup: already up to date"
else
    $PY -m pip install --quiet --disable-pip-version-check -e .
    echo "$sum" > "$stamp"
fi
$PY -c "import sgdr.backend as b; b.check_llvm(); print('setup: ok, libLLVM at', b.find_libllvm())"
