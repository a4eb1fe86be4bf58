"""aravis's own fake GigE Vision camera for the tests: the real protocol (GVCP/GVSP over UDP), no fake
of ours.

``arv-fake-gv-camera-0.8`` (Debian's ``aravis-tools``) serves one camera, ``Aravis-Fake-GV01``, on an
interface's address; only addresses of an interface work, so the tests use 127.0.0.1, and GigE
Vision's control port is fixed (3956): one fake camera at a time on a machine. :func:`fake_gv_camera`
starts one (``lost_per_thousand``: its ``-r`` option, GVSP packets dropped per thousand) as a
subprocess and stops it at the end; a file lock makes test processes (pytest-xdist workers, other
checkouts) take turns. Its pictures: Mono8 512 x 512 by default (sensor 2048 x 2048), pixel (x, y) of
frame ``id`` is ``(x + id + y) % 255`` at the default exposure and gain; software trigger works, a
``Line0`` trigger never fires (it has no line), and it does not answer packet-resend requests, so a
dropped packet loses its frame.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

EXE = "arv-fake-gv-camera-0.8"
ADDRESS = "127.0.0.1"
DEVICE_ID = "Aravis-Fake-GV01"
LOCK = Path(tempfile.gettempdir()) / "lfstudio-fake-gv-camera.lock"


@dataclass(frozen=True)
class FakeGV:
    device_id: str
    address: str
    process: subprocess.Popen


def need_aravis() -> str:
    """The fake camera's program; skips when it or aravis's Python binding is missing."""
    from lfstudio.rig.genicam import aravis_available

    exe = shutil.which(EXE)
    if exe is None:
        pytest.skip(f"{EXE} is not installed (apt-get install aravis-tools)")
    if not aravis_available():
        pytest.skip("aravis's Python binding is not available (apt-get install gir1.2-aravis-0.8 python3-gi, "
                    "then tools/setup-env.sh)")
    return exe


def expected_mono8(frame_id: int, width: int = 512, height: int = 512) -> np.ndarray:
    """The fake camera's Mono8 picture of frame ``frame_id`` at its default exposure and gain."""
    y, x = np.mgrid[0:height, 0:width]
    return ((x + frame_id + y) % 255).astype(np.uint8)


@contextmanager
def fake_gv_camera(lost_per_thousand: int = 0, timeout_s: float = 20.0) -> Iterator[FakeGV]:
    """Run the fake camera on 127.0.0.1 until the block ends (see the module docstring)."""
    exe = need_aravis()
    from lfstudio.rig.genicam import list_cameras

    with open(LOCK, "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)        # one fake camera at a time (fixed GVCP port)
        args = [exe, "-i", ADDRESS] + (["-r", str(int(lost_per_thousand))] if lost_per_thousand else [])
        proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True, env={**os.environ, "LC_ALL": "C"})
        try:
            deadline = time.monotonic() + timeout_s
            while DEVICE_ID not in list_cameras():     # discovery answers once it listens (each try waits ~1 s)
                if proc.poll() is not None:
                    pytest.fail(f"{EXE} ended at once: {(proc.stderr.read() if proc.stderr else '').strip()}")
                if time.monotonic() > deadline:
                    pytest.fail(f"{EXE} did not answer discovery within {timeout_s:g} s")
            yield FakeGV(DEVICE_ID, ADDRESS, proc)
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.stderr is not None:
                proc.stderr.close()
