"""One application state shared by all panels; panels react to its signals."""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import QObject, Signal


class AppState(QObject):
    """What the whole window shares: the current plan, the open dataset, the devices.

    Panels read attributes and connect to the signals; they never call each other.
    """

    planChanged = Signal(object)        # the current scene plan (lfstudio.planning) or None
    datasetChanged = Signal(object)     # the open lfstudio.dataset.Dataset or None
    statusMessage = Signal(str, int)    # text, timeout in ms (0: until replaced)
    errorOccurred = Signal(str, str)    # title, message an operator understands
    scanEvent = Signal(object)          # lfstudio.scan.events.ScanEvent from the running scan (GUI thread)
    recaptureRequested = Signal(object)  # list of (row, column) to capture again (grid view → scan panel)
    devicesChanged = Signal(str)        # a device ("rig", "camera", ...) was connected or removed
    cameraFrame = Signal(object, str)   # an RGB uint8 image from the camera (test shot) and its caption

    def __init__(self, simulated: bool = True, parent: QObject | None = None):
        super().__init__(parent)
        self.simulated = simulated
        self.plan: Any = None
        self.dataset: Any = None
        self.devices: dict[str, Any] = {}   # "rig", "camera": Qt device adapters, when connected

    def set_plan(self, plan: Any) -> None:
        self.plan = plan
        self.planChanged.emit(plan)

    def set_dataset(self, dataset: Any) -> None:
        self.dataset = dataset
        self.datasetChanged.emit(dataset)

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
