"""One application state shared by all panels; panels react to its signals.

It also follows the running scan from its events: ``scan_state`` and ``scanStateChanged`` tell the
panels when the scan owns the rig and the camera (motion controls, test shots, live view and camera
settings locked, see :data:`lfstudio.scan.events.OWNS_RIG`) and when a scan is active (quitting asks
first).

Scan events reach listeners as lists, in order (``scanEvents``): the Scan panel publishes the events
of one drain together (:meth:`AppState.publish_scan_events`), so a fast scan costs each listener one
Python call per drain, not one per event. Listen to ``scanEvents``; ``scanEvent`` (one event) is for
publishing a single event and is forwarded as a list of one.
"""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import QObject, Signal

from lfstudio.gui.heartbeat import keep_out_of_gc
from lfstudio.scan.events import OWNS_RIG, TERMINAL, EventKind, ScanState


class AppState(QObject):
    """What the whole window shares: the current plan, the open dataset, the devices.

    Panels read attributes and connect to the signals; they never call each other.
    """

    planChanged = Signal(object)        # the current scene plan (lfstudio.planning) or None
    datasetChanged = Signal(object)     # the open lfstudio.dataset.Dataset or None
    statusMessage = Signal(str, int)    # text, timeout in ms (0: until replaced)
    errorOccurred = Signal(str, str)    # title, message an operator understands
    scanEvent = Signal(object)          # publish one lfstudio.scan.events.ScanEvent (forwarded to scanEvents)
    scanEvents = Signal(object)         # list of ScanEvents of the running scan, in order (GUI thread): listen here
    scanStateChanged = Signal(object)   # the scan's ScanState changed (see scan_owns_rig, scan_active)
    recaptureRequested = Signal(object)  # list of (row, column) to capture again (grid view → scan panel)
    devicesChanged = Signal(str)        # a device ("rig", "camera", ...) was connected or removed
    cameraFrame = Signal(object, str)   # an RGB uint8 image from the camera (test shot) and its caption
    liveVerdicts = Signal(object)       # list of the scan-time check's verdict entries (grid view → notifications)
    scanFolderChanged = Signal(str)     # the dataset folder the Scan panel will write to (the Planner's disk row)
    stopRequested = Signal()            # the window's STOP was pressed (after the rig's own stop was sent)

    def __init__(self, simulated: bool = True, parent: QObject | None = None):
        super().__init__(parent)
        self.simulated = simulated
        self.plan: Any = None
        self.dataset: Any = None
        self.devices: dict[str, Any] = {}   # "rig", "camera": Qt device adapters, when connected
        self.scan_state: ScanState | None = None   # of the latest scan, from its events
        self.scan_label = ""                 # "the scan of studio_day (started 14:02)"
        self.scan_progress = (0, 0)          # views done, views in the dataset
        self.scan_folder = ""                # the dataset folder the next scan writes to (set_scan_folder)
        self.scanEvents.connect(self._follow_scan_events)
        self.scanEvent.connect(lambda ev: self.scanEvents.emit([ev]))

    def set_plan(self, plan: Any) -> None:
        self.plan = plan
        self.planChanged.emit(plan)

    def set_scan_folder(self, folder: str) -> None:
        """The Scan panel's dataset folder, announced with ``scanFolderChanged`` when it changes."""
        if folder != self.scan_folder:
            self.scan_folder = folder
            self.scanFolderChanged.emit(folder)

    def set_dataset(self, dataset: Any) -> None:
        self.dataset = dataset
        self.datasetChanged.emit(dataset)
        keep_out_of_gc()          # its thousands of view records need no full collections (stalls)

    def set_device(self, name: str, device: Any) -> None:
        """Store (or with None remove) ``devices[name]`` and announce it with ``devicesChanged``."""
        if device is None:
            self.devices.pop(name, None)
        else:
            self.devices[name] = device
        self.devicesChanged.emit(name)

    def show_status(self, text: str, timeout_ms: int = 5000) -> None:
        self.statusMessage.emit(text, timeout_ms)

    def report_error(self, title: str, message: str) -> None:
        self.errorOccurred.emit(title, message)

    # -- the running scan --------------------------------------------------------------------------
    def publish_scan_events(self, events: list) -> None:
        """Hand scan events (in order) to every listener of ``scanEvents`` at once."""
        if events:
            self.scanEvents.emit(list(events))

    def _follow_scan_events(self, events: list) -> None:
        for ev in events:
            self._follow_scan(ev)

    def _follow_scan(self, ev: Any) -> None:
        if ev.total:
            self.scan_progress = (ev.done, ev.total)
        if ev.kind is not EventKind.STATE or ev.state is None:
            return
        self.scan_label = ev.extra.get("scan", self.scan_label)
        if ev.state is not self.scan_state:
            self.scan_state = ev.state
            self.scanStateChanged.emit(ev.state)

    @property
    def scan_owns_rig(self) -> bool:
        """True while the scan holds the rig: every motion command but STOP is refused."""
        return self.scan_state in OWNS_RIG

    @property
    def scan_active(self) -> bool:
        """True from the scan's start until it finished or failed (paused included)."""
        return self.scan_state is not None and self.scan_state not in TERMINAL

    @property
    def scan_owns_camera(self) -> bool:
        """True while the scan holds the camera (the same states as the rig): test shots, live view
        and setting changes are refused."""
        return self.scan_state in OWNS_RIG

    def camera_lock_reason(self) -> str:
        """Why the camera's controls are disabled now, for their tooltips ("" while they are not)."""
        if not self.scan_owns_camera:
            return ""
        return (f"Disabled while {self.scan_label or 'the scan'} runs: the scan owns the camera until it ends "
                "or is paused.")

    def motion_lock_reason(self) -> str:
        """Why motion controls are disabled now, for their tooltips ("" while they are not)."""
        if not self.scan_owns_rig:
            return ""
        return (f"Disabled while {self.scan_label or 'the scan'} runs: the scan owns the rig until it ends "
                "or is paused. STOP (Esc) is always available.")
