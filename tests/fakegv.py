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
dropped packet loses its frame. :func:`scene_gv_camera` serves the same fake camera from this process
with pictures of the caller's making (the virtual studio at the rig's true position).
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import shutil
import subprocess
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

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


# -- a fake camera that photographs something ----------------------------------------------------
SCENE_SERIAL = "LFScene01"


class _GObject(ctypes.Structure):
    _fields_ = [("g_class", ctypes.c_void_p), ("ref_count", ctypes.c_uint), ("qdata", ctypes.c_void_p)]


class _BufferPrivate(ctypes.Structure):
    """The head of aravis 0.8's ``ArvBufferPrivate`` (src/arvbufferprivate.h of 0.8.26), up to
    ``received_size``, which has no public setter and a fill callback must set."""

    _fields_ = [("allocated_size", ctypes.c_size_t), ("is_preallocated", ctypes.c_int), ("data", ctypes.c_void_p),
                ("user_data", ctypes.c_void_p), ("user_data_destroy_func", ctypes.c_void_p), ("status", ctypes.c_int),
                ("received_size", ctypes.c_size_t)]


class _Buffer(ctypes.Structure):
    _fields_ = [("object", _GObject), ("priv", ctypes.POINTER(_BufferPrivate))]


FILL_PATTERN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32,
                                ctypes.c_uint32)
MONO8 = 0x01080001


@dataclass
class SceneGV:
    """An in-process fake GigE Vision camera (``device_id``: its IP address) whose frames ``render`` makes;
    ``frames``: how many it filled, ``problems``: what went wrong inside the callback (raised at the end)."""

    device_id: str
    frames: int = 0
    problems: list = field(default_factory=list)


@contextmanager
def scene_gv_camera(render: Callable[[int, int], np.ndarray]) -> Iterator[SceneGV]:
    """aravis's fake GigE Vision camera (``Aravis.GvFakeCamera``: the GVCP/GVSP server of
    ``arv-fake-gv-camera-0.8``) served from this process on 127.0.0.1, each Mono8 frame's pixels from
    ``render(width, height)`` (uint8, height x width) instead of its diagonal ramp, so the frames carry a
    picture (the virtual studio at the rig's true position) that calibration can use.

    aravis's own hook for it, ``ArvFakeCamera.set_fill_pattern``, cannot take a Python function through
    GObject introspection: its annotation is ``(scope call)``, so PyGObject frees the closure when the call
    returns and the camera's first frame crashes the process (checked: exit 139 on 0.8.26). The callback is
    set through ctypes instead (kept alive here), and it sets the buffer's received size, which aravis's
    public API cannot, through the layout of 0.8.26's ``ArvBufferPrivate``: checked on the first frame
    against ``arv_buffer_get_data``'s pointer (a mismatch is a test failure naming the layout)."""
    need_aravis()
    import importlib

    import gi

    gi.require_version("Aravis", "0.8")
    Aravis = importlib.import_module("gi.repository.Aravis")     # made by gi's importer at run time

    try:
        lib = ctypes.CDLL("libaravis-0.8.so.0")
    except OSError as exc:
        pytest.skip(f"libaravis-0.8.so.0 cannot be loaded through ctypes ({exc})")
    lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, FILL_PATTERN, ctypes.c_void_p]
    lib.arv_buffer_get_data.restype = ctypes.c_void_p
    lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    for name in ("arv_buffer_get_image_width", "arv_buffer_get_image_height"):
        getattr(lib, name).argtypes = [ctypes.c_void_p]
    served = SceneGV(ADDRESS)

    def fill(buffer: int, _data: int, _exposure_us: int, _gain: int, pixel_format: int) -> None:
        try:
            size = ctypes.c_size_t()
            data = lib.arv_buffer_get_data(buffer, ctypes.byref(size))
            priv = ctypes.cast(buffer, ctypes.POINTER(_Buffer)).contents.priv.contents
            if priv.data != data:
                raise RuntimeError("ArvBufferPrivate's layout is not that of aravis 0.8.26")
            width, height = lib.arv_buffer_get_image_width(buffer), lib.arv_buffer_get_image_height(buffer)
            if pixel_format != MONO8:
                raise RuntimeError(f"the scene camera serves Mono8 only (pixel format {pixel_format:#x})")
            image = np.ascontiguousarray(render(width, height), dtype=np.uint8)
            if image.shape != (height, width) or image.nbytes > priv.allocated_size:
                raise RuntimeError(f"render gave {image.shape} for {width} x {height}")
            ctypes.memmove(data, image.ctypes.data, image.nbytes)
            priv.received_size = image.nbytes
            served.frames += 1
        except Exception as exc:  # noqa: BLE001 - raised in the test's thread at the end
            served.problems.append(exc)

    callback = FILL_PATTERN(fill)
    with open(LOCK, "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)        # one fake camera at a time (fixed GVCP port)
        camera = Aravis.GvFakeCamera.new(ADDRESS, SCENE_SERIAL)
        try:
            if not camera.is_running():
                pytest.fail("aravis's fake GigE Vision camera did not start on 127.0.0.1")
            lib.arv_fake_camera_set_fill_pattern(hash(camera.get_fake_camera()), callback, None)
            yield served
        finally:
            del camera                      # stops its threads (GObject unref)
            import gc

            gc.collect()
    if served.problems:
        raise served.problems[0]
