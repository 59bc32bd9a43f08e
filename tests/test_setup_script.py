"""setup.sh decides reliably whether libusb-1.0 is installed.

`ldconfig -p | grep -q` under `set -o pipefail` failed about 1 run in 20: grep
exits at the first match, ldconfig gets SIGPIPE, the pipeline fails, and setup
ran apt-get again (which then failed on dpkg's lock). The check must answer the
same way every time. The install waits for a concurrent apt run instead of
failing on dpkg's lock.
"""

from __future__ import annotations

import fcntl
import os
import pathlib
import shutil
import subprocess
import time

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


@pytest.mark.skipif(shutil.which("apt-get") is None or os.geteuid() != 0,
                    reason="needs apt-get and root (the dpkg lock)")
def test_setups_apt_get_waits_for_a_concurrent_apt_run():
    """setup.sh's install command, run while another process holds dpkg's frontend lock for 2 s, waits for it
    and succeeds (apt-get without a lock timeout fails at once, exit 100). No package is named, so nothing is
    installed."""
    line = next(t.strip() for t in (ROOT / "setup.sh").read_text().splitlines()
                if "apt-get" in t and " install " in t)
    script = f'set -euo pipefail\nMISSING=()\nSUDO=""\n{line}\n'
    fd = os.open("/var/lib/dpkg/lock-frontend", os.O_RDWR | os.O_CREAT, 0o640)
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX)  # waits for any other apt run first
        start = time.monotonic()
        proc = subprocess.Popen(["bash", "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(2)
        assert proc.poll() is None, proc.communicate()  # still waiting, not failed
        fcntl.lockf(fd, fcntl.LOCK_UN)
        out, err = proc.communicate(timeout=120)
    finally:
        os.close(fd)
    assert (proc.returncode, err) == (0, "")
    assert time.monotonic() - start >= 2
