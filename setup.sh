#!/usr/bin/env bash
# Sets up cloudsieve on a fresh Debian/Ubuntu machine with Python >= 3.10:
# the system library open3d needs (libusb-1.0-0, via apt-get when missing),
# then a virtual environment in .venv with cloudsieve and its test extras.
set -euo pipefail
cd "$(dirname "$0")"

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "setup: installing libusb-1.0-0 (needed by open3d) with apt-get" >&2
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test,e57]"
