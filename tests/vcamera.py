"""libgphoto2's own virtual PTP camera (vusb) for the tests: the real PTP stack, no fake.

The python-gphoto2 wheel ships libgphoto2's ``vusb`` port library beside its USB one. With
``VCAMERADIR=<folder>`` it presents a "Nikon DSC D750" whose storage is the folder's
``DCIM/100TEST`` (JPEG, DNG, ... files); ``capture()`` adds a copy of the first JPEG as
``/store_00010001/DCIM/100GPHOT/GPH_NNNN.JPG``; file_get/file_delete work (deleting is virtual:
the folder's files stay); it offers f-number, exposure time and a read-only image size, no live
view (-6), and after ~26 captures in one session answers "store full" (-3).

What we found about running it in one process: python-gphoto2 picks the port libraries (the
``IOLIBS`` variable) once, when ``gphoto2`` is imported (``vusb`` if ``VCAMERADIR`` is set then,
USB otherwise); libgphoto2 itself reads ``IOLIBS`` and ``VCAMERADIR`` again at every
``Camera.init()``. vusb keeps its store (the folder's files, the pictures taken, the "full"
counter) in process-wide state that is reset when no ``gp.Camera`` object of the process is left:
a new session while an old camera object is still alive (e.g. held by a kept exception's
traceback) starts with the old, maybe full, store. So a test switches to the virtual camera by
setting both variables after importing gphoto2 (:func:`use_vcamera`, which also collects old
camera objects), and back by restoring them; no subprocess is needed. The CLI tests run ``python -m lfstudio`` with
``VCAMERADIR`` set, as an operator would.
"""

from __future__ import annotations

import gc
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

STORE = "/store_00010001"
SOURCE_FOLDER = f"{STORE}/DCIM/100TEST"
MODEL = "Nikon DSC D750"        # libgphoto2's name for the USB ids vusb presents


@dataclass(frozen=True)
class VCamera:
    folder: Path        # VCAMERADIR
    jpeg: Path          # every capture returns a copy of this file
    dngs: tuple[Path, ...]   # DNG files in the camera's storage (for the RAW + JPEG test)
    iolibs: Path        # python-gphoto2's vusb port library folder


def port_libraries(gp, kind: str) -> Path:
    """python-gphoto2's folder of port libraries: ``vusb`` (the virtual camera) or ``iolibs`` (USB)."""
    return Path(gp.__file__).parent / "libgphoto2" / kind


def write_vcamera_folder(folder: Path, *, dngs: int = 0, seed: int = 0) -> tuple[Path, tuple[Path, ...]]:
    """``folder/DCIM/100TEST`` with one real JPEG (OpenCV) and ``dngs`` real DNGs (our DNG writer)."""
    from lfstudio.sim.dng import write_dng

    src = folder / "DCIM" / "100TEST"
    src.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), (0, 0), 3)
    cv2.putText(img, "vusb", (60, 140), cv2.FONT_HERSHEY_SIMPLEX, 2.5, (0, 220, 255), 6)
    jpeg = src / "IMG_0001.JPG"
    ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 92])
    assert ok
    jpeg.write_bytes(data.tobytes())
    raws = []
    for i in range(dngs):
        path = src / f"RAW_{i + 1:04d}.DNG"
        write_dng(path, rng.integers(600, 4000, (48, 64)).astype(np.uint16))
        raws.append(path)
    return jpeg, tuple(raws)


def use_vcamera(folder: Path, monkeypatch: pytest.MonkeyPatch, *, dngs: int = 0) -> VCamera:
    """Make ``gp.Camera().init()`` in this process find the virtual camera serving ``folder``
    (until ``monkeypatch`` undoes it). Skips when python-gphoto2 or its vusb library is missing."""
    gp = pytest.importorskip("gphoto2", reason="python-gphoto2 is not installed (pip install gphoto2)")
    vusb = port_libraries(gp, "vusb")
    if not any(vusb.glob("vusb*")):
        pytest.skip(f"this python-gphoto2 has no libgphoto2 virtual camera ({vusb} is missing; "
                    "it is in the PyPI wheels, not in builds against a system libgphoto2)")
    jpeg, raws = write_vcamera_folder(folder, dngs=dngs)
    # vusb's store lives until the last session's gp.Camera is freed (see above); pytest keeps the
    # last failed test's traceback (sys.last_*, for post-mortem debugging), whose frames would keep
    # that test's camera, and with it a full or broken store, for every later test of the process
    for name in ("last_type", "last_value", "last_traceback", "last_exc"):
        if hasattr(sys, name):
            setattr(sys, name, None)
    gc.collect()
    monkeypatch.setenv("IOLIBS", str(vusb))
    monkeypatch.setenv("VCAMERADIR", str(folder))
    return VCamera(folder, jpeg, raws, vusb)


def use_usb(monkeypatch: pytest.MonkeyPatch):
    """The real USB port libraries for this process (no virtual camera); returns the gphoto2 module."""
    gp = pytest.importorskip("gphoto2", reason="python-gphoto2 is not installed (pip install gphoto2)")
    monkeypatch.setenv("IOLIBS", str(port_libraries(gp, "iolibs")))
    monkeypatch.delenv("VCAMERADIR", raising=False)
    return gp
