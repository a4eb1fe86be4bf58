"""One Ctrl+C of ``lfstudio scan --status-http`` stops the scan and ends the process (it stayed for
``--status-linger-s``, 600 s by default, until a second Ctrl+C): a real process, a real SIGINT mid-scan;
it exits 130 with its journal consistent (every view marked done has its whole file) and the page's
port free. A scan that ends by itself still lingers (tests/cli/test_scan_secrets.py)."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time

from lfstudio.dataset import Dataset
from tests.conftest import REPO_ROOT
from tests.scankill import journal_lines, lfstudio_env

ARGS = ["--port", "sim", "--camera", "sim", "--grid", "6x3", "--spacing-mm", "4x6", "--time-scale", "0.3",
        "--sim-width-px", "96", "--status-http", "127.0.0.1:0", "--status-linger-s", "3600"]
HANG_GUARD_S = 120      # the old process stayed 3600 s: only a second Ctrl+C ended it


def test_one_ctrl_c_ends_a_scan_with_a_status_page(tmp_path):
    out = tmp_path / "ds"
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", *ARGS, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=lfstudio_env(),
                            cwd=REPO_ROOT)
    ended = True
    try:
        while proc.poll() is None and journal_lines(out) < 2:
            time.sleep(0.01)        # polling the journal the scan writes, not synchronising on a duration
        assert proc.poll() is None, proc.communicate()[1]
        proc.send_signal(signal.SIGINT)
        try:
            _, stderr = proc.communicate(timeout=HANG_GUARD_S)
        except subprocess.TimeoutExpired:
            ended = False
            proc.send_signal(signal.SIGINT)            # the old way out: a second Ctrl+C
            _, stderr = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert ended, "one Ctrl+C did not end the process"
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert "shows the final state until" not in stderr, stderr
    url = next(line.split("status page (read-only): ", 1)[1].split()[0] for line in stderr.splitlines()
               if "status page (read-only)" in line)
    port = int(url.rsplit(":", 1)[1].split("/")[0])
    with socket.socket() as s:                         # the page is gone with the process
        assert s.connect_ex(("127.0.0.1", port)) != 0
    ds = Dataset.open(out)
    try:
        assert 2 <= ds.status_counts()["done"] < 18 and ds.verify_files() == []
    finally:
        ds.close()
