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
import math
import queue
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_json, atomic_write_with
from lfstudio.errors import DeviceError, InputError
from lfstudio.numbers import EXPOSURE_S, TIME_SCALE, TRANSFER_S
from lfstudio.rig.camera import CameraSetting, CameraStatus, CaptureResult, setting_number
from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, write_dng
from lfstudio.sim.sensor import SensorModel
from lfstudio.sim.studio import VirtualStudio, demo_studio_kwargs

log = logging.getLogger(__name__)

BLACK_LEVEL = 512
WHITE_LEVEL = 16383
REFERENCE_EXPOSURE = {"shutter_s": 0.5, "iso": 100, "aperture": 16.0}
ISO_VALUES = (50, 100, 200, 400, 800, 1600, 3200, 6400)
#: the shutter times the simulated camera takes (s), as a real body's range
SHUTTER_RANGE_S = (1e-4, 60.0)
FAULTS = ("capture_fails", "silent", "miss_trigger", "late_trigger", "unplugged")


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
                 faults: dict[str, int | None] | Any = None,
                 trigger_latency_s: float = 0.0005, trigger_jitter_s: float = 0.0002,
                 frame_rate_fps: float = 20.0):
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
        #: fly scanning (TriggeredCamera): nominal delay from trigger() to the exposure, its jitter (σ)
        self.trigger_latency_s = float(trigger_latency_s)
        self.trigger_jitter_s = float(trigger_jitter_s)
        self.frame_rate_fps = float(frame_rate_fps)      # triggered frames a second it sustains
        self._rng = np.random.default_rng(seed + 7919)
        self._triggers: "queue.Queue[tuple[float, float, bool] | None]" = queue.Queue()
        self._exposed: "deque[dict[str, Any]]" = deque()
        self._exposed_cond = threading.Condition()
        self._shutter: threading.Thread | None = None
        self._armed = False
        #: the exposure output (a GenICam camera's ExposureActive line): called with True at each triggered
        #: frame's exposure start and False at its end (monotonic time); wired to the emulated drives' touch probe
        self.exposure_output: Callable[[bool, float], Any] | None = None
        #: hardware trigger (LineTriggered): the line wired to the trigger input (None: the GRBL
        #: simulator's spindle output when the position comes from it), edge to exposure start
        self.trigger_line: Any = None
        self.line_trigger_latency_s = 2e-5
        self._line_mode = False
        self._line_after = 0.0
        self._line_index = 0
        self._line_last_open = -math.inf
        #: pictures the simulated card holds (None: no limit); a full card refuses the next capture
        self.card_capacity: int | None = None
        if faults:
            items = faults.items() if isinstance(faults, dict) else ((name, 1) for name in faults)
            for fault, count in items:
                self.inject(fault, count)

    # -- connection ---------------------------------------------------------------------------------
    def connect(self) -> None:
        if "unplugged" in self._faults:
            raise DeviceError(f"{self.name}: no camera answers on USB (is its cable plugged in?)")
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
                "vignetting": self.sensor.vignetting, "time_scale": self.time_scale,
                "frame_rate_fps": self.frame_rate_fps}

    def describe_settings(self) -> list[CameraSetting]:
        """The shutter time the simulated camera takes, as data (a continuous range): a scan checks a
        bracket's frames against it before the rig moves."""
        return [CameraSetting("shutter_s", "Shutter time", "float", self.exposure_s,
                              range=(SHUTTER_RANGE_S[0], SHUTTER_RANGE_S[1], 0.0), unit="s")]

    def set_setting(self, name: str, value: Any) -> None:
        if name == "iso":
            iso = setting_number(name, value, ", ".join(map(str, ISO_VALUES)))
            if iso not in ISO_VALUES:
                raise InputError("iso", f"{value} is not available", ", ".join(map(str, ISO_VALUES)))
            self.iso = int(iso)
        elif name == "shutter_s":
            seconds = setting_number(name, value, f"{SHUTTER_RANGE_S[0]:g} .. {SHUTTER_RANGE_S[1]:g} s")
            if not SHUTTER_RANGE_S[0] <= seconds <= SHUTTER_RANGE_S[1]:
                raise InputError("shutter_s", f"{value} s is out of range",
                                 f"{SHUTTER_RANGE_S[0]:g} .. {SHUTTER_RANGE_S[1]:g} s")
            self.exposure_s = seconds
        elif name == "aperture":
            if not 1.0 <= setting_number(name, value, "f/1 .. f/32") <= 32:
                raise InputError("aperture", f"f/{value} is out of range", "f/1 .. f/32")
            self.aperture = float(value)
        elif name == "format":
            if str(value).upper() != "DNG":
                raise InputError("format", f"{value!r} is not available on the simulated camera", "DNG")
        elif name == "transfer_s":
            if not 0 <= setting_number(name, value, "0 .. 60 s") <= 60:
                raise InputError("transfer_s", f"{value} s is out of range", "0 .. 60 s")
            self.transfer_s = float(value)
        elif name == "time_scale":
            if setting_number(name, value, ">= 0 (0: no simulated delays)") < 0:
                raise InputError("time_scale", "must not be negative", ">= 0 (0: no simulated delays)")
            self.time_scale = float(value)
        elif name == "frame_rate_fps":
            if not 0 < setting_number(name, value, "> 0 … 10000 frames/s") <= 10_000:
                raise InputError("frame_rate_fps", f"{value} frames/s is out of range", "> 0 … 10000 frames/s")
            self.frame_rate_fps = float(value)
        elif name in ("noise", "flicker", "vignetting"):
            if not 0 <= setting_number(name, value, "0 .. 1") <= 1:
                raise InputError(name, f"{value} is out of range", "0 .. 1")
            s = self.sensor
            self.sensor = SensorModel(**{**{"flicker": s.flicker, "vignetting": s.vignetting, "noise": s.noise,
                                            "full_well_e": s.full_well_e, "seed": s.seed}, name: float(value)})
        else:
            raise InputError(name, "unknown setting of the simulated camera",
                             "iso, shutter_s, aperture, format, transfer_s, time_scale, noise, flicker, vignetting, "
                             "frame_rate_fps")

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
        if "unplugged" in self._faults:          # a pulled cable: nothing answers until it is back
            raise DeviceError(f"{self.name}: the camera stopped answering (its USB cable was pulled?)")
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

    def _expose(self, studio: VirtualStudio, t_call: float) -> tuple[float, int, float, float, np.ndarray, float]:
        """Trigger (``trigger_s`` after ``t_call``), render the view at the current position and
        expose it (``exposure_s``): the shutter-open time, shot number, position, recorded frame, gain."""
        self._wait_until(t_call, self.trigger_s)
        t_open = time.monotonic()
        x_mm, y_mm = (float(v) for v in self.position_mm())
        shot = self.shots
        self.shots += 1
        rgb = studio.render(x_mm, y_mm)
        rgb *= np.float32(self.exposure_factor())
        recorded, gain = self.sensor.apply(rgb, shot)
        self._wait_until(t_open, self.exposure_s)
        return t_open, shot, x_mm, y_mm, recorded, gain

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
            t_open, shot, x_mm, y_mm, recorded, gain = self._expose(studio, t_call)
            t_closed = time.monotonic()
            if on_exposed is not None:
                on_exposed()
            truth = self._truth(studio, shot, x_mm, y_mm, gain)
            raw_path, jpg_path, truth_path, mosaic = self._write_files(stem_path, recorded, truth)
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

    # -- the card as the buffer (lfstudio.rig.camera.CardBuffered) -----------------------------------
    def keep_on_card(self) -> str:
        """Pictures stay on the simulated card (this process's memory: a killed process loses it, a
        real card would not) until :meth:`download_from_card`."""
        self._card: dict[str, tuple[np.ndarray, dict[str, Any]]] = getattr(self, "_card", {})
        return "the simulated card"

    def capture_to_card(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> list[str]:
        """Trigger, expose and keep the picture on the card (no transfer); its path on the card."""
        card = getattr(self, "_card", None)
        if card is None:
            card = self._card = {}
        t_call = time.monotonic()
        if self._connected:
            self._abort.clear()
        studio = self._check_ready()
        if self._take_fault("capture_fails"):
            raise DeviceError(f"{self.name}: capture failed (the camera reported an error); retry the shot")
        if self.card_capacity is not None and len(card) >= self.card_capacity:
            raise DeviceError(f"{self.name}: the camera's card is full ({len(card)} pictures): free space on the "
                              "card (download or delete pictures), then retry")
        t_open, shot, x_mm, y_mm, recorded, gain = self._expose(studio, t_call)
        if on_exposed is not None:
            on_exposed()
        name = f"/card/DCIM/100SIM/SIM_{shot:05d}.DNG"
        card[name] = (recorded, self._truth(studio, shot, x_mm, y_mm, gain))
        return [name]

    def download_from_card(self, camera_files: list[str], stem_path: Path) -> CaptureResult:
        """Write the picture kept on the card as :meth:`capture` would, taking ``transfer_s``; gone from the card."""
        card = getattr(self, "_card", {})
        t0 = time.monotonic()
        self._check_ready()
        name = str(camera_files[0]) if camera_files else ""
        if name not in card:
            raise DeviceError(f"{self.name}: {name or 'the picture'} is not on the card (the camera restarted?)")
        recorded, truth = card[name]
        raw_path, jpg_path, truth_path, mosaic = self._write_files(Path(stem_path), recorded, truth)
        self._wait_until(t0, self.transfer_s)
        del card[name]
        size = raw_path.stat().st_size
        return CaptureResult(files=(raw_path, jpg_path, truth_path), exposure_s=self.exposure_s,
                             transfer_s=time.monotonic() - t0,
                             metadata={"iso": self.iso, "shutter_s": self.exposure_s, "aperture": self.aperture,
                                       "format": "DNG", "bytes": size, "model": "lfstudio Virtual Studio",
                                       "ground_truth": truth, "camera_files": [name]})

    # -- triggered frames (lfstudio.rig.camera.TriggeredCamera: fly scanning) ------------------------
    def arm(self, frames: int) -> None:
        """Ready for ``frames`` triggered frames: each trigger opens the shutter after
        ``trigger_latency_s`` ± ``trigger_jitter_s`` (σ) and the exposure is integrated along the motion."""
        self._check_ready()
        with self._exposed_cond:
            self._exposed.clear()
        if self._shutter is None or not self._shutter.is_alive():
            self._shutter = threading.Thread(target=self._shutter_loop, name="sim-camera-shutter", daemon=True)
            self._shutter.start()
        self._armed = True

    def disarm(self) -> None:
        self._armed = False
        self._line_mode = False
        with self._exposed_cond:
            self._exposed.clear()

    # -- hardware trigger (lfstudio.rig.camera.LineTriggered) ---------------------------------------
    def _line(self) -> Any:
        if self.trigger_line is not None:
            return self.trigger_line
        return getattr(getattr(self.position_mm, "__self__", None), "spindle_output", None)

    def line_trigger_problem(self) -> str | None:
        if self._line() is None:
            return "no trigger line is wired to the simulated camera's input (its rig is not the GRBL simulator)"
        if self.time_scale <= 0:
            return "the simulated camera's trigger line needs simulated time to pass (time scale > 0)"
        return None

    def arm_line(self, frames: int) -> None:
        """Ready for ``frames`` frames, each on a rising edge of the trigger line (GenICam
        ``TriggerSource=Line1``): the shutter opens :attr:`line_trigger_latency_s` after the edge. An
        edge that comes sooner than the frame rate allows after the last frame takes none (missed)."""
        self._check_ready()
        problem = self.line_trigger_problem()
        if problem is not None:
            raise DeviceError(f"{self.name}: {problem}")
        with self._exposed_cond:
            self._exposed.clear()
        self._abort.clear()                      # a STOP before this row ended its waits, not this row's
        self._line_after = time.monotonic()
        self._line_index = 0
        self._line_last_open = -math.inf
        self._line_mode = True
        self._armed = True

    def _line_frame(self, timeout_s: float) -> dict[str, Any]:
        line = self._line()
        edge = line.wait_rising(self._line_after, self._line_index, timeout_s, cancelled=self._abort.is_set)
        if edge is None:
            raise DeviceError(f"{self.name}: no edge on the trigger line within {timeout_s:g} s")
        self._line_index += 1
        if self._take_fault("miss_trigger"):   # an edge the camera never saw (a glitch on the line): silently
            edge = line.wait_rising(self._line_after, self._line_index, timeout_s, cancelled=self._abort.is_set)
            if edge is None:
                raise DeviceError(f"{self.name}: no edge on the trigger line within {timeout_s:g} s")
            self._line_index += 1
        scale = self.time_scale
        t0 = edge + self.line_trigger_latency_s * scale
        t1 = t0 + self.exposure_s * scale
        gap = t0 - self._line_last_open
        missed = self.frame_rate_fps > 0 and gap < 0.999 * scale / self.frame_rate_fps
        if not missed:
            self._line_last_open = t0
        while (left := t1 - time.monotonic()) > 0:
            time.sleep(left)
        at: Any = getattr(getattr(self.position_mm, "__self__", None), "true_position_at", None)
        q0: Any = at(t0) if callable(at) else None
        q1: Any = at(t1) if callable(at) else None
        if q0 is None or q1 is None:
            q0 = q1 = self.position_mm()
        return {"t_trigger": edge, "t_open": t0, "t_close": t1, "p0": (float(q0[0]), float(q0[1])),
                "p1": (float(q1[0]), float(q1[1])), "latency_s": self.line_trigger_latency_s, "missed": missed,
                "edge_s": edge, "why_missed": (f"the line's edge came {1000 * gap / scale:.1f} ms after the last "
                                               f"frame, sooner than {self.frame_rate_fps:g} frames/s allow")}

    def trigger(self) -> float:
        """A software trigger: returns at once with the time it was sent; the shutter opens after the
        latency (simulated time) on the camera's own thread."""
        t = time.monotonic()
        if not self._armed or not self._connected:
            raise DeviceError(f"{self.name}: triggered while not armed; the scan arms the camera before a row")
        latency = max(0.0, self.trigger_latency_s + float(self._rng.normal(0.0, self.trigger_jitter_s)))
        missed = self._take_fault("miss_trigger")
        if self._take_fault("late_trigger"):
            latency += 0.05                       # a trigger that waited 50 ms (a busy bus)
        self._triggers.put((t, latency, missed))
        return t

    def _shutter_loop(self) -> None:
        while True:
            item = self._triggers.get()
            if item is None:
                return
            t, latency, missed = item
            scale = self.time_scale
            if scale > 0:
                t_open = t + latency * scale
                delay = t_open - time.monotonic()
                if delay > 0.002:
                    time.sleep(delay - 0.002)
                while time.monotonic() < t_open:     # spun: a sleep may wake up ms late
                    pass
            t0 = time.monotonic()
            wire = self.exposure_output if not missed and scale > 0 else None
            self._output(wire, True, t0)
            p0 = self.position_mm()
            if scale > 0:
                time.sleep(self.exposure_s * scale)
            t1 = time.monotonic()
            self._output(wire, False, t0 + self.exposure_s * scale)
            p1 = self.position_mm()
            # the truth at the exposure's own start and end, where the controller keeps its history
            # (this thread may have run late between the clock and the question)
            at: Any = getattr(getattr(self.position_mm, "__self__", self.position_mm), "true_position_at", None)
            if callable(at) and scale > 0:
                t1 = t0 + self.exposure_s * scale
                q0: Any = at(t0)
                q1: Any = at(t1)
                if q0 is not None and q1 is not None:
                    p0, p1 = (float(q0[0]), float(q0[1])), (float(q1[0]), float(q1[1]))
            frame = {"t_trigger": t, "t_open": t0, "t_close": t1, "p0": (float(p0[0]), float(p0[1])),
                     "p1": (float(p1[0]), float(p1[1])), "latency_s": latency, "missed": missed}
            with self._exposed_cond:
                self._exposed.append(frame)
                self._exposed_cond.notify_all()

    @staticmethod
    def _output(wire: Callable[[bool, float], Any] | None, level: bool, t: float) -> None:
        """The exposure output goes to ``level`` at ``t``: what it is wired to sees the edge."""
        if wire is None:
            return
        try:
            wire(level, t)
        except Exception as exc:  # noqa: BLE001 - a cable to nothing does not stop the camera
            log.debug("exposure output: %s", exc)

    def render_exposure(self, p0: Any, blur_mm: Any, k: int) -> np.ndarray:
        """The light of one exposure before the sensor: ``k`` sub-frames at the centres of ``k`` equal
        parts of the path from ``p0`` along ``blur_mm`` (mm; one at its middle when ``k`` is 1),
        averaged, times the exposure factor. What :meth:`fetch` records (and a check makes again from
        a view's truth sidecar: benchmarks/fly_scan.py)."""
        studio = self.studio                    # no fault taken here: fetch() checked the camera
        if studio is None:
            raise DeviceError(f"{self.name}: not connected; connect the camera first (Camera panel: Connect)")
        p0, blur_mm = np.asarray(p0, dtype=float), np.asarray(blur_mm, dtype=float)
        rgb = None
        for i in range(k):
            pos = p0 + blur_mm * ((i + 0.5) / k if k > 1 else 0.5)
            one = studio.render(float(pos[0]), float(pos[1]))
            rgb = one if rgb is None else rgb + one
        assert rgb is not None
        rgb /= np.float32(k)
        rgb *= np.float32(self.exposure_factor())
        return rgb

    def fetch(self, stem_path: Path, timeout_s: float) -> CaptureResult:
        """The next triggered frame, rendered with its motion blur (renders along the exposure's
        path averaged) and written like :meth:`capture`'s; ``metadata`` has ``exposure_start_s``/
        ``exposure_end_s`` (monotonic clock) and the truth (``ground_truth``: true centre position,
        blur in px at the near distance)."""
        studio = self._check_ready()
        stem_path = Path(stem_path)
        deadline = time.monotonic() + timeout_s
        if self._line_mode:
            f = self._line_frame(timeout_s)
            if f["missed"]:
                raise DeviceError(f"{self.name}: {f['why_missed']} (missed trigger)")
        else:
            with self._exposed_cond:
                while not self._exposed:
                    left = deadline - time.monotonic()
                    if left <= 0 or self._abort.is_set():
                        raise DeviceError(f"{self.name}: no triggered frame arrived within {timeout_s:g} s")
                    self._exposed_cond.wait(min(left, 0.1))
                f = self._exposed.popleft()
        if f["missed"]:
            raise DeviceError(f"{self.name}: the trigger sent at {f['t_trigger']:.6f} took no frame (missed trigger)")
        scale = self.time_scale
        span_s = f["t_close"] - f["t_open"]
        p0, p1 = np.asarray(f["p0"]), np.asarray(f["p1"])
        # the carriage's travel during the (simulated) exposure: measured over the real interval, so
        # a late wake-up of this thread does not lengthen it
        blur_mm = (p1 - p0) * (self.exposure_s * scale / span_s) if scale > 0 and span_s > 0 else np.zeros(2)
        blur_px = float(studio.disparity_px(studio.near_m, float(np.hypot(blur_mm[0], blur_mm[1]))))
        # k sub-frames at the centres of k equal parts of the path: their spread is √(1 - 1/k²) of the box's,
        # and less again where the texture's pixels fall between them (2 made 0.5 px look like a 0.43 px box
        # on the picture, 5 like 0.47, 16 like 0.49: lfstudio.sim.motion_blur), so blur / (2k²) ≤ 0.0025 px
        k = 1 if blur_px < 1e-3 else min(16, max(2, int(math.ceil(math.sqrt(blur_px / 0.005)))))
        rgb = self.render_exposure(p0, blur_mm, k)
        shot = self.shots
        self.shots += 1
        recorded, gain = self.sensor.apply(rgb, shot)
        centre = p0 + blur_mm / 2
        truth = self._truth(studio, shot, float(centre[0]), float(centre[1]), gain)
        truth.update({"blur_mm": [float(v) for v in blur_mm], "blur_px_near": blur_px, "subframes": k,
                      "trigger_latency_s": f["latency_s"]})
        unseen: Any = getattr(getattr(self.position_mm, "__self__", None), "repeatability_error_at", None)
        if callable(unseen) and scale > 0:     # the controller's repeatability error, in the truth above
            err: Any = unseen(0.5 * (f["t_open"] + f["t_close"]))
            truth["repeatability_error_mm"] = [float(err[0]), float(err[1])]
        raw_path, jpg_path, truth_path, mosaic = self._write_files(stem_path, recorded, truth)
        size = raw_path.stat().st_size
        exposure_end = f["t_open"] + self.exposure_s * scale
        return CaptureResult(files=(raw_path, jpg_path, truth_path), trigger_s=f["t_open"] - f["t_trigger"],
                             exposure_s=self.exposure_s,
                             metadata={"iso": self.iso, "shutter_s": self.exposure_s, "aperture": self.aperture,
                                       "format": "DNG", "bytes": size, "model": "lfstudio Virtual Studio",
                                       "ground_truth": truth, "exposure_start_s": f["t_open"],
                                       "exposure_end_s": exposure_end,
                                       **({"trigger_edge_s": f["edge_s"]} if "edge_s" in f else {})})

    def _truth(self, studio: VirtualStudio, shot: int, x_mm: float, y_mm: float, gain: Any) -> dict[str, Any]:
        return {"shot": shot, "true_position_mm": [x_mm, y_mm], "gain": gain,
                "exposure_factor": self.exposure_factor(),
                "rotation_deg": list(studio.rotation_deg), "R": studio.R.tolist(),
                "pp_offset_px": list(studio.pp_offset_px), "K_true": studio.K_true.tolist(),
                "K0": studio.K0.tolist(), "H": studio.H.tolist(), "focal_length_px": studio.f_px,
                "image_size_px": [studio.width_px, studio.height_px]}

    def _write_files(self, stem_path: Path, recorded: np.ndarray, truth: dict[str, Any]
                     ) -> tuple[Path, Path, Path, np.ndarray]:
        """STEM.dng, STEM.jpg and STEM.truth.json of one shot."""
        raw_path = stem_path.with_name(stem_path.name + self.suffix)
        jpg_path = stem_path.with_name(stem_path.name + ".jpg")
        truth_path = stem_path.with_name(stem_path.name + ".truth.json")
        mosaic = mosaic_from_rgb(recorded, BLACK_LEVEL, WHITE_LEVEL, DEFAULT_NEUTRAL)
        write_dng(raw_path, mosaic, black_level=BLACK_LEVEL, white_level=WHITE_LEVEL,
                  as_shot_neutral=DEFAULT_NEUTRAL, exposure_s=self.exposure_s, f_number=self.aperture,
                  iso=self.iso)
        self._write_preview_jpeg(jpg_path, recorded)
        atomic_write_json(truth_path, truth)
        return raw_path, jpg_path, truth_path, mosaic

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
