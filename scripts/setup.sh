#!/usr/bin/env bash
# Installs everything sgdr needs on a fresh Debian machine (run as root): libLLVM for Dr.Jit's
# LLVM backend, a virtual environment at .venv (Debian's Python refuses system-wide pip
# installs, PEP 668), and sgdr with its pinned dependencies in editable mode. Idempotent: a
# second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
apt_updated=0
apt_install() {
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "setup: need $* but apt-get is unavailable; install them by hand" >&2
        exit 1
    fi
    [ "$apt_updated" = 1 ] || { $SUDO apt-get update -qq; apt_updated=1; }
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@"
}

# Dr.Jit's LLVM backend needs libLLVM >= 16 (Debian bookworm's 14/15 abort on dr.maximum).
if ! ls /usr/lib/*/libLLVM-19.so* /usr/lib/libLLVM-19.so* >/dev/null 2>&1; then
    apt_install libllvm19
fi

# The report test opens report.html in a real browser: Debian's Chromium and its driver
# (selenium drives /usr/bin/chromedriver; nothing is downloaded at test time).
if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then
    apt_install chromium chromium-driver
fi

command -v "$PY" >/dev/null 2>&1 || apt_install python3 python3-venv
if [ ! -x "$VENV/bin/python" ]; then
    if ! "$PY" -m venv "$VENV" 2>/dev/null; then
        rm -rf "$VENV"
        apt_install python3-venv
        "$PY" -m venv "$VENV"
    fi
fi

# Editable install with pinned dependencies and the test extra (pytest, ruff); skipped when the
# same pyproject and extras are installed.
EXTRAS="test"
stamp="$VENV/.sgdr-setup-stamp"
sum="$(sha256sum pyproject.toml | cut -d' ' -f1) extras=$EXTRAS"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$sum" ] && "$VENV/bin/python" -c "import sgdr, drjit, mitsuba, pytest" 2>/dev/null; then
    echo "setup: already up to date"
else
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -e ".[$EXTRAS]"
    echo "$sum" > "$stamp"
fi
"$VENV/bin/python" -c "import sgdr.backend as b; print('setup: ok, libLLVM at', b.check_llvm())"
