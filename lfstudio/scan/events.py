"""The scan engine's states, the one table of its transitions, and what it tells its listeners.

:data:`TRANSITIONS` is the whole state machine (as bluesky's RunEngine keeps it): for each
:class:`ScanState`, the :class:`Trigger` objects allowed there and the state each one leads to. The
operator's requests (:data:`REQUESTS`: start, pause, resume, abort, skip, recapture) and the engine's
own steps (a fault, the pause checkpoint reached, done, an unexpected error) both go through it; a
request that the table does not allow in the current state is refused with
:class:`ScanRequestRefused` (naming the state and the request), never half-applied.

One plain, immutable event type keeps the Qt bridge trivial: ``kind`` says what happened and the
other fields are filled where they apply. Listeners run on the engine's threads: they must be quick
and must not wait for the engine (a request returns at once; the engine thread applies it).
"""

from __future__ import annotations

import enum
import re
import time
from dataclasses import dataclass, field
from typing import Any

from lfstudio.dataset.paths import view_label
from lfstudio.errors import LfError


class ScanState(str, enum.Enum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSING = "pausing"       # pause requested: finishing the current view
    PAUSED = "paused"         # by the operator or by a fault (see ``ScanEngine.fault``)
    STOPPING = "stopping"     # abort requested: finishing the current view, then stop
    FINISHED = "finished"     # every queued view handled, or aborted (the message says which)
    FAILED = "failed"         # an unexpected error; the dataset stays valid and resumable


class Trigger(str, enum.Enum):
    """What moves the scan from one state to another (see :data:`TRANSITIONS`)."""

    # the operator's requests (any thread; applied by the engine thread)
    START = "start"
    PAUSE = "pause"           # pause after the current view
    RESUME = "resume"         # continue a paused scan (after a fault: reconnect and retry)
    ABORT = "abort"           # stop after the current view; what is captured stays
    SKIP = "skip"             # leave views out
    RECAPTURE = "recapture"   # queue views again
    # the engine's own steps (engine thread only)
    FAULT = "fault"           # a device or disk fault, or STOP pressed: pause at the next checkpoint
    CHECKPOINT = "checkpoint"  # every file of a pausing scan is stored: now paused
    DONE = "done"             # every queued view handled, or the abort landed
    CRASH = "crash"           # an unexpected error: the dataset stays valid and resumable


S, T = ScanState, Trigger
#: The state machine: ``TRANSITIONS[state][trigger]`` is the next state; a trigger missing from a
#: state's row is not allowed there. Requests accepted while idle wait in the engine's queue and
#: are applied once the scan runs (a pause or abort before the first view lands before it).
TRANSITIONS: dict[ScanState, dict[Trigger, ScanState]] = {
    S.IDLE: {T.START: S.RUNNING, T.PAUSE: S.IDLE, T.ABORT: S.IDLE, T.SKIP: S.IDLE, T.RECAPTURE: S.IDLE,
             T.CRASH: S.FAILED},
    S.RUNNING: {T.PAUSE: S.PAUSING, T.ABORT: S.STOPPING, T.SKIP: S.RUNNING, T.RECAPTURE: S.RUNNING,
                T.FAULT: S.PAUSING, T.DONE: S.FINISHED, T.CRASH: S.FAILED},
    S.PAUSING: {T.ABORT: S.STOPPING, T.SKIP: S.PAUSING, T.RECAPTURE: S.PAUSING, T.FAULT: S.PAUSING,
                T.CHECKPOINT: S.PAUSED, T.DONE: S.FINISHED, T.CRASH: S.FAILED},
    S.PAUSED: {T.RESUME: S.RUNNING, T.ABORT: S.STOPPING, T.SKIP: S.PAUSED, T.RECAPTURE: S.PAUSED,
               T.FAULT: S.PAUSED, T.CRASH: S.FAILED},
    S.STOPPING: {T.ABORT: S.STOPPING, T.FAULT: S.STOPPING, T.DONE: S.FINISHED, T.CRASH: S.FAILED},
    S.FINISHED: {},
    S.FAILED: {},
}
del S, T

#: The triggers an operator (GUI, CLI, a listener) may request; the others are the engine's own.
REQUESTS = frozenset({Trigger.START, Trigger.PAUSE, Trigger.RESUME, Trigger.ABORT, Trigger.SKIP,
                      Trigger.RECAPTURE})
#: States in which the scan owns the rig and the camera: every other motion command, capture or camera
#: setting is refused (STOP never is). While paused the operator has both back (to home the rig, clear
#: a fault or take a test shot before Resume).
OWNS_RIG = frozenset({ScanState.RUNNING, ScanState.PAUSING, ScanState.STOPPING})
TERMINAL = frozenset({ScanState.FINISHED, ScanState.FAILED})

_WHY = {ScanState.IDLE: "the scan has not started",
        ScanState.RUNNING: "the scan is running",
        ScanState.PAUSING: "the scan is pausing (finishing the current view)",
        ScanState.PAUSED: "the scan is paused",
        ScanState.STOPPING: "the scan is stopping (finishing the current view)",
        ScanState.FINISHED: "the scan has finished",
        ScanState.FAILED: "the scan has failed"}


def allowed_requests(state: ScanState) -> list[Trigger]:
    """The operator requests :data:`TRANSITIONS` allows in ``state`` (in :class:`Trigger` order)."""
    return [t for t in Trigger if t in REQUESTS and t in TRANSITIONS[state]]


class ScanRequestRefused(LfError):
    """``trigger`` is not allowed in ``state`` (see :data:`TRANSITIONS`); nothing was changed."""

    kind = "request-refused"

    def __init__(self, trigger: Trigger, state: ScanState, why: str | None = None):
        self.trigger = trigger
        self.state = state
        allowed = ", ".join(t.value for t in allowed_requests(state))
        super().__init__(f"Scan: {trigger.value} refused: {why or _WHY[state]}"
                         + (f" (possible now: {allowed})." if allowed else "; start a new scan to go on."))


def next_state(state: ScanState, trigger: Trigger) -> ScanState:
    """The state ``trigger`` leads to from ``state``; :class:`ScanRequestRefused` if not allowed."""
    try:
        return TRANSITIONS[state][trigger]
    except KeyError:
        raise ScanRequestRefused(trigger, state) from None


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
        where = f"view {view_label(self.row, self.column or 0)}" if self.row is not None else ""
        if self.kind is EventKind.STATE:
            if re.match(r"[A-Z][a-z]+: ", self.message):     # "Finished: 27 of 27 …" names its state itself
                return self.message
            return f"{self.state.value if self.state else ''}: {self.message}".rstrip(": ")
        if self.kind is EventKind.VIEW_DONE:
            period = self.timings_s.get("period")
            return f"{where} done ({self.done}/{self.total})" + (f", {period:.2f} s per view" if period else "")
        if self.kind is EventKind.VIEW_STARTED:
            return f"{where} moving"
        if self.kind is EventKind.VIEW_EXPOSED:
            return f"{where} exposed"
        return f"{where}: {self.message}" if where else self.message
