#!/usr/bin/env bash
# Sets up cloudsieve on a fresh Debian/Ubuntu machine with Python >= 3.10:
# the system library open3d needs (libusb-1.0-0, via apt-get when missing),
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

if ! has_libusb; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "setup: installing libusb-1.0-0 (needed by open3d) with apt-get" >&2
    # wait for another apt/dpkg run instead of failing on its lock
    $SUDO apt-get -o DPkg::Lock::Timeout=300 update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get -o DPkg::Lock::Timeout=300 install -y -qq libusb-1.0-0 >/dev/null
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test,e57]"

# Compile every numba kernel into numba's on-disk cache now, once (a few minutes on 2 cores), so the
# first run loads them in about a second instead of compiling them (`cloudsieve warmup --help`).
.venv/bin/python -m cloudsieve warmup
