"""The camera interface every camera driver implements, and the types it returns.

Beyond :class:`Camera`, a driver may offer capabilities, each a named interface checked with
``isinstance`` (never ``hasattr``): :class:`DescribesSettings` (what the camera offers, so a GUI
builds its controls from data), :class:`HasIdentity` (model, serial, lens as the camera reports
them; the dataset records it), :class:`HasStatus`, :class:`Stoppable` (a capture under way cut
short), :class:`HasCardSpace` (pictures kept on the camera's card), :class:`SimulatedScene`,
:class:`CardBuffered` (keeps pictures on its card, downloaded later), :class:`TriggeredCamera` (takes a frame on a trigger, in order, without waiting for the previous
frame's transfer: fly scanning).

An **array camera** (:class:`ArrayCamera`: machine-vision cameras) hands each picture back as pixels
with their metadata (:class:`lfstudio.dataset.frames.Frame`) instead of writing a file: its
``capture`` returns a :class:`CaptureResult` with ``frame`` set and no files, and the scan's store
stage (or :func:`stored` for a test shot) writes it. A plugin that only has ``grab()`` is made a
camera by :class:`FrameGrabber`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import inspect
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from lfstudio.dataset.frames import Frame
from lfstudio.dataset.manifest import ViewUpdate


@dataclass(frozen=True)
class CameraStatus:
    """A snapshot of a camera for the GUI (what the device worker publishes)."""

    connected: bool
    model: str = ""
    shots: int = 0
    busy: bool = False
    message: str = ""          # last error an operator understands, "" when fine


@dataclass(frozen=True)
class CaptureResult:
    """Files a capture produced (already on disk at their final names) and how long each step took."""

    files: tuple[Path, ...]          # the main file first (RAW), then sidecars (JPEG preview, ...)
    trigger_s: float = 0.0           # from the call to the shutter opening
    exposure_s: float = 0.0
    transfer_s: float = 0.0          # download / write of the files
    metadata: dict[str, Any] = field(default_factory=dict)   # ISO, shutter, ground truth (simulated), ...
    #: extra fields for this view's manifest entry (JSON-safe), e.g. the camera's identity and the
    #: exposure settings it reported for this shot; the scan engine merges them into the view record
    record: ViewUpdate = field(default_factory=lambda: ViewUpdate())
    #: an array camera's picture, not yet written (``files`` is empty): :func:`stored` writes it to ``stem``
    frame: Frame | None = None
    stem: Path | None = None

    @property
    def path(self) -> Path:
        return self.files[0]


@dataclass(frozen=True)
class CameraSetting:
    """One setting a camera offers, as data a GUI builds its control from (cf. python-microscope's
    ``describe_settings``). ``set_setting(name, v)`` accepts one of ``values`` (matched by value,
    e.g. 0.01 finds "1/100") or one of the camera's own ``choices`` texts."""

    name: str                         # the key of settings() and set_setting(): "shutter_s", "aperture", ...
    label: str                        # what the camera calls it, e.g. "Shutter Speed"
    type: str                         # "float", "int" or "str": the type of ``value`` and ``values``
    value: Any                        # current value in our units (the camera's text where it has none, "Auto")
    choices: tuple[str, ...] = ()     # the camera's texts for the values it offers, in its order
    values: tuple[Any, ...] = ()      # each choice in our units (its text where it has no number: "Bulb")
    range: tuple[float, float, float] | None = None   # (min, max, step) of a continuous setting
    read_only: bool = False
    unit: str = ""                    # "s", "EV", "" (ISO, f-number)


@runtime_checkable
class Camera(Protocol):
    """Blocking camera driver; run it through :class:`lfstudio.rig.worker.DeviceWorker`."""

    name: str

    def connect(self) -> None: ...
    def disconnect(self) -> None: ...
    def settings(self) -> dict[str, Any]:
        """Current settings, e.g. {"iso": 100, "shutter_s": 0.5, "aperture": 16, "format": "RAW"}."""
        ...
    def set_setting(self, name: str, value: Any) -> None: ...
    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Take one picture and store it as ``stem_path`` + the driver's suffix (e.g. ``.dng``).

        The file is complete (size checked) and atomically in place when this returns.

        ``on_exposed`` (optional keyword): the driver calls it once, from the calling thread, as soon
        as the shutter has closed, before the download/transfer. The scan engine uses it to start
        the next move while the file is still transferring (pipelined scan). A driver that cannot
        tell may call it just before returning; drivers written before this keyword existed simply
        lack it and the engine waits for ``capture`` to return.
        """
        ...
    def preview(self) -> np.ndarray | None:
        """A live-view frame (H x W x 3 uint8) or None when the camera has none."""
        ...


def supports_on_exposed(camera: Any) -> bool:
    """True when ``camera.capture`` accepts the ``on_exposed`` keyword (pipelined transfer)."""
    try:
        params = inspect.signature(camera.capture).parameters
    except (TypeError, ValueError):
        return False
    return "on_exposed" in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


# -- capabilities (checked with isinstance) ----------------------------------------------------------
@runtime_checkable
class DescribesSettings(Protocol):
    def describe_settings(self) -> list[CameraSetting]: ...


@runtime_checkable
class HasIdentity(Protocol):
    def identity(self) -> dict[str, Any]: ...


@runtime_checkable
class HasStatus(Protocol):
    def status(self) -> Any: ...


@runtime_checkable
class HasName(Protocol):
    """A driver that tells what it is called ("Simulated camera", "Ramp camera (example plugin)")."""

    name: str


def name_of(camera: Any, default: str) -> str:
    """The camera's own name (:class:`HasName`), else ``default``."""
    return str(camera.name) if isinstance(camera, HasName) else default


def setting_number(name: str, value: Any, valid: str) -> float:
    """The value of the camera setting ``name`` as a finite number (``--set shutter_s=abc``, a text field):
    :class:`~lfstudio.errors.InputError` naming the setting and ``valid`` otherwise, never a ValueError."""
    import math

    from lfstudio.errors import InputError

    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise InputError(name, f"{value!r} is not a number", valid)
    return number


@runtime_checkable
class Stoppable(Protocol):
    def stop(self) -> None: ...


@runtime_checkable
class HasCardSpace(Protocol):
    def card_space(self) -> Any: ...


@runtime_checkable
class Paced(Protocol):
    """A simulated camera whose delays are scaled (``time_scale``: 1 real time, 0 none)."""

    time_scale: float


@runtime_checkable
class SimulatedScene(Protocol):
    def set_view_region(self, view_region_mm: tuple[float, ...]) -> None: ...


@runtime_checkable
class TriggeredCamera(Protocol):
    """A camera that takes frames on triggers (fly scanning; cf. GenICam ``TriggerMode=On``).

    ``arm(frames)`` readies it for that many triggered frames (acquisition started, trigger mode on);
    ``trigger()`` fires a software trigger and returns at once with the ``time.monotonic()`` it was
    sent: it is called from the scan engine's thread, never queued behind a transfer, so it must be
    safe while ``fetch`` runs on the device worker. ``fetch(stem, timeout_s)`` returns the next
    triggered frame in trigger order (written to ``stem`` + suffix, or as an array camera's frame),
    its ``metadata`` giving ``exposure_start_s``/``exposure_end_s`` (``time.monotonic()`` clock) when
    the camera knows them; it raises :class:`~lfstudio.errors.DeviceError` for a trigger that took
    no frame (missed). ``disarm()`` ends the acquisition and drops frames not fetched.
    ``trigger_latency_s`` is the nominal delay from ``trigger()`` to the exposure's start."""

    trigger_latency_s: float

    def arm(self, frames: int) -> None: ...
    def trigger(self) -> float: ...
    def fetch(self, stem_path: Path, timeout_s: float) -> CaptureResult: ...
    def disarm(self) -> None: ...


@runtime_checkable
class LineTriggered(Protocol):
    """A :class:`TriggeredCamera` that can take its triggers from a hardware line instead (GenICam
    ``TriggerSource=Line1``, rising edge), driven by the axis controller at the views' positions.
    ``line_trigger_problem()``: why it cannot (nothing wired, ...), None when it can;
    ``arm_line(frames)``: ready for that many frames, each on a rising edge of the line (``fetch`` and
    ``disarm`` as for software triggers; a frame's ``metadata`` has ``trigger_edge_s``, the edge's
    time, when the camera knows it); ``line_trigger_latency_s``: edge to exposure start."""

    line_trigger_latency_s: float

    def line_trigger_problem(self) -> str | None: ...
    def arm_line(self, frames: int) -> None: ...


@runtime_checkable
class CardBuffered(Protocol):
    """A camera that can keep its pictures on its card and download them later (``--keep-on-card``):
    ``keep_on_card()`` makes captures stay there (returns where: the capture target); ``capture_to_card``
    takes a picture and returns the paths of its files on the camera at once; ``download_from_card``
    fetches them to ``stem_path`` + suffix (sizes checked) and deletes them there, as ``capture`` would."""

    def keep_on_card(self) -> str: ...
    def capture_to_card(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> list[str]: ...
    def download_from_card(self, camera_files: list[str], stem_path: Path) -> CaptureResult: ...


@runtime_checkable
class ArrayCamera(Protocol):
    """A camera that hands back pixels: ``grab()`` takes one picture and returns it as a
    :class:`~lfstudio.dataset.frames.Frame` (calling ``on_exposed`` as soon as it is exposed)."""

    def connect(self) -> None: ...
    def disconnect(self) -> None: ...
    def settings(self) -> dict[str, Any]: ...
    def set_setting(self, name: str, value: Any) -> None: ...
    def grab(self, on_exposed: Callable[[], None] | None = None) -> Frame: ...


def frame_result(frame: Frame, stem_path: Path, *, trigger_s: float = 0.0, transfer_s: float = 0.0
                 ) -> CaptureResult:
    """The :class:`CaptureResult` of an array camera's ``frame`` for the view ``stem_path``: no file yet
    (the store stage writes it), the frame's settings, identity and timing as the view's record."""
    record = ViewUpdate(camera_frame=frame.record())
    if frame.settings:
        record["camera_settings"] = dict(frame.settings)
    if frame.identity:
        record["camera"] = dict(frame.identity)
    meta = dict(frame.settings)
    return CaptureResult(files=(), trigger_s=trigger_s, exposure_s=float(frame.exposure_s or 0.0),
                         transfer_s=transfer_s, metadata=meta, record=record, frame=frame, stem=Path(stem_path))


class FrameGrabber:
    """An :class:`ArrayCamera` as a :class:`Camera`: ``capture(stem)`` grabs a frame and returns it
    unwritten (:func:`frame_result`). Every other attribute is the array camera's own."""

    def __init__(self, camera: ArrayCamera):
        self.camera = camera
        self.name = str(getattr(camera, "name", type(camera).__name__))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.camera, name)

    def connect(self) -> None:
        self.camera.connect()

    def disconnect(self) -> None:
        self.camera.disconnect()

    def settings(self) -> dict[str, Any]:
        return self.camera.settings()

    def set_setting(self, name: str, value: Any) -> None:
        self.camera.set_setting(name, value)

    def preview(self) -> np.ndarray | None:
        preview = getattr(self.camera, "preview", None)
        frame = preview() if callable(preview) else None
        return frame if isinstance(frame, np.ndarray) else None

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        import time

        t0 = time.monotonic()
        frame = self.camera.grab(on_exposed)
        return frame_result(frame, stem_path, trigger_s=time.monotonic() - t0)


def stored(result: CaptureResult) -> CaptureResult:
    """``result`` with its files on disk: an array camera's frame written to its stem (Bayer as DNG,
    mono and RGB as 16-bit PNG; :func:`lfstudio.dataset.frames.write_frame`); a file camera's result
    as it is."""
    if result.frame is None:
        return result
    from dataclasses import replace

    from lfstudio.dataset.frames import preview_rgb, write_frame

    if result.stem is None:
        raise ValueError("an array camera's capture result names no stem to write its frame to")
    identity = result.frame.identity
    path = write_frame(result.frame, result.stem, model=str(identity.get("model", "")),
                       make=str(identity.get("vendor", "")))
    # the thumbnail is made from the pixels in hand, not by decoding the file just written
    metadata = {**result.metadata, "preview": preview_rgb(result.frame)}
    return replace(result, files=(path,), frame=None, metadata=metadata)
