"""Detect GUI-thread stalls: a timer that should fire every ``interval_ms`` measures its lateness."""

from __future__ import annotations

import logging
import time

from PySide6.QtCore import QObject, QTimer

log = logging.getLogger(__name__)


class Heartbeat(QObject):
    """Records the longest gap between timer ticks beyond the interval (``max_stall_ms``)."""

    def __init__(self, interval_ms: int = 10, warn_ms: float = 50.0, parent: QObject | None = None):
        super().__init__(parent)
        self.interval_ms = interval_ms
        self.warn_ms = warn_ms
        self.max_stall_ms = 0.0
        self.stalls: list[float] = []
        self._last = None
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self._tick)

    def start(self) -> None:
        self._last = time.perf_counter()
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()

    def _tick(self) -> None:
        now = time.perf_counter()
        stall_ms = (now - self._last) * 1000.0 - self.interval_ms
        self._last = now
        if stall_ms > self.max_stall_ms:
            self.max_stall_ms = stall_ms
        if stall_ms > self.warn_ms:
            self.stalls.append(stall_ms)
            log.warning("GUI thread stalled for %.0f ms", stall_ms)
