"""The camera interface every camera driver implements, and the types it returns.

Beyond :class:`Camera`, a driver may offer ``describe_settings() -> list[CameraSetting]`` (what the
camera offers, so a GUI builds its controls from data) and ``identity() -> dict`` (model, serial,
lens as the camera reports them; the dataset records it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import inspect
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

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
