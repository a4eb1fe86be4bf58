"""The simulated camera: photographs the virtual studio from wherever the (simulated) rig is.

It *asks* for the camera position when the shutter opens (``position_mm()``; in the simulated
studio that is the GRBL simulator's true position, so positioning errors end up in the images) and
writes a real RAW file: ``STEM.dng`` (14-bit RGGB Bayer, see :mod:`lfstudio.sim.dng`), a small
``STEM.jpg`` preview and ``STEM.truth.json`` (true position, R, principal point, gain). Exposure,
transfer and trigger delays are simulated (``time_scale`` = 0 makes them instant for tests).

Exposure: the image brightness scales with ``shutter_s * iso / 100 / (aperture / 16)^2`` relative to
the reference exposure (0.5 s, ISO 100, f/16), so the live view's clipping warning means something.

Faults (:meth:`SimulatedCamera.inject`): ``"capture_fails"`` (the capture raises a DeviceError),
``"silent"`` (the camera stops answering: capture and preview hang until :meth:`stop`,
:meth:`disconnect` or ``silent_hang_s``).
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_json, atomic_write_with
from lfstudio.errors import DeviceError, InputError
from lfstudio.numbers import EXPOSURE_S, TIME_SCALE, TRANSFER_S
from lfstudio.rig.camera import CameraStatus, CaptureResult
from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, write_dng
from lfstudio.sim.sensor import SensorModel
from lfstudio.sim.studio import VirtualStudio, demo_studio_kwargs

log = logging.getLogger(__name__)

BLACK_LEVEL = 512
WHITE_LEVEL = 16383
REFERENCE_EXPOSURE = {"shutter_s": 0.5, "iso": 100, "aperture": 16.0}
ISO_VALUES = (50, 100, 200, 400, 800, 1600, 3200, 6400)
FAULTS = ("capture_fails", "silent")


def srgb8(linear_rgb: np.ndarray) -> np.ndarray:
    """Linear RGB float (1 = white) -> sRGB-encoded uint8, for previews."""
    x = np.clip(linear_rgb, 0.0, 1.0)
    out = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(out * 255.0).astype(np.uint8)


class SimulatedCamera:
    """A :class:`lfstudio.rig.camera.Camera` that renders :class:`VirtualStudio` views.

    ``studio``: the scene (built on :meth:`connect` from ``studio_kwargs`` when None: the demo
    scene with :data:`DEMO_ROTATION_DEG` / :data:`DEMO_PP_OFFSET_PX`). ``position_mm``: called at
    each shot for the camera position (default: always (0, 0)). ``faults``: injected at start,
    ``{"capture_fails": 2, "silent": None}`` (count; None = until cleared) or a list of names (once each).
    """

    name = "Simulated camera"
    suffix = ".dng"

    def __init__(self, studio: VirtualStudio | None = None,
                 position_mm: Callable[[], tuple[float, float]] | None = None, *,
                 exposure_s: float = 0.5, transfer_s: float = 1.0, trigger_s: float = 0.05,
                 time_scale: float = 1.0, iso: int = 100, aperture: float = 16.0,
                 noise: float = 0.002, flicker: float = 0.0, vignetting: float = 0.0, seed: int = 0,
                 preview_width_px: int = 640, silent_hang_s: float = 600.0,
                 studio_kwargs: dict[str, Any] | None = None,
                 faults: dict[str, int | None] | Any = None):
        self.studio = studio
        self.studio_kwargs = dict(studio_kwargs or demo_studio_kwargs())
        self.position_mm: Callable[[], tuple[float, float]] = position_mm or (lambda: (0.0, 0.0))
        self.exposure_s = EXPOSURE_S.check("exposure_s", exposure_s)
        self.transfer_s = TRANSFER_S.check("transfer_s", transfer_s)
        self.trigger_s = TRANSFER_S.check("trigger_s", trigger_s)
        self.time_scale = TIME_SCALE.check("time_scale", time_scale)
        self.iso = int(iso)
        self.aperture = float(aperture)
        self.sensor = SensorModel(flicker=flicker, vignetting=vignetting, noise=noise, seed=seed)
        self.preview_width_px = int(preview_width_px)
        self.silent_hang_s = float(silent_hang_s)
        self.shots = 0
        self.status_listener: Callable[[Any], None] | None = None
        self._connected = False
        self._busy = False
        self._message = ""
        self._faults: dict[str, int | None] = {}
        self._lock = threading.Lock()
        self._abort = threading.Event()
        if faults:
            items = faults.items() if isinstance(faults, dict) else ((name, 1) for name in faults)
            for fault, count in items:
                self.inject(fault, count)

    # -- connection ---------------------------------------------------------------------------------
    def connect(self) -> None:
        if self.studio is None:
            self.studio = VirtualStudio(**self.studio_kwargs)   # ~2 s at 2000 px: on the device thread
        self._abort.clear()
        self._connected = True
        self._message = ""

    def disconnect(self) -> None:
        self._connected = False
        self._abort.set()

    def set_view_region(self, view_region_mm: tuple[float, float, float, float]) -> None:
        """Centre the virtual scene on the grid a scan will visit (``(x_min, x_max, y_min, y_max)``
        mm); rebuilds the scene (same seed and camera) only when the region changes."""
        region = tuple(float(v) for v in view_region_mm)
        if self.studio is not None and tuple(self.studio.view_region_mm) == region:
            return
        kwargs = self.studio.init_kwargs() if self.studio is not None else dict(self.studio_kwargs)
        kwargs["view_region_mm"] = region
        self.studio_kwargs = kwargs
        if self.studio is not None:
            self.studio = VirtualStudio(**kwargs)

    def stop(self) -> None:
        """Abort a hanging or waiting capture now (called from another thread by STOP)."""
        self._abort.set()

    @property
    def connected(self) -> bool:
        return self._connected

    def status(self) -> CameraStatus:
        model = "lfstudio Virtual Studio" if self.studio is None else \
            f"lfstudio Virtual Studio ({self.studio.width_px} x {self.studio.height_px})"
        return CameraStatus(self._connected, model, self.shots, self._busy, self._message)

    # -- settings -----------------------------------------------------------------------------------
    def settings(self) -> dict[str, Any]:
        return {"iso": self.iso, "shutter_s": self.exposure_s, "aperture": self.aperture, "format": "DNG",
                "transfer_s": self.transfer_s, "noise": self.sensor.noise, "flicker": self.sensor.flicker,
                "vignetting": self.sensor.vignetting, "time_scale": self.time_scale}

    def set_setting(self, name: str, value: Any) -> None:
        if name == "iso":
            if int(value) not in ISO_VALUES:
                raise InputError("iso", f"{value} is not available", ", ".join(map(str, ISO_VALUES)))
            self.iso = int(value)
        elif name == "shutter_s":
            if not 1e-4 <= float(value) <= 60:
                raise InputError("shutter_s", f"{value} s is out of range", "0.0001 .. 60 s")
            self.exposure_s = float(value)
        elif name == "aperture":
            if not 1.0 <= float(value) <= 32:
                raise InputError("aperture", f"f/{value} is out of range", "f/1 .. f/32")
            self.aperture = float(value)
        elif name == "format":
            if str(value).upper() != "DNG":
                raise InputError("format", f"{value!r} is not available on the simulated camera", "DNG")
        elif name == "transfer_s":
            if not 0 <= float(value) <= 60:
                raise InputError("transfer_s", f"{value} s is out of range", "0 .. 60 s")
            self.transfer_s = float(value)
        elif name == "time_scale":
            if float(value) < 0:
                raise InputError("time_scale", "must not be negative", ">= 0 (0: no simulated delays)")
            self.time_scale = float(value)
        elif name in ("noise", "flicker", "vignetting"):
            if not 0 <= float(value) <= 1:
                raise InputError(name, f"{value} is out of range", "0 .. 1")
            s = self.sensor
            self.sensor = SensorModel(**{**{"flicker": s.flicker, "vignetting": s.vignetting, "noise": s.noise,
                                            "full_well_e": s.full_well_e, "seed": s.seed}, name: float(value)})
        else:
            raise InputError(name, "unknown setting of the simulated camera",
                             "iso, shutter_s, aperture, format, transfer_s, time_scale, noise, flicker, vignetting")

    def exposure_factor(self) -> float:
        """Brightness relative to the reference exposure (0.5 s, ISO 100, f/16)."""
        ref = REFERENCE_EXPOSURE
        return (self.exposure_s / ref["shutter_s"]) * (self.iso / ref["iso"]) * (ref["aperture"] / self.aperture) ** 2

    # -- faults -------------------------------------------------------------------------------------
    def inject(self, fault: str, count: int | None = 1) -> None:
        """Make the next ``count`` captures (None: all until :meth:`clear_faults`) misbehave."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; choose one of {', '.join(FAULTS)}")
        with self._lock:
            self._faults[fault] = count

    def clear_faults(self) -> None:
        with self._lock:
            self._faults.clear()

    def _take_fault(self, fault: str) -> bool:
        with self._lock:
            if fault not in self._faults:
                return False
            left = self._faults[fault]
            if left is not None:
                if left <= 1:
                    del self._faults[fault]
                else:
                    self._faults[fault] = left - 1
            return True

    # -- capture ------------------------------------------------------------------------------------
    def _wait_until(self, t_start: float, sim_seconds: float) -> None:
        """Wait until ``sim_seconds`` of simulated time have passed since ``t_start`` (monotonic);
        work done meanwhile (rendering, writing) counts. Raises DeviceError if stopped."""
        if self.time_scale <= 0 or sim_seconds <= 0:
            return
        remaining = t_start + sim_seconds * self.time_scale - time.monotonic()
        if remaining > 0 and self._abort.wait(remaining):
            raise DeviceError(f"{self.name}: stopped")

    def _report(self) -> None:
        """Hand a fresh status to the device worker (if one listens) during a long call."""
        listener = self.status_listener
        if listener is not None:
            listener(self.status())

    def _check_ready(self) -> VirtualStudio:
        if not self._connected or self.studio is None:
            raise DeviceError(f"{self.name}: not connected; connect the camera first (Camera panel: Connect)")
        if self._take_fault("silent"):
            self._message = "the camera does not answer"
            self._report()
            if self._abort.wait(self.silent_hang_s):
                raise DeviceError(f"{self.name}: stopped while the camera did not answer")
            raise DeviceError(f"{self.name}: the camera does not answer; check its cable and power, "
                              "then reconnect")
        return self.studio

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Render the view at the current position and write STEM.dng, STEM.jpg, STEM.truth.json."""
        stem_path = Path(stem_path)
        t_call = time.monotonic()
        if self._connected:
            self._abort.clear()
        studio = self._check_ready()
        self._busy = True
        try:
            if self._take_fault("capture_fails"):
                self._message = "capture failed"
                raise DeviceError(f"{self.name}: capture failed (the camera reported an error); "
                                  "retry the shot; if it persists, reconnect the camera")
            self._wait_until(t_call, self.trigger_s)
            t_open = time.monotonic()
            x_mm, y_mm = (float(v) for v in self.position_mm())
            shot = self.shots
            self.shots += 1
            rgb = studio.render(x_mm, y_mm)
            rgb *= np.float32(self.exposure_factor())
            recorded, gain = self.sensor.apply(rgb, shot)
            self._wait_until(t_open, self.exposure_s)
            t_closed = time.monotonic()
            if on_exposed is not None:
                on_exposed()
            raw_path = stem_path.with_name(stem_path.name + self.suffix)
            jpg_path = stem_path.with_name(stem_path.name + ".jpg")
            truth_path = stem_path.with_name(stem_path.name + ".truth.json")
            mosaic = mosaic_from_rgb(recorded, BLACK_LEVEL, WHITE_LEVEL, DEFAULT_NEUTRAL)
            write_dng(raw_path, mosaic, black_level=BLACK_LEVEL, white_level=WHITE_LEVEL,
                      as_shot_neutral=DEFAULT_NEUTRAL, exposure_s=self.exposure_s, f_number=self.aperture,
                      iso=self.iso)
            self._write_preview_jpeg(jpg_path, recorded)
            truth = {"shot": shot, "true_position_mm": [x_mm, y_mm], "gain": gain,
                     "exposure_factor": self.exposure_factor(),
                     "rotation_deg": list(studio.rotation_deg), "R": studio.R.tolist(),
                     "pp_offset_px": list(studio.pp_offset_px), "K_true": studio.K_true.tolist(),
                     "K0": studio.K0.tolist(), "H": studio.H.tolist(), "focal_length_px": studio.f_px,
                     "image_size_px": [studio.width_px, studio.height_px]}
            atomic_write_json(truth_path, truth)
            self._wait_until(t_closed, self.transfer_s)
            t_done = time.monotonic()
            size = raw_path.stat().st_size
            if size < mosaic.nbytes:
                raise DeviceError(f"{raw_path}: incomplete file ({size} bytes); retry the shot")
            self._message = ""
            log.debug("simulated camera: captured %s", raw_path.name)
            return CaptureResult(files=(raw_path, jpg_path, truth_path), trigger_s=t_open - t_call,
                                 exposure_s=t_closed - t_open, transfer_s=t_done - t_closed,
                                 metadata={"iso": self.iso, "shutter_s": self.exposure_s,
                                           "aperture": self.aperture, "format": "DNG", "bytes": size,
                                           "model": "lfstudio Virtual Studio", "ground_truth": truth})
        finally:
            self._busy = False

    def _write_preview_jpeg(self, path: Path, recorded: np.ndarray) -> None:
        h, w = recorded.shape[:2]
        pw = min(w, self.preview_width_px)
        small = cv2.resize(recorded, (pw, max(1, int(round(h * pw / w)))), interpolation=cv2.INTER_AREA)
        bgr = cv2.cvtColor(srgb8(small), cv2.COLOR_RGB2BGR)

        def _write(tmp: Path) -> None:
            if not cv2.imwrite(str(tmp), bgr, [cv2.IMWRITE_JPEG_QUALITY, 88]):
                raise DeviceError(f"{path}: cannot write the JPEG preview")

        atomic_write_with(path, _write)

    def preview(self) -> np.ndarray | None:
        """A live-view frame (sRGB uint8, about ``preview_width_px`` wide) at the current position."""
        studio = self._check_ready()
        x_mm, y_mm = (float(v) for v in self.position_mm())
        scale = min(1.0, 2.0 * self.preview_width_px / studio.width_px)
        rgb = studio.render(x_mm, y_mm, scale=scale)
        rgb *= np.float32(self.exposure_factor())
        recorded, _ = self.sensor.apply(rgb, self.shots + 1_000_000)
        h, w = recorded.shape[:2]
        pw = min(w, self.preview_width_px)
        if pw < w:
            recorded = cv2.resize(recorded, (pw, max(1, int(round(h * pw / w)))), interpolation=cv2.INTER_AREA)
        return srgb8(recorded)
