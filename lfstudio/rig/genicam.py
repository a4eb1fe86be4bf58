"""Machine-vision cameras speaking GenICam (GigE Vision, USB3 Vision) through aravis.

Device word ``genicam:ID``: ID is what aravis lists for the camera (``arv-tool-0.8`` prints
``MODEL-SERIAL (ADDRESS)``; the id, the serial or the IP address all open it).

Contract:

- An array camera (:class:`lfstudio.rig.camera.ArrayCamera`): :meth:`GenicamCamera.grab` returns each
  picture as a :class:`lfstudio.dataset.frames.Frame` (pixels, pixel format, the camera's timestamp
  and frame id, this computer's arrival time, the exposure time and gain); the scan's store stage
  writes it (Bayer formats as DNG, mono and RGB as 16-bit PNG). :meth:`capture` is ``grab`` for a
  view (see :class:`lfstudio.rig.camera.FrameGrabber`).
- Settings are the camera's own GenICam nodes under our names (:data:`SETTINGS`): ``exposure_s``
  (ExposureTime, µs on the camera), ``gain``, ``pixel_format``, the region (``offset_x``,
  ``offset_y``, ``width``, ``height``), ``frame_rate`` and the trigger (``trigger_mode``,
  ``trigger_source``, ``trigger_activation``); :meth:`describe_settings` gives their current values,
  bounds and the choices the camera offers as data. A pixel format lfstudio cannot store (packed,
  YUV, ...) is refused with the ones it can.
- Trigger: with ``trigger_mode`` On and source ``Software`` a capture fires the software trigger;
  with another source (``Line0``, ...) a capture arms and waits for the next frame the line
  triggers (the rig's controller pulses it); with ``trigger_mode`` Off the next frame the free-running
  camera sends is taken. Connecting sets software trigger when the camera has it.
- A frame that arrives incomplete (lost packets aravis could not get resent, a wrong size) or not at
  all is never returned as good: the capture is taken again (software trigger) up to ``retries``
  times and the frame reports how many were lost (``Frame.lost``; the view's ``camera_frame.lost_before``);
  when every attempt fails the capture fails with what happened.
- Stale frames (sent before the capture was asked for) are dropped before each capture.

aravis is LGPL; Debian ships it (``gir1.2-aravis-0.8`` and ``python3-gi``; ``aravis-tools`` has the
fake GigE Vision camera the tests use). See the user guide, "Machine-vision cameras (GenICam)".
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lfstudio.dataset.frames import Frame
from lfstudio.errors import DeviceError, DeviceTimeout, InputError
from lfstudio.numbers import RETRIES, Number, described
from lfstudio.rig.camera import CameraSetting, CameraStatus, CaptureResult, frame_result

log = logging.getLogger(__name__)

INSTALL_HINT = ("install aravis: apt-get install gir1.2-aravis-0.8 python3-gi (then run tools/setup-env.sh "
                "again so the venv sees them), or pip install aravis-python pygobject; the user guide's 'Machine-vision cameras (GenICam)'")


def load_aravis() -> Any:
    """The aravis 0.8 module (GObject introspection), or DeviceError saying how to install it."""
    try:
        import importlib

        import gi

        gi.require_version("Aravis", "0.8")
        aravis = importlib.import_module("gi.repository.Aravis")    # made by gi's importer at run time
    except (ImportError, ValueError) as exc:
        raise DeviceError(f"genicam: aravis is not available ({exc}); {INSTALL_HINT}") from None
    return aravis


def aravis_version() -> tuple[bool, str]:
    """(usable, "aravis 0.8 (its typelib)") or (False, why not and how to install it)."""
    try:
        ar = load_aravis()
    except DeviceError as exc:
        return False, str(exc).removeprefix("genicam: ")
    try:                       # the 0.8 binding has no run-time version call: where its typelib is
        import gi

        where = gi.Repository.get_default().get_typelib_path("Aravis")
    except Exception:          # noqa: BLE001 - only for the text
        where = ""
    return True, f"aravis {getattr(ar, '_version', '0.8')}" + (f" ({where})" if where else "")


def aravis_available() -> bool:
    try:
        load_aravis()
    except DeviceError:
        return False
    return True


def list_cameras(aravis: Any = None) -> list[str]:
    """The ids of the cameras aravis finds now (GigE Vision on every interface, USB3 Vision)."""
    ar = aravis or load_aravis()
    ar.update_device_list()
    return [str(ar.get_device_id(i)) for i in range(ar.get_n_devices())]


@dataclass(frozen=True)
class GenicamOptions:
    """The connection options of ``genicam:ID`` (``--camera-option NAME=VALUE``, the Camera panel's form)."""

    timeout_s: float = described(5.0, number=Number("s", 0.01, 3600), label="Frame timeout",
                                 tip="how long a frame may take after its trigger (a hardware trigger: after the "
                                     "capture is armed) before the capture fails")
    retries: int = described(3, number=RETRIES, label="Retries of a lost frame",
                             tip="frames lost in a row (packets lost, incomplete) taken again before the capture fails")
    packet_size: int | None = described(None, number=Number("B", 576, 65536, integer=True), optional="auto",
                                        label="Packet size",
                                        tip="GigE Vision packet size in bytes; auto: the largest the link carries")
    buffers: int = described(4, number=Number("", 2, 64, integer=True), label="Frame buffers",
                             tip="frames the stream holds while the computer is busy")


@dataclass(frozen=True)
class PixelFormat:
    layout: str                 # "mono", "bayer", "rgb"
    bits: int
    dtype: Any                  # numpy sample type on the wire (unpacked, little-endian)
    pattern: str = ""           # Bayer
    bgr: bool = False           # samples in B G R order


def _formats() -> dict[str, PixelFormat]:
    table = {"Mono8": PixelFormat("mono", 8, np.uint8)}
    for bits in (10, 12, 14, 16):
        table[f"Mono{bits}"] = PixelFormat("mono", bits, np.dtype("<u2"))
    for cam, pattern in (("RG", "RGGB"), ("GR", "GRBG"), ("GB", "GBRG"), ("BG", "BGGR")):
        table[f"Bayer{cam}8"] = PixelFormat("bayer", 8, np.uint8, pattern)
        for bits in (10, 12, 16):
            table[f"Bayer{cam}{bits}"] = PixelFormat("bayer", bits, np.dtype("<u2"), pattern)
    for name in ("RGB8", "RGB8Packed"):
        table[name] = PixelFormat("rgb", 8, np.uint8)
    for name in ("BGR8", "BGR8Packed"):
        table[name] = PixelFormat("rgb", 8, np.uint8, bgr=True)
    table["RGB16"] = PixelFormat("rgb", 16, np.dtype("<u2"))
    return table


#: the pixel formats lfstudio stores (unpacked mono, Bayer and RGB); packed and YUV formats are refused
STORABLE: dict[str, PixelFormat] = _formats()


@dataclass(frozen=True)
class Node:
    """One of our settings on the camera: its GenICam feature names (tried in order) and type."""

    features: tuple[str, ...]
    type: str                   # "float", "int", "str"
    label: str
    unit: str = ""
    scale: float = 1.0          # camera value * scale = our value (ExposureTime µs -> s)


#: our setting names -> the GenICam features that hold them (SFNC names first, then older ones)
SETTINGS: dict[str, Node] = {
    "exposure_s": Node(("ExposureTime", "ExposureTimeAbs"), "float", "Exposure time", "s", 1e-6),
    "gain": Node(("Gain", "GainRaw"), "float", "Gain"),
    "pixel_format": Node(("PixelFormat",), "str", "Pixel format"),
    "offset_x": Node(("OffsetX",), "int", "Region left", "px"),
    "offset_y": Node(("OffsetY",), "int", "Region top", "px"),
    "width": Node(("Width",), "int", "Region width", "px"),
    "height": Node(("Height",), "int", "Region height", "px"),
    "frame_rate": Node(("AcquisitionFrameRate", "AcquisitionFrameRateAbs"), "float", "Frame rate", "Hz"),
    "trigger_mode": Node(("TriggerMode",), "str", "Trigger mode"),
    "trigger_source": Node(("TriggerSource",), "str", "Trigger source"),
    "trigger_activation": Node(("TriggerActivation",), "str", "Trigger activation"),
}
#: settings that change the frame's size: acquisition is stopped and the buffers made again
_PAYLOAD = ("pixel_format", "offset_x", "offset_y", "width", "height")


@dataclass(frozen=True)
class GenicamStatus(CameraStatus):
    lost: int = 0                # frames lost and taken again since connect


class GenicamCamera:
    """A GenICam camera through aravis (see the module docstring). ``device_id``: what aravis lists
    (id, serial or IP address); ``timeout_s``: how long a frame may take after its trigger (a hardware
    trigger: after the capture was asked for); ``retries``: frames lost before a capture fails;
    ``buffers``: frame buffers in the stream; ``packet_size``: GigE Vision packet size in bytes (None:
    the largest the link carries, as aravis finds it)."""

    def __init__(self, device_id: str, *, timeout_s: float = 5.0, retries: int = 3, buffers: int = 4,
                 packet_size: int | None = None, aravis: Any = None):
        if not str(device_id).strip():
            raise InputError("--camera", "genicam: names no camera", "genicam:ID, the id arv-tool-0.8 lists "
                             "(e.g. genicam:Aravis-Fake-GV01 or genicam:192.168.1.20)")
        self.device_id = str(device_id).strip()
        self.name = f"GenICam {self.device_id}"
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.buffers = max(2, int(buffers))
        self.packet_size = None if packet_size is None else int(packet_size)
        self._ar = aravis
        self._cam: Any = None
        self._stream: Any = None
        self._acquiring = False
        self._abort = threading.Event()
        self._features: dict[str, str] = {}
        self._identity: dict[str, Any] = {}
        self._snapshot: dict[str, Any] | None = None
        self._triggers: list[float] = []
        self._fetched = 0
        self._armed = 0
        self._line: str | None = None           # the input line a hardware trigger uses (see _line_source)
        self._line_mode = False
        self._clock: tuple[float, float] | None = None    # (offset s, uncertainty s): monotonic = camera + offset
        self.shots = 0
        self.lost = 0
        self._busy = False
        self._message = ""

    # -- connection --------------------------------------------------------------------------------
    @property
    def aravis(self) -> Any:
        if self._ar is None:
            self._ar = load_aravis()
        return self._ar

    def connect(self) -> None:
        ar = self.aravis
        if self._cam is not None:
            return
        try:
            # discovery first: opened by name without it, aravis may direct the camera's stream to another
            # interface's address than the one the camera answered on (seen with the fake camera on 127.0.0.1)
            _call(ar.update_device_list, None)
            cam = ar.Camera.new(self.device_id)
        except Exception as exc:       # GLib.Error: the id matches no camera, or it does not answer
            try:
                found = list_cameras(ar)
            except Exception:          # noqa: BLE001 - only for the message
                found = []
            seen = ", ".join(found) if found else "none"
            raise DeviceError(f"genicam:{self.device_id}: no camera answers ({_gerror(exc)}); cameras aravis "
                              f"finds now: {seen}") from None
        self._cam = cam
        self._snapshot = None
        dev = cam.get_device()
        self._features = {}
        for name, node in SETTINGS.items():
            for feature in node.features:
                if dev.get_feature(feature) is not None and _call(lambda f=feature, c=cam: c.is_feature_available(f), False):
                    self._features[name] = feature
                    break
        self._identity = {k: v for k, v in (
            ("model", _call(cam.get_model_name, "")), ("vendor", _call(cam.get_vendor_name, "")),
            ("serial", _call(cam.get_device_serial_number, "")), ("id", _call(cam.get_device_id, "")),
            ("firmware", _call(lambda c=cam: c.get_string("DeviceFirmwareVersion"), "")),
            ("transport", "GigE Vision" if _call(cam.is_gv_device, False) else
             "USB3 Vision" if _call(cam.is_uv_device, False) else "")) if v}
        try:
            cam.set_acquisition_mode(ar.AcquisitionMode.CONTINUOUS)
            if _call(cam.is_gv_device, False):
                # the largest packet the link carries (jumbo frames): fewer packets, fewer to lose
                if self.packet_size:
                    cam.gv_set_packet_size(self.packet_size)
                else:
                    _call(cam.gv_auto_packet_size, None)
            prior = _call(lambda c=cam: str(c.get_string("TriggerSource")), "")
            if prior.startswith("Line"):
                self._line = prior              # the line the camera was set to trigger on: its hardware trigger
            if _call(cam.is_software_trigger_supported, False):
                cam.set_trigger("Software")
            self._check_format(self._read("pixel_format"))
        except Exception as exc:
            # an exception's frames keep their locals alive: the camera object (and with it the
            # camera's control channel, which a second connection then cannot take) must not be one
            cam = dev = None
            self._close()
            if isinstance(exc, DeviceError):
                raise
            raise DeviceError(f"genicam:{self.device_id}: setting up the camera failed: {_gerror(exc)}") from None
        cam = dev = None
        self._message = ""

    def disconnect(self) -> None:
        self._abort.set()
        self._close()

    def _close(self) -> None:
        self._stop_acquisition()
        self._stream = None
        self._cam = None

    def stop(self) -> None:
        """Cut a capture that waits for its frame short (from another thread)."""
        self._abort.set()

    def _need(self) -> Any:
        if self._cam is None:
            raise DeviceError(f"genicam:{self.device_id}: not connected; connect the camera first")
        return self._cam

    def identity(self) -> dict[str, Any]:
        self._need()
        return dict(self._identity)

    def status(self) -> GenicamStatus:
        return GenicamStatus(self._cam is not None, self._identity.get("model", ""), self.shots, self._busy,
                             self._message, self.lost)

    # -- acquisition -------------------------------------------------------------------------------
    def _start_acquisition(self) -> None:
        if self._acquiring:
            return
        self._need()
        ar = self.aravis
        try:
            self._stream = self._need().create_stream(None, None)
            if self._stream is None:
                raise DeviceError(f"genicam:{self.device_id}: the camera opened no stream")
            size = self._need().get_payload()
            for _ in range(self.buffers):
                self._stream.push_buffer(ar.Buffer.new_allocate(size))
            self._need().start_acquisition()
        except DeviceError:
            self._stream = None
            raise
        except Exception as exc:
            self._stream = None
            raise DeviceError(f"genicam:{self.device_id}: starting the acquisition failed: {_gerror(exc)}") from None
        self._acquiring = True

    def _stop_acquisition(self) -> None:
        if not self._acquiring:
            return
        self._acquiring = False
        try:
            if self._cam is not None:
                self._cam.stop_acquisition()
        except Exception as exc:   # noqa: BLE001 - stopping a camera that went away
            log.debug("genicam: stopping the acquisition: %s", exc)
        self._stream = None

    # -- settings ----------------------------------------------------------------------------------
    def _read(self, name: str) -> Any:
        self._need()
        node = SETTINGS[name]
        feature = self._features.get(name)
        if feature is None:
            return None
        try:
            if node.type == "float":
                return float(self._need().get_float(feature)) * node.scale if feature != "GainRaw" else \
                    float(self._need().get_integer(feature))
            if node.type == "int":
                return int(self._need().get_integer(feature))
            return str(self._need().get_string(feature))
        except Exception as exc:
            raise DeviceError(f"genicam:{self.device_id}: reading {feature} failed: {_gerror(exc)}") from None

    def settings(self) -> dict[str, Any]:
        self._need()
        return {name: self._read(name) for name in SETTINGS if name in self._features}

    def _choices(self, feature: str) -> tuple[str, ...]:
        try:
            return tuple(str(c) for c in self._need().dup_available_enumerations_as_strings(feature) or ())
        except Exception:          # noqa: BLE001 - no choices known
            return ()

    def _bounds(self, name: str, feature: str) -> tuple[float, float, float] | None:
        self._need()
        node = SETTINGS[name]
        try:
            if node.type == "float" and feature != "GainRaw":
                low, high = self._need().get_float_bounds(feature)
                return (low * node.scale, high * node.scale, 0.0)
            low, high = self._need().get_integer_bounds(feature)
            step = self._need().get_integer_increment(feature) if node.type == "int" else 1
            return (float(low), float(high), float(step))
        except Exception:          # noqa: BLE001 - no bounds known
            return None

    def describe_settings(self) -> list[CameraSetting]:
        """The settings this camera has, with their bounds and choices (pixel formats: those it offers
        that lfstudio can store)."""
        out = []
        for name, node in SETTINGS.items():
            feature = self._features.get(name)
            if feature is None:
                continue
            value = self._read(name)
            if node.type == "str":
                choices = self._choices(feature)
                if name == "pixel_format":
                    choices = tuple(c for c in choices if c in STORABLE)
                out.append(CameraSetting(name, node.label, "str", value, choices, choices, unit=node.unit))
            else:
                out.append(CameraSetting(name, node.label, node.type, value, range=self._bounds(name, feature),
                                         unit=node.unit))
        return out

    def _check_format(self, name: Any) -> PixelFormat:
        fmt = STORABLE.get(str(name))
        if fmt is None:
            feature = self._features.get("pixel_format")
            offered = [c for c in self._choices(feature) if c in STORABLE] if feature else []
            raise InputError("pixel_format", f"genicam:{self.device_id}: pixel format {name!r} cannot be stored by "
                             "lfstudio (packed and YUV formats are not)",
                             ", ".join(offered) if offered else "an unpacked Mono, Bayer or RGB format")
        return fmt

    def set_setting(self, name: str, value: Any) -> None:
        self._need()
        node = SETTINGS.get(name)
        feature = self._features.get(name)
        if node is None or feature is None:
            raise InputError(name, f"genicam:{self.device_id} has no setting {name!r}",
                             ", ".join(n for n in SETTINGS if n in self._features))
        if node.type == "str":
            value = str(value)
            choices = self._choices(feature)
            if choices and value not in choices:
                if name == "pixel_format":
                    self._check_format(value)
                raise InputError(name, f"{value!r} is not one of the camera's choices", ", ".join(choices))
            if name == "pixel_format":
                self._check_format(value)
        else:
            try:
                number = float(value)
            except (TypeError, ValueError):
                raise InputError(name, f"{value!r} is not a number", node.unit or "a number") from None
            bounds = self._bounds(name, feature)
            if bounds is not None and not bounds[0] <= number <= bounds[1]:
                raise InputError(name, f"{value!r}{' ' + node.unit if node.unit else ''} is out of the camera's "
                                 f"range", f"{bounds[0]:g} … {bounds[1]:g}{' ' + node.unit if node.unit else ''}")
            if node.type == "int" and number != int(number):
                raise InputError(name, f"{value!r} is not a whole number", "a whole number of pixels")
            value = number
        self._snapshot = None
        if name == "trigger_source" and str(value).startswith("Line"):
            self._line = str(value)             # the operator's line: the fly scan's hardware trigger uses it
        restart = name in _PAYLOAD and self._acquiring
        if restart:
            self._stop_acquisition()
        try:
            if node.type == "str":
                self._need().set_string(feature, value)
            elif node.type == "int" or feature == "GainRaw":
                self._need().set_integer(feature, int(value))
            else:
                self._need().set_float(feature, float(value) / node.scale)
        except Exception as exc:
            raise DeviceError(f"genicam:{self.device_id}: setting {feature} to {value!r} failed: {_gerror(exc)}") \
                from None

    # -- capture -----------------------------------------------------------------------------------
    def _shot_settings(self) -> dict[str, Any]:
        """The settings each frame records, read from the camera once and again only after a
        set_setting (a frame costs no register reads; each is a network round trip)."""
        if self._snapshot is None:
            self._snapshot = self.settings()
        return dict(self._snapshot)

    def _trigger(self, settings: dict[str, Any] | None = None) -> str:
        """"software", "line" (wait for the hardware trigger) or "free" (free-running)."""
        settings = self._shot_settings() if settings is None else settings
        if str(settings.get("trigger_mode", "Off")) != "On":
            return "free"
        return "software" if str(settings.get("trigger_source")) == "Software" else "line"

    def _drain(self) -> None:
        """Give back frames that arrived before this capture (free-running or line-triggered)."""
        while self._stream is not None:
            buf = self._stream.try_pop_buffer()
            if buf is None:
                return
            self._stream.push_buffer(buf)

    def _pop(self, deadline: float) -> Any:
        """The next buffer, or None at ``deadline``; DeviceError when stopped."""
        while True:
            if self._abort.is_set():
                raise DeviceError(f"genicam:{self.device_id}: stopped while waiting for the frame")
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            buf = self._stream.timeout_pop_buffer(int(min(left, 0.1) * 1e6))
            if buf is not None:
                return buf

    def grab(self, on_exposed: Callable[[], None] | None = None) -> Frame:
        """Take one frame (see the module docstring: trigger, retries of lost frames)."""
        self._need()
        ar = self.aravis
        self._abort.clear()
        self._busy = True
        try:
            settings = self._shot_settings()
            fmt = self._check_format(settings.get("pixel_format"))
            self._start_acquisition()
            trigger = self._trigger(settings)
            exposure_s = settings.get("exposure_s")
            wait_s = self.timeout_s + (exposure_s or 0.0)
            problems: list[str] = []
            for attempt in range(self.retries + 1):
                self._drain()
                if trigger == "software":
                    try:
                        self._need().software_trigger()
                    except Exception as exc:
                        raise DeviceError(f"genicam:{self.device_id}: the software trigger failed: "
                                          f"{_gerror(exc)}") from None
                buf = self._pop(time.monotonic() + wait_s)
                if buf is None:
                    if trigger == "line":
                        raise DeviceTimeout(f"genicam:{self.device_id}: no frame within {wait_s:g} s of arming: "
                                            f"is the trigger line ({settings.get('trigger_source')}) wired and "
                                            "pulsed?")
                    problems.append("no frame arrived")
                    self.lost += 1
                    continue
                try:
                    status = buf.get_status()
                    if status != ar.BufferStatus.SUCCESS:
                        problems.append(_status_text(status))
                        self.lost += 1
                        log.info("genicam:%s: frame %s lost (%s), taking it again", self.device_id,
                                 buf.get_frame_id(), problems[-1])
                        continue
                    frame = self._frame(buf, fmt, settings, exposure_s, lost=attempt)
                finally:
                    if self._stream is not None:
                        self._stream.push_buffer(buf)
                if on_exposed is not None:
                    on_exposed()
                self.shots += 1
                self._message = ""
                return frame
            raise DeviceError(f"genicam:{self.device_id}: {self.retries + 1} frames in a row lost "
                              f"({', '.join(problems)}); check the network link (jumbo frames, packet delay, "
                              "a direct cable)")
        except DeviceError as exc:
            self._message = str(exc)
            raise
        finally:
            self._busy = False

    def _frame(self, buf: Any, fmt: PixelFormat, settings: dict[str, Any], exposure_s: float | None,
               lost: int) -> Frame:
        width, height = int(buf.get_image_width()), int(buf.get_image_height())
        data = buf.get_image_data() if hasattr(buf, "get_image_data") else buf.get_data()
        channels = 3 if fmt.layout == "rgb" else 1
        dtype = np.dtype(fmt.dtype)
        need = width * height * channels * dtype.itemsize
        if len(data) < need:
            raise DeviceError(f"genicam:{self.device_id}: frame of {len(data)} bytes for {width} x {height} "
                              f"{settings.get('pixel_format')} ({need} expected)")
        pixels = np.frombuffer(data, dtype=dtype, count=width * height * channels)
        pixels = pixels.reshape((height, width, 3) if channels == 3 else (height, width))
        if fmt.bgr:
            pixels = pixels[:, :, ::-1]
        pixels = np.ascontiguousarray(pixels, dtype=np.uint8 if dtype.itemsize == 1 else np.uint16)
        stamp = int(buf.get_timestamp() or 0) or None
        system = int(buf.get_system_timestamp() or 0) or time.time_ns()
        return Frame(pixels, fmt.layout, fmt.bits, fmt.pattern, str(settings.get("pixel_format") or ""),
                     exposure_s=exposure_s, timestamp_ns=stamp, system_timestamp_ns=system,
                     frame_id=int(buf.get_frame_id()), lost=lost, settings=settings, identity=dict(self._identity))

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Grab a frame for the view ``stem_path``: returned unwritten, the store stage writes it."""
        t0 = time.monotonic()
        frame = self.grab(on_exposed)
        return frame_result(frame, stem_path, trigger_s=time.monotonic() - t0)

    # -- triggered frames (fly scanning: lfstudio.rig.camera.TriggeredCamera) --------------------------
    #: from trigger() to the exposure's start: a software trigger's GVCP write (the fake camera starts at
    #: its next frame period, up to 1/frame_rate later)
    trigger_latency_s = 0.0

    def arm(self, frames: int) -> None:
        """Software trigger on, the acquisition running, stale frames dropped; ``frames`` expected."""
        self._line_mode = False
        if self._trigger() != "software":
            self.set_setting("trigger_mode", "On")
            self.set_setting("trigger_source", "Software")
        self._start_acquisition()
        self._drain()
        self._triggers = []
        self._fetched = 0
        self._armed = int(frames)

    def trigger(self) -> float:
        """Fire the software trigger now (from any thread; aravis serialises the camera's control
        channel) and return when it was sent (time.monotonic)."""
        sent = time.monotonic()
        try:
            self._need().software_trigger()
        except DeviceError:
            raise
        except Exception as exc:
            raise DeviceError(f"genicam:{self.device_id}: the software trigger failed: {_gerror(exc)}") from None
        self._triggers.append(sent)
        return sent

    def fetch(self, stem_path: Path, timeout_s: float) -> CaptureResult:
        """The next triggered frame, in trigger order (unwritten: the store stage writes it); DeviceError
        for a trigger whose frame did not arrive whole (it cannot be taken again: the rig moved on)."""
        self._need()
        if self._stream is None:
            raise DeviceError(f"genicam:{self.device_id}: not armed; arm the camera first")
        settings = self._shot_settings()
        fmt = self._check_format(settings.get("pixel_format"))
        index = self._fetched
        self._fetched += 1
        sent = self._triggers[index] if index < len(self._triggers) else None
        buf = self._pop(time.monotonic() + float(timeout_s))
        if buf is None:
            self.lost += 1
            if self._line_mode:
                raise DeviceError(f"genicam:{self.device_id}: no frame {index + 1} within {timeout_s:g} s: no rising "
                                  f"edge on {settings.get('trigger_source')} took one (missed)")
            raise DeviceError(f"genicam:{self.device_id}: triggered frame {index + 1} did not arrive within "
                              f"{timeout_s:g} s (missed)")
        try:
            if buf.get_status() != self.aravis.BufferStatus.SUCCESS:
                self.lost += 1
                raise DeviceError(f"genicam:{self.device_id}: triggered frame {index + 1} lost "
                                  f"({_status_text(buf.get_status())})")
            frame = self._frame(buf, fmt, settings, settings.get("exposure_s"), lost=0)
        finally:
            if self._stream is not None:
                self._stream.push_buffer(buf)
        self.shots += 1
        result = frame_result(frame, stem_path)
        if self._line_mode and self._clock is not None and frame.timestamp_ns:
            # the camera's timestamp of the frame (SFNC: the exposure's start on most cameras) on this
            # computer's clock, through the offset latched at arm_line
            start = frame.timestamp_ns * 1e-9 + self._clock[0]
            result.metadata.update(exposure_start_s=start, exposure_end_s=start + float(frame.exposure_s or 0.0),
                                   clock_uncertainty_s=self._clock[1])
        elif sent is not None:
            start = sent + self.trigger_latency_s
            result.metadata.update(exposure_start_s=start, exposure_end_s=start + float(frame.exposure_s or 0.0))
        return result

    def disarm(self) -> None:
        self._stop_acquisition()
        self._triggers = []
        self._fetched = 0
        self._armed = 0
        self._line_mode = False

    # -- hardware trigger (fly scanning: lfstudio.rig.camera.LineTriggered) ---------------------------
    #: from the line's edge to the exposure's start: the camera's TriggerDelay where it has one (read by
    #: arm_line); the camera's own input latency (opto-coupler, a few µs) is not known to lfstudio
    line_trigger_latency_s = 0.0
    #: how the camera's clock is read now: (latch command, latched value, its tick frequency or None for ns)
    CLOCK_LATCHES = (("TimestampLatch", "TimestampLatchValue", None),
                     ("GevTimestampControlLatch", "GevTimestampValue", "GevTimestampTickFrequency"))

    def _available(self, feature: str) -> bool:
        cam = self._cam
        return cam is not None and cam.get_device().get_feature(feature) is not None and \
            bool(_call(lambda: cam.is_feature_available(feature), False))

    def _line_source(self) -> tuple[str | None, str]:
        """(the TriggerSource line a hardware trigger uses, "") or (None, why the camera has none). The line is
        the one the operator set as Trigger source (or the camera had when connected), else its first."""
        if self._cam is None:
            return None, "the camera is not connected"
        if "trigger_mode" not in self._features or "trigger_source" not in self._features:
            return None, "it has no TriggerMode and TriggerSource nodes"
        choices = self._choices(self._features["trigger_source"])
        lines = [c for c in choices if c.startswith("Line")]
        if not lines:
            return None, f"its TriggerSource offers no input line ({', '.join(choices) or 'no choices'})"
        activation = self._features.get("trigger_activation")
        edges = self._choices(activation) if activation is not None else ()
        if edges and "RisingEdge" not in edges:
            return None, f"its TriggerActivation has no RisingEdge ({', '.join(edges)})"
        return (self._line if self._line in lines else lines[0]), ""

    def _clock_latch(self) -> tuple[str, str, str | None] | None:
        return next((latch for latch in self.CLOCK_LATCHES if self._available(latch[0]) and self._available(latch[1])),
                    None)

    def line_trigger_problem(self) -> str | None:
        """Why this camera cannot take a fly scan's frames on its trigger line, None when it can: it needs a
        line among its trigger sources (rising edge) and a clock lfstudio can read (a timestamp latch), so
        that each frame's exposure is dated on this computer's clock and checked against the rig's reports."""
        line, why = self._line_source()
        if line is None:
            return f"genicam:{self.device_id}: {why}"
        if self._clock_latch() is None:
            return (f"genicam:{self.device_id}: its frames cannot be dated on this computer's clock (it has no "
                    "timestamp latch: TimestampLatch/TimestampLatchValue or GevTimestampControlLatch/"
                    "GevTimestampValue), so a frame its line took could not be checked against the rig's "
                    "position reports")
        return None

    def _read_clock(self) -> tuple[float, float] | None:
        """(offset, uncertainty) in s with monotonic = camera timestamp + offset: the camera's clock latched
        between two readings of this computer's (uncertainty: half their distance); None without a latch."""
        latch = self._clock_latch()
        cam = self._need()
        if latch is None:
            return None
        command, value, frequency = latch
        try:
            ticks_per_s = float(cam.get_integer(frequency)) if frequency is not None else 1e9
            t0 = time.monotonic()
            cam.execute_command(command)
            t1 = time.monotonic()
            ticks = float(cam.get_integer(value))
        except Exception as exc:
            raise DeviceError(f"genicam:{self.device_id}: reading its clock ({command}) failed: {_gerror(exc)}") from None
        if ticks_per_s <= 0:
            return None
        return 0.5 * (t0 + t1) - ticks / ticks_per_s, 0.5 * (t1 - t0)

    def arm_line(self, frames: int) -> None:
        """Ready for ``frames`` frames, each on a rising edge of the trigger line: TriggerMode On,
        TriggerSource the line (see :meth:`_line_source`), TriggerActivation RisingEdge, the acquisition
        running, stale frames dropped, the camera's clock read (each frame's exposure then comes dated on
        this computer's clock). :meth:`fetch` waits for each frame; :meth:`disarm` ends it."""
        line, why = self._line_source()
        if line is None:
            raise DeviceError(f"genicam:{self.device_id}: no hardware trigger: {why}")
        self.set_setting("trigger_mode", "On")
        self.set_setting("trigger_source", line)
        if "trigger_activation" in self._features:
            self.set_setting("trigger_activation", "RisingEdge")
        delay = _call(lambda: float(self._need().get_float("TriggerDelay")), 0.0) if self._available("TriggerDelay") else 0.0
        self.line_trigger_latency_s = max(0.0, delay) * 1e-6          # SFNC: µs
        self._start_acquisition()
        self._drain()
        self._abort.clear()
        self._clock = self._read_clock()
        self._triggers = []
        self._fetched = 0
        self._armed = int(frames)
        self._line_mode = True

    def preview(self) -> np.ndarray | None:
        """A frame as 8-bit RGB for the live view (None while a hardware trigger decides when frames come)."""
        if self._cam is None or (self._trigger() == "line"):
            return None
        return preview_rgb8(self.grab())


def preview_rgb8(frame: Frame) -> np.ndarray:
    """An 8-bit H x W x 3 RGB picture of ``frame`` (Bayer demosaiced by OpenCV)."""
    import cv2

    px = frame.pixels
    if px.dtype != np.uint8:
        px = (px >> max(0, frame.bits - 8)).clip(0, 255).astype(np.uint8)
    if frame.layout == "mono":
        return np.dstack([px, px, px])
    if frame.layout == "bayer":
        # OpenCV names Bayer codes by the second row's first two colours
        code = {"RGGB": cv2.COLOR_BayerBG2RGB, "GRBG": cv2.COLOR_BayerGB2RGB, "GBRG": cv2.COLOR_BayerGR2RGB,
                "BGGR": cv2.COLOR_BayerRG2RGB}[frame.pattern]
        return cv2.cvtColor(px, code)
    return np.ascontiguousarray(px)


def _status_text(status: Any) -> str:
    name = getattr(status, "value_nick", None) or str(status)
    return {"missing-packets": "packets lost", "size-mismatch": "wrong size", "timeout": "timed out",
            "wrong-packet-id": "wrong packet id", "aborted": "aborted"}.get(str(name), str(name))


def _gerror(exc: BaseException) -> str:
    return str(getattr(exc, "message", "") or exc).strip() or type(exc).__name__


def _call(fn: Callable[[], Any], default: Any) -> Any:
    try:
        return fn()
    except Exception:   # noqa: BLE001 - an optional feature the camera lacks
        return default
