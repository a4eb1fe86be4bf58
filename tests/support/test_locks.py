"""OS-level locks with real processes: the second is refused naming the holder; a dead holder's lock
is taken over; a serial port is also locked on its device node (like pyserial's exclusive=True)."""

from __future__ import annotations

import os
import subprocess
import sys
import tty

import pytest
import serial

from lfstudio.support.locks import LockBusy, dataset_lock, holder_of, port_lock
from tests.studio.conftest import cli_env

HOLD = """
import sys
from lfstudio.support.locks import {factory}
lock = {factory}(sys.argv[1], "testing the lock").acquire()
print("held", flush=True)
sys.stdin.read()
"""


def hold_in_child(factory: str, target) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLD.format(factory=factory), str(target)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=cli_env())
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_dataset_lock_refuses_a_second_process_then_takes_over_from_a_dead_one(tmp_path):
    child = hold_in_child("dataset_lock", tmp_path)
    try:
        with pytest.raises(LockBusy) as refused:
            dataset_lock(tmp_path, "second").acquire()
        text = str(refused.value)
        assert f"pid {child.pid}" in text and "testing the lock" in text and str(tmp_path) in text
        holder = holder_of(tmp_path / "dataset.lock")
        assert holder is not None and holder.pid == child.pid
    finally:
        child.kill()                     # kill -9: no clean-up runs in the holder
        child.wait(10)
        child.stdin.close()
        child.stdout.close()
    assert holder_of(tmp_path / "dataset.lock") is None       # the kernel dropped its flock
    lock = dataset_lock(tmp_path, "third").acquire()
    try:
        assert lock.taken_over is not None and lock.taken_over.pid == child.pid
        assert holder_of(tmp_path / "dataset.lock").pid == os.getpid()
    finally:
        lock.release()
    assert (tmp_path / "dataset.lock").read_text() == ""       # released: no holder named any more


def test_port_lock_refuses_a_second_process_and_locks_the_device_node():
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    try:
        child = hold_in_child("port_lock", port)
        try:
            with pytest.raises(LockBusy, match=f"rig port {port} is in use by .*pid {child.pid}"):
                port_lock(port).acquire()
            # another program locking the port the way pyserial does (exclusive=True) is kept out too
            with pytest.raises(serial.SerialException, match="exclusively lock"):
                serial.Serial(port, exclusive=True)
        finally:
            child.kill()
            child.wait(10)
            child.stdin.close()
            child.stdout.close()
        # and the other way round: a port another program holds exclusively is refused
        other = serial.Serial(port, exclusive=True)
        try:
            with pytest.raises(LockBusy, match="another program"):
                port_lock(port).acquire()
        finally:
            other.close()
        with port_lock(port, "now free"):
            pass
    finally:
        os.close(master)
        os.close(slave)


def test_a_camera_in_use_is_refused_naming_its_holder(run_cli, tmp_path):
    child = hold_in_child("camera_lock", "gphoto2")
    try:
        r = run_cli("camera", tmp_path / "shot", "--camera", "gphoto2")
        assert r.returncode == 1 and "Traceback" not in r.stderr
        assert "camera gphoto2 is in use by" in r.stderr and f"pid {child.pid}" in r.stderr
        assert not list(tmp_path.iterdir())
    finally:
        child.kill()
        child.wait(10)
        child.stdin.close()
        child.stdout.close()


FAILED_WRITE = """
import fcntl, os, resource, signal, sys, tty
from lfstudio.support.locks import LockBusy, port_lock
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)      # the write fails with EFBIG instead of killing us
master, slave = os.openpty()
tty.setraw(slave)
port = os.ttyname(slave)
soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
resource.setrlimit(resource.RLIMIT_FSIZE, (0, hard))  # the holder line cannot be written (as on a full disk)
try:
    port_lock(port, "first try").acquire()
    print("acquired with no holder line written")
except OSError as exc:
    print("first try failed:", exc.errno)
resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
try:
    lock = port_lock(port, "second try").acquire()
except LockBusy as exc:
    print("second try refused:", exc)
else:
    print("second try held")
    lock.release()
"""


def test_a_lock_whose_holder_line_cannot_be_written_leaves_the_port_free(tmp_path):
    """Taking a port's lock flocks its device node too; when writing the holder line then fails (a full
    disk), the device node's lock must go with the failure: the process that failed must be able to
    try again (it was refused by its own leftover lock, "in use by another program", until it ended)."""
    env = {**cli_env(), "LFSTUDIO_RUNTIME_DIR": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", FAILED_WRITE], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "first try failed: 27" in r.stdout                  # EFBIG: the holder line was refused
    assert "second try held" in r.stdout, r.stdout


def test_a_hot_folder_with_a_long_path_gets_a_lock_of_its_own(tmp_path, monkeypatch):
    """A lock file is named after what it locks: a hot folder 300 characters deep made a name longer than a
    file name may be, and the camera could not be used at all ('File name too long', blaming the lock
    file). Long names are shortened with a digest, so two long folders that differ only at their end
    are still two locks, and one folder is still one."""
    from lfstudio.support.locks import camera_lock

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path))
    deep = "/studio/" + "/".join(["capture-session-2026-11-29"] * 12)
    first = camera_lock(f"folder-{deep}/left", "the first").acquire()
    try:
        other = camera_lock(f"folder-{deep}/right", "another folder").acquire()
        other.release()
        with pytest.raises(LockBusy, match="is in use by .*the first"):
            camera_lock(f"folder-{deep}/left", "the second").acquire()
    finally:
        first.release()
