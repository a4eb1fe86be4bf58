"""An example lfstudio camera plugin: a "camera" whose frames are a 12-bit ramp and a moving spot.

lfstudio finds it through the entry point in pyproject.toml (group ``lfstudio.cameras``, name
``ramp``): ``lfstudio scan --camera ramp:WIDTHxHEIGHT`` calls :func:`open_camera` with the text after
``ramp:``. It is an *array camera*: ``grab()`` returns a :class:`lfstudio.dataset.frames.Frame` and
the scan writes it (here as a 16-bit PNG), checksums and journals it. A camera that writes its own
files implements ``capture(stem_path, on_exposed=None) -> CaptureResult`` instead (see
lfstudio/rig/camera.py); optional capabilities (``identity()``, ``describe_settings()``, ``stop()``,
...) are found by what the object has.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from lfstudio.dataset.frames import Frame
from lfstudio.errors import DeviceError, InputError


class RampCamera:
    """Frames of ``width`` x ``height`` px, 12 bits; settings: ``exposure_s`` and ``gain``."""

    name = "Ramp camera (example plugin)"

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self._settings: dict[str, Any] = {"exposure_s": 0.01, "gain": 1.0}
        self._connected = False
        self._count = 0

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def identity(self) -> dict[str, Any]:
        return {"model": "Ramp", "serial": f"{self.width}x{self.height}"}

    def settings(self) -> dict[str, Any]:
        return dict(self._settings)

    def set_setting(self, name: str, value: Any) -> None:
        if name not in self._settings:
            raise InputError(name, "unknown setting of the ramp camera", ", ".join(self._settings))
        number = float(value)
        if not 0 < number <= 100:
            raise InputError(name, f"{value!r} is out of range", "0 … 100")
        self._settings[name] = number

    def grab(self, on_exposed: Callable[[], None] | None = None) -> Frame:
        if not self._connected:
            raise DeviceError("ramp camera: not connected")
        y, x = np.mgrid[0:self.height, 0:self.width]
        cx, cy = (self._count * 7) % self.width, self.height // 2
        ramp = (x * 4095 // max(1, self.width - 1)).astype(np.float32) * float(self._settings["gain"])
        ramp[(x - cx) ** 2 + (y - cy) ** 2 < 25] = 4095
        if on_exposed is not None:
            on_exposed()
        self._count += 1
        return Frame(np.clip(ramp, 0, 4095).astype(np.uint16), "mono", 12, pixel_format="Mono12",
                     exposure_s=float(self._settings["exposure_s"]), timestamp_ns=time.time_ns(),
                     frame_id=self._count, settings=self.settings(), identity=self.identity())


def open_camera(arguments: str) -> RampCamera:
    """``ramp:WIDTHxHEIGHT`` (e.g. ``ramp:640x480``; empty: 320x240)."""
    text = arguments.strip() or "320x240"
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError("--camera", f"ramp:{arguments}: cannot read the size", "ramp:WIDTHxHEIGHT, e.g. ramp:640x480") \
            from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise InputError("--camera", f"ramp:{arguments}: size out of range", "16 … 8192 px each side")
    return RampCamera(width, height)
