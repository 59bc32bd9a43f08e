"""setup.sh decides reliably whether libusb-1.0 is installed.

`ldconfig -p | grep -q` under `set -o pipefail` failed about 1 run in 20: grep
exits at the first match, ldconfig gets SIGPIPE, the pipeline fails, and setup
ran apt-get again (which then failed on dpkg's lock). The check must answer the
same way every time.
"""

from __future__ import annotations

import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _ldconfig_knows_libusb() -> bool:
    out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, check=False).stdout
    return "libusb-1.0.so.0" in out


@pytest.mark.skipif(shutil.which("ldconfig") is None, reason="no ldconfig on this system")
def test_libusb_check_gives_the_same_answer_every_time():
    expected = _ldconfig_knows_libusb()
    script = (
        "set -euo pipefail\n"
        f'source <(sed -n "/^has_libusb()/,/^}}/p" "{ROOT / "setup.sh"}")\n'
        "yes=0; no=0\n"
        "for i in $(seq 200); do if has_libusb; then yes=$((yes+1)); else no=$((no+1)); fi; done\n"
        'echo "$yes $no"\n'
    )
    out = subprocess.run(["bash", "-c", script], capture_output=True, text=True, check=True).stdout.split()
    yes, no = int(out[0]), int(out[1])
    assert (yes, no) == ((200, 0) if expected else (0, 200))


def test_setup_does_not_pipe_into_grep_q():
    text = (ROOT / "setup.sh").read_text()
    assert "grep -q" not in text
    assert "DPkg::Lock::Timeout" in text  # waits for a concurrent apt run instead of failing
