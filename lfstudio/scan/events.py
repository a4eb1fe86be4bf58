"""What the scan engine tells its listeners (CLI progress bar, GUI panel and grid, logs).

One plain, immutable event type keeps the Qt bridge trivial: ``kind`` says what happened and the
other fields are filled where they apply. Listeners run on the engine's threads: they must be quick
and must not call back into the engine synchronously (post to a queue or a Qt signal instead).
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field
from typing import Any


class ScanState(str, enum.Enum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSING = "pausing"       # pause requested: finishing the current view
    PAUSED = "paused"         # by the operator or by a fault (see ``ScanEngine.fault``)
    STOPPING = "stopping"     # abort requested: finishing the current view, then stop
    FINISHED = "finished"     # every queued view handled, or aborted (the message says which)
    FAILED = "failed"         # an unexpected error; the dataset stays valid and resumable


class EventKind(str, enum.Enum):
    STATE = "state"               # state changed (``state``, ``message``)
    VIEW_STARTED = "view-started"  # moving to a view
    VIEW_EXPOSED = "view-exposed"  # shutter closed; the rig may move on, the file is transferring
    VIEW_DONE = "view-done"       # file on disk, checksummed, thumbnail written, journalled
    VIEW_FAILED = "view-failed"   # one attempt failed (``will_retry`` says whether it is retried)
    VIEW_SKIPPED = "view-skipped"
    FAULT = "fault"               # device or disk fault: the scan pauses (``message`` says what to do)
    LOG = "log"                   # anything else worth a line in the log


@dataclass(frozen=True)
class ScanEvent:
    kind: EventKind
    message: str = ""
    state: ScanState | None = None
    index: int | None = None              # position in the scan order of this run (0-based)
    row: int | None = None
    column: int | None = None
    done: int = 0                         # views finished in this dataset (all runs)
    total: int = 0                        # views in this dataset
    eta_s: float | None = None
    timings_s: dict[str, float] = field(default_factory=dict)   # move, settle, expose, transfer, store, period
    file: str | None = None               # relative to the dataset folder
    thumb: str | None = None
    will_retry: bool = False
    time: float = field(default_factory=time.time)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def cell(self) -> tuple[int, int] | None:
        return None if self.row is None else (self.row, int(self.column or 0))

    def describe(self) -> str:
        """A one-line, human-readable description (logs, the GUI event list)."""
        where = f"view r{self.row:02d} c{self.column:03d}" if self.row is not None else ""
        if self.kind is EventKind.STATE:
            return f"{self.state.value if self.state else ''}: {self.message}".rstrip(": ")
        if self.kind is EventKind.VIEW_DONE:
            period = self.timings_s.get("period")
            return f"{where} done ({self.done}/{self.total})" + (f", {period:.2f} s per view" if period else "")
        if self.kind is EventKind.VIEW_STARTED:
            return f"{where} moving"
        if self.kind is EventKind.VIEW_EXPOSED:
            return f"{where} exposed"
        return f"{where}: {self.message}" if where else self.message
