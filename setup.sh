#!/usr/bin/env bash
# Sets up cloudsieve on a fresh Debian/Ubuntu machine with Python >= 3.10:
# the system library open3d needs (libusb-1.0-0) and the browser the report
# tests use (chromium), via apt-get when missing,
# then a virtual environment in .venv with cloudsieve and its test extras.
set -euo pipefail
cd "$(dirname "$0")"

# True when the dynamic linker knows libusb-1.0. The whole listing is read into a
# variable first: piping ldconfig into a quiet grep under pipefail fails at random when grep
# exits early and ldconfig gets SIGPIPE (measured: 16 of 300 runs).
has_libusb() {
    local libs
    libs="$(ldconfig -p 2>/dev/null || true)"
    [[ "$libs" == *"libusb-1.0.so.0"* ]]
}

# True when Debian's chromium is installed (the tests open report.html in it, headless).
has_chromium() {
    [ -x /usr/bin/chromium ]
}

MISSING=()
if ! has_libusb; then MISSING+=(libusb-1.0-0); fi
if ! has_chromium; then MISSING+=(chromium); fi
if [ "${#MISSING[@]}" -gt 0 ]; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "setup: installing ${MISSING[*]} (libusb-1.0-0: needed by open3d; chromium: the report.html tests) with apt-get" >&2
    # wait for another apt/dpkg run instead of failing on its lock
    $SUDO apt-get -o DPkg::Lock::Timeout=300 update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get -o DPkg::Lock::Timeout=300 install -y -qq "${MISSING[@]}" >/dev/null
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test,e57]"

# The package's bytecode, written once now, as a non-editable pip install does: an editable install
# writes it at the first import, and never where PYTHONDONTWRITEBYTECODE is set; then every start
# compiles ~100 modules from source (a 1,000-point file: 1.16 s median against 0.95 s, measured).
.venv/bin/python -m compileall -q src

# Compile every numba kernel into numba's on-disk cache now, once (28-45 s on 2 cores), so the
# first run loads them in about a second instead of compiling them (`cloudsieve warmup --help`).
.venv/bin/python -m cloudsieve warmup
