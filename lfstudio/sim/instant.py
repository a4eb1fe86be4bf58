"""Instant devices: a rig that arrives at once and a camera that writes a tiny image at once.

They implement :class:`lfstudio.rig.motion.MotionController` and :class:`lfstudio.rig.camera.Camera`
without any timing, so what is left of a scan's duration is the engine's own overhead
(``benchmarks/scan_overhead.py``). For realistic timing use the GRBL simulator and the simulated
camera, wired together by :mod:`lfstudio.studio.devices`.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import CaptureResult, setting_number
from lfstudio.rig.motion import RigConfig, RigState, RigStatus


class InstantRig:
    """A MotionController whose moves take no time; refuses targets outside the soft limits."""

    def __init__(self, config: RigConfig):
        self.config = config
        self._pos = (config.horizontal.soft_min_mm, config.vertical.soft_min_mm)
        self._connected = False
        self._lock = threading.Lock()
        self.moves = 0

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def home(self) -> None:
        self._pos = (self.config.horizontal.soft_min_mm, self.config.vertical.soft_min_mm)

    def set_origin(self) -> None:
        pass

    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        if not self._connected:
            raise DeviceError("instant rig: not connected")
        if not (self.config.horizontal.contains(x_mm) and self.config.vertical.contains(y_mm)):
            raise DeviceError(f"instant rig: target ({x_mm:g}, {y_mm:g}) mm is outside the soft limits")
        with self._lock:
            self._pos = (float(x_mm), float(y_mm))
            self.moves += 1
        return self.status()

    def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None:
        self.move_to(self._pos[0] + dx_mm, self._pos[1] + dy_mm)

    def jog_cancel(self) -> None:
        pass

    def feed_hold(self) -> None:
        pass

    def resume(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def reset(self) -> None:
        pass

    def status(self) -> RigStatus:
        if not self._connected:
            return RigStatus(RigState.DISCONNECTED)
        return RigStatus(RigState.IDLE, self._pos, homed=True)

    def true_position_mm(self) -> tuple[float, float]:
        return self._pos


class InstantCamera:
    """A Camera that writes a small PNG (a gradient shifted by the rig position) at once."""

    name = "Instant camera"

    def __init__(self, position_mm: Callable[[], tuple[float, float]] | None = None, size_px: tuple[int, int] = (64, 48),
                 render: Callable[[float, float], np.ndarray] | None = None, describe_size: bool = False):
        """``render(x_mm, y_mm)`` (optional) returns the RGB uint8 image to write instead of the gradient,
        e.g. a small :class:`lfstudio.sim.studio.VirtualStudio` rendering.

        ``describe_size``: :meth:`identity` tells the image size (``sensor_px``), so the scan's disk
        pre-flight counts these small files (:func:`lfstudio.scan.preflight.view_size`) instead of the
        scene plan's camera (84 MB an image for the reference camera: a 2121-view scan from the window
        was refused as needing 179 GB). Off by default: the instant camera also stands for the cameras
        whose frame size nothing tells before the first picture (a gphoto2 camera, a hot folder)."""
        self.position_mm = position_mm or (lambda: (0.0, 0.0))
        self.size_px = size_px
        self.describe_size = describe_size
        self.render = render
        self._connected = False
        self.shutter_s = 0.0
        w, h = size_px
        yy, xx = np.mgrid[0:h, 0:w]
        self._base = np.dstack([(xx * 4) % 256, (yy * 5) % 256, ((xx + yy) * 3) % 256]).astype(np.uint8)
        self.captures = 0

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def identity(self) -> dict[str, Any]:
        """``{"sensor_px": [w, h]}`` with ``describe_size``, else nothing."""
        return {"sensor_px": [int(v) for v in self.size_px]} if self.describe_size else {}

    def settings(self) -> dict[str, Any]:
        return {"format": "PNG", "shutter_s": self.shutter_s}

    def set_setting(self, name: str, value: Any) -> None:
        """``shutter_s`` is kept (it takes no time); ``format`` is PNG; ``time_scale`` changes nothing;
        any other name is refused (the camera contract: a setting is never dropped unsaid)."""
        if name == "shutter_s":
            seconds = setting_number(name, value, "0 … 3600 s")
            if not 0 <= seconds <= 3600:
                raise InputError("shutter_s", f"{value} s is out of range", "0 … 3600 s")
            self.shutter_s = seconds
        elif name == "format":
            if str(value).upper() != "PNG":
                raise InputError("format", f"{value!r} is not available on the instant camera", "PNG")
        elif name != "time_scale":
            raise InputError(name, "unknown setting of the instant camera", "shutter_s, format")

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        if not self._connected:
            raise DeviceError("instant camera: not connected")
        x, y = self.position_mm()
        if self.render is not None:
            img = cv2.cvtColor(np.ascontiguousarray(self.render(x, y)), cv2.COLOR_RGB2BGR)
        else:
            img = np.roll(self._base, (int(y) % self.size_px[1], int(x) % self.size_px[0]), axis=(0, 1))
        if on_exposed is not None:
            on_exposed()
        path = Path(f"{stem_path}.png")
        def write(tmp: Path) -> None:
            if not cv2.imwrite(str(tmp), img):     # e.g. a full disk: never a short file under the view's name
                raise OSError(f"{path}: the image could not be written")
        atomic_write_with(path, write)
        self.captures += 1
        return CaptureResult(files=(path,), metadata={"position_mm": (x, y)})

    def preview(self) -> np.ndarray | None:
        return self._base.copy()
