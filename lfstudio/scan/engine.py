"""The scan engine: runs a :class:`ScanPlan` on a rig and a camera into a dataset folder.

States and requests: the engine's states and what moves it between them are ONE table,
:data:`lfstudio.scan.events.TRANSITIONS`. The operator's requests (``start``, ``pause``,
``resume``, ``abort``, ``skip``, ``recapture``) may come from any thread: each is checked against
the table at once (an illegal one raises :class:`ScanRequestRefused`, naming the state and the
request) and queued to the engine thread, which applies it (or refuses it, through the returned
Future, when an earlier request changed the state meanwhile). The store thread and STOP post their
news to the same queue. Only the engine thread changes the state; any exception in its own code
ends the scan in ``failed`` with a message (the dataset stays valid and resumable).

Threads:

* the **engine thread** owns the state machine and, per view, moves the rig, waits for it to
  settle and triggers the camera; as soon as the camera reports the shutter closed
  (``Camera.capture(..., on_exposed=)``), it moves on to the next view. While it waits for a device
  it keeps applying requests;
* the **store thread** (:class:`lfstudio.scan.store.ScanStore`, which owns it and its state) waits
  for each capture's file (download/transfer), checksums it, writes its thumbnail and journals the
  view (fsync'd) — overlapping the next move and settle. It talks to the engine only through the
  inbox (a fault, a view to capture again, its crash) and its count of views in flight; disk faults
  and free space are its too;
* the devices run on their :class:`lfstudio.rig.worker.DeviceWorker` threads (the engine makes
  its own workers for bare drivers).

Interlock: while the scan owns the rig and the camera (running, pausing, stopping: :data:`OWNS_RIG`)
it holds the leases of both workers (:meth:`DeviceWorker.claim`), so every other motion command,
capture, live-view frame or setting change is refused with a message naming the scan
(:attr:`ScanEngine.label`); STOP is always accepted and pauses the scan. A paused scan gives both
back, so the operator can home the rig, clear a fault or take a test shot before Resume.

Checkpoints (where a pause or an abort lands) are between views: a pause finishes the current
view, waits until every file is stored, then reports ``paused``. An abort with a grace time
(``abort(grace_s=1)``, the CLI's Ctrl+C) ends sooner: a move under way is stopped and its view is
not taken, an exposure or transfer that ends within the grace time is stored, a later one is cut
short by stopping the camera and that view is not marked done (taken on resume). A device fault retries the view
with backoff; when the retries are used up the scan pauses with the device's message, and
``resume()`` reconnects the device and retries the view. Too little free disk space pauses too.
With ``auto_resume=N`` a pause whose cause can clear without a person (:attr:`ScanFault.clears`: the
disk has room again, the camera or a lost controller connection answers again after a reconnect)
is looked at every ``auto_resume_poll_s`` and resumed by the engine itself when it has cleared, at most
N times (the paused event's ``extra["auto_resume"]`` says it waits; the resumed one's
``extra["auto_resumed"]`` counts). STOP, an alarm (limit switch, homing), a position error or a
refused command always wait for a person.
Listeners get :class:`ScanEvent` objects on the engine's threads (a listener that raises is logged
and otherwise ignored).
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, TypeGuard

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import Bracket, frame_times_on_camera
from lfstudio.dataset.manifest import ViewUpdate, is_finished
from lfstudio.dataset.paths import folder_inside, view_label, view_stem
from lfstudio.dataset.storage import storage_error
from lfstudio.dataset.store import clean_temporary_files, free_bytes
from lfstudio.errors import DeviceError, DeviceRefused, DeviceTimeout, InputError, LfError, words
from lfstudio.numbers import RETRIES, TIME_SCALE, TIMEOUT_S, Number, non_finite_fields
from lfstudio.rig.camera import DescribesSettings, HasStatus, Paced, supports_on_exposed
from lfstudio.rig.motion import RigState
from lfstudio.rig.worker import CallTimedOut, DeviceWorker, Lease
from lfstudio.scan.events import (OWNS_RIG, TERMINAL, TRANSITIONS, EventKind, ScanEvent, ScanRequestRefused,
                                  ScanState, Trigger, next_state)
from lfstudio.scan.faults import (CLEARS_CAMERA, CLEARS_RIG, FIX, ScanFault, clears_by_itself,
                                  error_text, fault_text, refused_text)
from lfstudio.scan.preflight import MIN_FREE_BYTES, card_shortfall
from lfstudio.scan.scan_plan import PlannedView, ScanPlan
from lfstudio.scan.store import RETRY, ScanStore, StoreJob, free_hung_camera
from lfstudio.dataset.thumbs import THUMB_WIDTH_PX
from lfstudio.support.listeners import Listeners
from lfstudio.support.locks import dataset_lock

log = logging.getLogger(__name__)

Listener = Callable[[ScanEvent], None]
#: a camera's download time when it does not tell it (a RAW over USB takes a few seconds)
TRANSFER_ALLOWANCE_S = 30.0


class _RigFailed(Exception):
    """The rig's move for a view failed with ``error`` (a view's failures are the camera's unless they
    come wrapped in this: the engine's own type, not an attribute patched onto the driver's exception)."""

    def __init__(self, error: Exception):
        super().__init__(str(error))
        self.error = error


class _Interrupted(Exception):
    """A view's attempt ended because the scan is pausing or stopping (STOP, pause, abort, a fault)."""


@dataclass
class _Message:
    """One entry of the engine thread's inbox: a request, a fault, a retry or a crash."""

    kind: Trigger | str
    payload: Any = None
    future: Future | None = None


def _valid(number: Number, value: Any) -> float | None:
    """``value`` as a float when ``number`` takes it (a number in its range), else None."""
    return float(value) if isinstance(value, (int, float)) and number.problem(value) is None else None


def stop_fault() -> ScanFault:
    """The fault a scan pauses on when the rig's STOP is pressed."""
    fault = ScanFault("STOP pressed: the rig stopped. Check the rig and the scene, then Resume to go on "
                      "(or Abort).", "rig")
    fault.stop_pressed = True
    return fault


def _as_worker(device: Any, name: str) -> tuple[DeviceWorker, bool]:
    if isinstance(device, DeviceWorker):
        return device, False
    status = "status" if name == "rig" else None
    return DeviceWorker(device, name=name, status_method=status, publish_hz=2.0), True


#: the bracket's field as each front end names it
BRACKET_FIELD = words("--bracket", "Bracket")
WITHOUT_BRACKET = words("without --bracket", "with the Bracket field empty")


def bracket_on_camera(bracket: Bracket, driver: Any, call: Callable[[str], Any],
                      field: str = BRACKET_FIELD) -> tuple[tuple[float, ...], float | None]:
    """(each frame's shutter time as the camera can set it, the camera's shutter time now): EV steps
    around the shutter time it is set to, matched to its own choices where it describes them
    (``describe_settings``). ``call(name)`` runs a driver method (through its worker). Raises
    :class:`InputError` naming ``field`` with the camera's choices."""
    settings = call("settings")
    settings = settings if isinstance(settings, dict) else {}
    if "shutter_s" not in settings and not isinstance(driver, DescribesSettings):
        # a hot folder or a trigger command: lfstudio cannot set the exposure, so every frame's
        # set_setting would fail at each view after the rig has moved; refused before anything
        raise InputError(field, "this camera has no shutter time lfstudio can set (a hot folder or a trigger "
                         "command takes what the camera is set to): bracket with a camera lfstudio controls ("
                         + words("--camera gphoto2", "a gphoto2 camera in the Camera panel")
                         + "), or use the camera's own bracketing and import the frames")
    base = _valid(Number("s", 0, low_open=True), settings.get("shutter_s"))
    values: tuple = ()
    texts: tuple = ()
    range_s: tuple[float, float] | None = None
    if isinstance(driver, DescribesSettings):
        try:
            described = call("describe_settings")
        except Exception as exc:       # the times are checked again when each frame is set
            log.info("camera settings not described (%s)", exc)
            described = []
        for setting in described or ():
            if getattr(setting, "name", "") == "shutter_s":
                values, texts = tuple(setting.values), tuple(setting.choices)
                span = getattr(setting, "range", None)
                if isinstance(span, (tuple, list)) and len(span) >= 2 and 0 < span[0] <= span[1]:
                    range_s = (float(span[0]), float(span[1]))
    model = ""
    try:
        model = driver.status().model if isinstance(driver, HasStatus) else ""
    except Exception:                  # a name for the message only
        pass
    return frame_times_on_camera(bracket, base, values, texts, model or "the camera", field, range_s), base


class ScanEngine:
    """Capture ``plan`` with ``rig`` and ``camera`` into ``dataset``.

    ``rig``/``camera``: drivers (:class:`MotionController`, :class:`Camera`) or the
    :class:`DeviceWorker` already running them (the GUI shares its workers). By default only views
    not yet ``done``/``skipped`` in the dataset are captured (resume); ``recapture=True`` captures
    every view of the plan (use a plan subset for chosen views).

    Requests (:meth:`start`, :meth:`pause`, :meth:`resume`, :meth:`abort`, :meth:`skip`,
    :meth:`recapture`) return at once with a Future that resolves (to the state after it) when the
    engine thread has applied the request; they raise :class:`ScanRequestRefused` when the current
    state does not allow them.
    """

    def __init__(self, dataset: Dataset, plan: ScanPlan, rig: Any, camera: Any, *,
                 recapture: bool = False, retries: int = 2, backoff_s: float = 0.5,
                 move_timeout_s: float = 300.0, capture_timeout_s: float = 120.0,
                 min_free_bytes: int = MIN_FREE_BYTES, time_scale: float = 1.0,
                 thumb_width_px: int = THUMB_WIDTH_PX, checkpoint_s: float = 5.0,
                 free_bytes_fn: Callable[[Path], int] = free_bytes, auto_resume: int = 0,
                 auto_resume_poll_s: float = 10.0):
        self.dataset = dataset
        self.plan = plan
        self.rig, self._own_rig = _as_worker(rig, "rig")
        self.camera, self._own_camera = _as_worker(camera, "camera")
        self.retries = RETRIES.check("retries", retries)
        self.backoff_s = Number("s", 0, 600).check("backoff_s", backoff_s)
        self.move_timeout_s = TIMEOUT_S.check("move_timeout_s", move_timeout_s)
        self.capture_timeout_s = TIMEOUT_S.check("capture_timeout_s", capture_timeout_s)
        self.time_scale = TIME_SCALE.check("time_scale", time_scale)
        #: resume by itself at most this many times when a fault's cause clears (ScanFault.clears),
        #: looking every auto_resume_poll_s seconds while paused
        self.auto_resume = RETRIES.check("auto_resume", auto_resume)
        self.auto_resume_poll_s = Number("s", 0.001, 3600).check("auto_resume_poll_s", auto_resume_poll_s)
        self.auto_resumed = 0
        self._pipelined = supports_on_exposed(self.camera.driver)
        #: who holds the rig while this scan runs, as motion commands refused meanwhile name it
        self.label = f"the scan of {Path(dataset.root).name}"

        # the state machine: changed by the engine thread only (see _transition), guarded by _cond
        self._cond = threading.Condition()
        self._state = ScanState.IDLE
        self._announced = ScanState.IDLE     # the last state whose event the listeners have had
        self._inbox: deque[_Message] = deque()
        self.fault: ScanFault | None = None
        self.message = ""
        self.aborted = False             # an abort was applied (the engine thread sets it)
        self._drop_by: float | None = None   # abort(grace_s): monotonic time after which captures are dropped
        self._moving = False             # the engine thread waits for a move (engine thread only)
        self._lease: Lease | None = None           # the rig's, while the scan owns it
        self._stops = 0                            # STOPs pressed (see _stop_pressed, the recovery after a pause)
        self._camera_lease: Lease | None = None    # the camera's, at the same times
        self._listeners: Listeners[ScanEvent] = Listeners("scan listener", log)

        finished = {(v["row"], v["column"]): is_finished(v) for v in dataset.views}
        todo = [v for v in plan.views() if recapture or not finished.get(v.cell)]
        missing = [v.cell for v in todo if v.cell not in finished]
        if missing:
            raise LfError(f"{dataset.manifest_path}: the plan has views the dataset does not list "
                          f"(first: row {missing[0][0]}, column {missing[0][1]}); scan into a new dataset folder")
        # owned by the engine thread
        self._queue: deque[PlannedView] = deque(todo)
        self._retry: deque[PlannedView] = deque()    # failed during transfer (news from the store thread)
        self._attempts: dict[tuple[int, int], int] = {}
        self._last_error: dict[tuple[int, int], str] = {}
        self._skip_cells: set[tuple[int, int]] = set()
        self._current: PlannedView | None = None
        self._prev_future: Future | None = None
        self._capture_timeout: float | None = None      # per capture, from the camera's exposure + transfer
        self.total = len(dataset.views)
        self._active_s = 0.0
        self._active_since: float | None = None
        self._thread: threading.Thread | None = None
        #: the store stage (its own thread and state): talks back through the inbox and its inflight count
        self.store = ScanStore(dataset, self.camera, post=lambda kind, payload: self._post(_Message(kind, payload)),
                               wake=self._wake, emit=self._emit, eta_s=self.eta_s,
                               silent=lambda view, exc: self._silent("camera", view, exc),
                               remaining=lambda: self.remaining, retries=self.retries,
                               min_free_bytes=min_free_bytes, thumb_width_px=thumb_width_px,
                               checkpoint_s=checkpoint_s, free_bytes_fn=free_bytes_fn)
        self._start_future: Future | None = None
        #: an exposure bracket: each frame's shutter time (resolved in _prepare from the dataset's
        #: record or the plan's bracket and the camera); None: one picture per view as the camera is set
        self.frame_shutter_s: tuple[float, ...] | None = None
        self.bracket: Bracket | None = None

    # -- the store stage's counts and disk checks ---------------------------------------------------
    @property
    def done(self) -> int:
        """Views done in the dataset."""
        return self.store.done

    @property
    def captured_this_run(self) -> int:
        return self.store.captured_this_run

    @property
    def free_bytes_fn(self) -> Callable[[Path], int]:
        """Free bytes on the disk of a folder (the store's; replaceable, e.g. by tests)."""
        return self.store.free_bytes_fn

    @free_bytes_fn.setter
    def free_bytes_fn(self, fn: Callable[[Path], int]) -> None:
        self.store.free_bytes_fn = fn

    def need_bytes(self) -> int:
        """Free space the next view needs (:meth:`ScanStore.need_bytes`)."""
        return self.store.need_bytes()

    # -- listeners ---------------------------------------------------------------------------------
    def subscribe(self, listener: Listener) -> Callable[[], None]:
        return self._listeners.add(listener)

    def _emit(self, kind: EventKind, message: str = "", **kw: Any) -> ScanEvent:
        ev = ScanEvent(kind=kind, message=message, state=kw.pop("state", self._state), done=self.done,
                       total=self.total, **kw)
        self._listeners.notify(ev)
        return ev

    # -- state -------------------------------------------------------------------------------------
    @property
    def state(self) -> ScanState:
        return self._state

    @property
    def remaining(self) -> int:
        """Views still queued in this run (including the one being captured)."""
        return len(self._queue) + len(self._retry) + self.store.unrecorded + (1 if self._current is not None else 0)

    @property
    def pipelined(self) -> bool:
        """True when the camera tells when the shutter closed, so transfer overlaps the next move."""
        return self._pipelined

    @property
    def active_s(self) -> float:
        """Seconds spent running so far (paused time excluded)."""
        return self._active_s + (time.monotonic() - self._active_since if self._active_since else 0.0)

    def eta_s(self) -> float | None:
        """Seconds left at the pace of this run so far (paused time excluded)."""
        if self.captured_this_run == 0:
            return None
        return self.remaining * self.active_s / self.captured_this_run

    def _transition(self, trigger: Trigger, message: str | None = None, **extra: Any) -> None:
        """Move along :data:`TRANSITIONS` (engine thread only); ``message`` None keeps the current one.

        The rig is given back before a state that does not own it is announced, and taken before
        one that does (if someone else holds it, the scan pauses naming the holder)."""
        if threading.current_thread() is not self._thread:
            raise RuntimeError(f"scan state changed off the engine thread ({trigger.value})")
        with self._cond:
            old = self._state
            new = next_state(old, trigger)
            text = self.message if message is None else message
            if new is old and text == self.message:
                return
        busy: ScanFault | None = None
        if new not in OWNS_RIG:
            self._release_rig()
        elif old not in OWNS_RIG and self._lease is None:
            busy = self._claim_rig()
        with self._cond:
            now = time.monotonic()
            if new is ScanState.RUNNING and self._active_since is None:
                self._active_since = now
            elif new is not ScanState.RUNNING and self._active_since is not None:
                self._active_s += now - self._active_since
                self._active_since = None
            self._state = new
            self.message = text
            self._cond.notify_all()
        log.info("scan %s%s", new.value, f": {text}" if text else "")
        self._emit(EventKind.STATE, text, state=new, extra={"scan": self.label, **extra})
        with self._cond:
            self._announced = new        # wait_for_state returns once the listeners have the event too
            self._cond.notify_all()
        if busy is not None:
            self._raise_fault(busy)

    # -- rig ownership -----------------------------------------------------------------------------
    def _claim_rig(self) -> ScanFault | None:
        """Take the rig worker's lease, then the camera worker's; the fault to pause on when someone
        else holds either (then neither is held)."""
        device = "rig"
        try:
            self._lease = self.rig.claim(self.label, on_stop=self._stop_pressed)
            device = "camera"
            self._camera_lease = self.camera.claim(self.label)
        except DeviceError as exc:
            self._release_rig()
            text = error_text(exc)       # "rig: cannot be taken by ...: it is in use by ..."
            return ScanFault(f"{text[:1].upper()}{text[1:]}. Stop that first, then Resume.", device)
        return None

    def _release_rig(self) -> None:
        """Give the rig and the camera back (idempotent)."""
        lease, self._lease = self._lease, None
        camera_lease, self._camera_lease = self._camera_lease, None
        for held in (lease, camera_lease):
            if held is not None:
                held.release()

    def _stop_pressed(self) -> None:
        """The rig's STOP was pressed (any thread): pause instead of moving on."""
        if self._drop_by is not None:       # the engine's own stop for abort(grace_s): already ending
            return
        self._stops += 1
        self._post(_Message(Trigger.FAULT, (stop_fault(), None)))

    # -- requests (any thread) ---------------------------------------------------------------------
    def _post(self, message: _Message) -> None:
        with self._cond:
            self._inbox.append(message)
            self._cond.notify_all()

    def _request(self, trigger: Trigger, payload: Any = None) -> Future:
        future: Future = Future()
        with self._cond:
            if trigger not in TRANSITIONS[self._state]:
                raise ScanRequestRefused(trigger, self._state)
            self._inbox.append(_Message(trigger, payload, future))
            self._cond.notify_all()
        return future

    def start(self) -> Future:
        """Start the engine thread; the Future resolves when the scan runs."""
        with self._cond:
            if self._thread is not None:
                raise ScanRequestRefused(Trigger.START, self._state, "this scan was started already; create a "
                                         "new engine to scan again")
            if Trigger.START not in TRANSITIONS[self._state]:
                raise ScanRequestRefused(Trigger.START, self._state)
            self.label = f"the scan of {Path(self.dataset.root).name} (started {time.strftime('%H:%M')})"
            self._start_future = Future()
            self._thread = threading.Thread(target=self._run, name="scan-engine", daemon=True)
        self.store.start()
        self._thread.start()
        return self._start_future

    def pause(self) -> Future:
        """Pause after the current view (its file is stored before the state becomes ``paused``)."""
        return self._request(Trigger.PAUSE)

    def resume(self) -> Future:
        """Continue a paused scan (after a fault: reconnect the device and retry the view)."""
        return self._request(Trigger.RESUME)

    def abort(self, grace_s: float | None = None) -> Future:
        """Stop after the current view; everything captured so far stays in the dataset.

        With ``grace_s`` (seconds), stop within about that long instead: a move under way stops (its
        view is not taken), a capture whose file has not arrived ``grace_s`` after the request is cut
        short and its view stays not done. A second call may shorten the grace, never lengthen it."""
        return self._request(Trigger.ABORT, None if grace_s is None else Number("s", 0, 600).check("grace_s", grace_s))

    def skip(self, cells: Iterable[tuple[int, int]] | None = None) -> Future:
        """Leave views out. ``None``: the view a fault paused on (recorded as ``failed``), or the next
        view. Given cells not yet captured are recorded as ``skipped``."""
        return self._request(Trigger.SKIP, None if cells is None else [(int(r), int(c)) for r, c in cells])

    def recapture(self, cells: Iterable[tuple[int, int]]) -> Future:
        """Queue views again (in plan order, after the views still to do)."""
        return self._request(Trigger.RECAPTURE, {(int(r), int(c)) for r, c in cells})

    def wait(self, timeout_s: float | None = None) -> ScanState:
        """Block until the scan finished or failed (or ``timeout_s``); return the state."""
        t = self._thread
        if t is not None:
            t.join(timeout_s)
        return self._state

    def wait_for_state(self, *states: ScanState, timeout_s: float | None = None) -> bool:
        """Wait until the scan is in one of ``states`` and its STATE event has reached every listener
        (a caller that then reads what it was told sees that event; under load it used to wake first)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._announced in states, timeout_s)

    # -- the engine thread's inbox -----------------------------------------------------------------
    def _wake(self, *_: Any) -> None:
        with self._cond:
            self._cond.notify_all()

    def _wait(self, done: Callable[[], bool], timeout_s: float | None = None) -> bool:
        """Apply requests until ``done()`` (checked under the lock) or ``timeout_s``; True if done."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            self._handle_inbox()
            with self._cond:
                if self._inbox:
                    continue
                if done():
                    return True
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._cond.wait(left)

    def _await(self, future: Future, timeout_s: float | None = None) -> bool:
        future.add_done_callback(self._wake)
        return self._wait(future.done, timeout_s)

    def _handle_inbox(self) -> None:
        while True:
            with self._cond:
                if not self._inbox:
                    return
                message = self._inbox.popleft()
            self._apply(message)

    def _apply(self, message: _Message) -> None:
        kind, payload, future = message.kind, message.payload, message.future
        if kind == RETRY:
            self._retry.append(payload)
            return
        assert isinstance(kind, Trigger), f"inbox message {kind!r}"    # the store posts RETRY; the rest are Triggers
        if kind is Trigger.CRASH:
            raise payload
        if kind not in TRANSITIONS[self._state]:
            refused = ScanRequestRefused(kind, self._state)
            if future is not None:
                future.set_exception(refused)
            self._emit(EventKind.LOG, str(refused))
            return
        if kind is Trigger.PAUSE:
            self._transition(kind, "finishing the current view")
        elif kind is Trigger.ABORT:
            self.aborted = True
            if payload is not None:
                by = time.monotonic() + payload
                self._drop_by = by if self._drop_by is None else min(by, self._drop_by)
                if self._moving:            # the view it moves to will not be taken: stop the rig now
                    self.rig.stop_now()
            self._transition(kind, "finishing the current view" if self._drop_by is None else "stopping now")
        elif kind is Trigger.RESUME:
            self._transition(kind, "resumed")
        elif kind is Trigger.SKIP:
            cells = payload if payload is not None else [self._queue[0].cell] if self._queue else []
            self._skip_cells.update(cells)
            self._transition(kind)
        elif kind is Trigger.RECAPTURE:
            queued = {v.cell for v in self._queue}
            for v in self.plan.with_subset(None).views():
                if v.cell in payload and v.cell not in queued:
                    self._queue.append(v)
                    self._attempts.pop(v.cell, None)
            self._skip_cells -= payload
            self._transition(kind)
        elif kind is Trigger.FAULT:
            fault, requeue = payload
            if requeue is not None:
                self._queue.appendleft(requeue)
            self._raise_fault(fault)
        else:
            raise ScanRequestRefused(kind, self._state, "not a request")
        if future is not None:
            future.set_result(self._state)

    def _raise_fault(self, fault: ScanFault) -> None:
        """Pause on a fault at the next checkpoint, telling the operator what happened."""
        self.fault = fault
        self._emit(EventKind.FAULT, str(fault), extra={"device": fault.device})
        self._transition(Trigger.FAULT, None if self._state is not ScanState.RUNNING else "finishing the current view")

    # -- engine thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._prepare()
            self._transition(Trigger.START, f"{self.remaining} views to capture")
            if self._start_future is not None:
                self._start_future.set_result(self._state)
            self._check_rig_ready()
            self._loop()
        except BaseException as exc:  # a bug or an unexpected library error: keep the dataset valid
            self._crash(exc)
        finally:
            try:
                if self._state not in TERMINAL:     # cannot happen; never leave a waiter hanging
                    self._crash(RuntimeError("the scan engine ended without finishing"))
            finally:
                self._close()

    def _crash(self, exc: BaseException) -> None:
        # the operator reads the state's message; the traceback goes to the log file (not the console)
        log.info("scan failed:\n%s", "".join(traceback.format_exception(exc)))
        with self._cond:        # let the store thread finish what it holds (bounded: it may be the culprit)
            self._cond.wait_for(lambda: self.store.inflight == 0, self.capture_timeout_s + 30)
        problems = []
        try:
            self.store.save()
        except Exception as save_exc:
            problems = non_finite_fields(self.dataset.manifest)
            if not problems:
                log.error("saving the manifest after the failure failed: %s", save_exc)
        if problems:
            message = (f"{self.dataset.manifest_path} cannot be saved: {', '.join(problems[:3])} "
                       f"{'is' if len(problems) == 1 else 'are'} not a number (NaN or infinite). Correct "
                       "it in the file, then resume the scan; every captured view is kept in the journal.")
        elif isinstance(exc, LfError):      # an operator's message (a path refused, a dataset problem)
            message = f"{error_text(exc).rstrip('.')}. Everything captured so far is saved."
        else:
            message = (f"Unexpected error: {type(exc).__name__}: {exc}. Everything captured so far is saved; "
                       "resume the scan to go on.")
        try:
            self._transition(Trigger.CRASH, message)
        except Exception:   # already ended, or the announcement itself failed: still end in FAILED
            log.exception("announcing the failure failed")
            self._release_rig()
            with self._cond:
                if self._state not in TERMINAL:
                    self._state, self.message = ScanState.FAILED, message
                self._cond.notify_all()

    def _close(self) -> None:
        """After the last state: refuse requests still queued, stop the store thread, close own workers."""
        self._release_rig()
        if self._start_future is not None and not self._start_future.done():
            self._start_future.set_exception(ScanRequestRefused(Trigger.START, self._state, self.message))
        with self._cond:
            left, self._inbox = list(self._inbox), deque()
        for message in left:
            if message.future is not None and isinstance(message.kind, Trigger):
                message.future.set_exception(ScanRequestRefused(message.kind, self._state))
        self.store.close(30)
        lock, self._journal_lock = getattr(self, "_journal_lock", None), None
        if lock is not None:
            lock.release()
        if self._own_rig:
            self.rig.close(disconnect=False)
        if self._own_camera:
            self.camera.close(disconnect=False)

    def _prepare(self) -> None:
        """Remove crash leftovers (temporary files, files of views the journal never finished) and
        make sure the manifest can be written before the rig moves."""
        root = self.dataset.root
        if not self.dataset.owns_journal():  # the scan owns the journal (a session took the lock already)
            self._journal_lock = self.dataset.journal_lock = dataset_lock(root, "scanning").acquire()
        folders = [folder_inside(root, sub) for sub in ("raw", "thumbs")]   # refused when they lead outside
        removed = clean_temporary_files(root)
        unfinished = {view_stem(v["row"], v["column"]) for v in self.dataset.views
                      if not is_finished(v)}
        for folder in folders:
            for p in folder.iterdir():
                if p.is_file() and p.name.split(".")[0] in unfinished:
                    p.unlink(missing_ok=True)
                    removed.append(p)
        if removed:
            self._emit(EventKind.LOG, f"removed {len(removed)} unfinished file(s) left by an interrupted scan")
        for v in self.dataset.views:          # the frames of a view not done are taken again, all of them
            if v.get("frames") and not is_finished(v):
                self.dataset.record_view(v["row"], v["column"], frames=None)
        self._resolve_bracket()
        try:
            self.dataset.save()            # the manifest can be written: checked before the rig moves
        except OSError as exc:
            raise storage_error(exc, self.dataset.manifest_path, doing="saving") or exc
        self.store.repair_thumbnails()

    def _resolve_bracket(self) -> None:
        """The frames of every view: the dataset's recorded bracket (a resume takes exactly the frames
        the views already captured have), else the plan's, with each frame's shutter time matched to
        the camera's own choices (EV steps around the shutter time the camera is set to now). Refuses
        a plan whose bracket differs from the dataset's, and a bracket on a dataset whose views were
        captured with one picture each."""
        recorded = self.dataset.manifest.get("bracket")
        wanted = getattr(self.plan, "bracket", None)
        where = f"{self.dataset.manifest_path}: bracket"
        if recorded:
            have = Bracket.from_manifest(recorded, where)
            times = recorded.get("frame_shutter_s")
            if not (isinstance(times, list) and len(times) == have.frames and
                    all(Number("s", 0, low_open=True).problem(t) is None for t in times)):
                raise LfError(f"{where}: frame_shutter_s must list a shutter time in s for each of the "
                              f"{have.frames} frames; correct the file or scan into a new folder")
            if wanted is not None and wanted != have:
                raise LfError(f"{BRACKET_FIELD}: {wanted.describe()} ({wanted.frames} frames) differs from the "
                              f"{have.describe()} ({have.frames} frames) this dataset's views were captured "
                              f"with; resume with that bracket ({WITHOUT_BRACKET}), or scan into a new folder")
            self.bracket, self.frame_shutter_s = have, tuple(float(t) for t in times)
            return
        if wanted is None:
            return
        single = [v for v in self.dataset.done_views() if not v.get("frames")]
        if single:
            raise LfError(f"{BRACKET_FIELD}: this dataset has {len(single)} view(s) captured with one picture each "
                          f"(first: {view_label(single[0]['row'], single[0]['column'])}); every view of a "
                          f"dataset has the same frames: resume {WITHOUT_BRACKET}, or scan into a new folder")
        times, base = bracket_on_camera(wanted, self.camera.driver,
                                        lambda name: self._camera_call(name, timeout_s=30))
        self.bracket, self.frame_shutter_s = wanted, times
        self.dataset.manifest["bracket"] = {**wanted.to_manifest(), "frame_shutter_s": list(times),
                                            "base_shutter_s": base}
        self._emit(EventKind.LOG, f"exposure bracket: {wanted.describe()} = "
                                  + ", ".join(f"{t:.6g} s" for t in times) + " at every view")

    def _rig_call(self, name: str, *args: Any, timeout_s: float) -> Any:
        """A rig command through the scan's lease (while it holds one), applying requests meanwhile."""
        target = self._lease if self._lease is not None else self.rig
        future = target.submit(name, *args, timeout_s=timeout_s)
        self._await(future)
        return future.result()

    def _camera_call(self, name: str, *args: Any, timeout_s: float) -> Any:
        """A camera command through the scan's lease (while it holds one), applying requests meanwhile."""
        future = self._camera_submit(name, *args, timeout_s=timeout_s)
        self._await(future)
        return future.result()

    def _camera_submit(self, name: str, *args: Any, timeout_s: float, **kwargs: Any) -> Future:
        target = self._camera_lease if self._camera_lease is not None else self.camera
        return target.submit(name, *args, timeout_s=timeout_s, **kwargs)

    def _rig_problem(self) -> ScanFault | None:
        try:
            status = self._rig_call("status", timeout_s=30)
        except Exception as exc:
            return ScanFault(f"Rig: {error_text(exc)}. Check the cable and power, reconnect, then Resume.", "rig",
                             clears_by_itself("rig", exc))
        if status.state is RigState.ALARM:
            return ScanFault(f"Rig in alarm: {status.message or 'locked'}. Home the rig (Rig → Home) "
                             "or clear the alarm, then Resume.", "rig")
        if status.state is RigState.DISCONNECTED:
            return ScanFault("Rig is not connected. Connect it, then Resume.", "rig", CLEARS_RIG)
        if not status.homed:
            return ScanFault("Rig is not homed: home it (Rig → Home) or set the origin, then Resume.", "rig")
        return None

    def _check_rig_ready(self) -> None:
        if self._state is not ScanState.RUNNING:
            return
        problem = self._rig_problem()
        if problem is not None:
            self._raise_fault(problem)

    def _loop(self) -> None:
        while True:
            if self._checkpoint():
                return
            if not self._take_next():
                # nothing queued: wait for the store stage (it may hand views back for a retry)
                self._drain_store()
                if self._retry or self._queue:
                    continue
                break
        self._drain_store()
        self.store.save()
        self._restore_shutter()
        self._finish()

    def _take_next(self) -> bool:
        """Take what comes next in the queue (one view here); False when nothing is queued."""
        view = self._next_view()
        if view is None:
            return False
        self._take_view(view)
        return True

    def _take_view(self, view: PlannedView) -> None:
        """Capture one view; queued again when a fault or an interruption stops it."""
        self._current = view
        try:
            self._capture_view(view)
        except ScanFault as fault:
            self._queue.appendleft(view)
            self._raise_fault(fault)
        except _Interrupted:
            self._queue.appendleft(view)
        finally:
            self._current = None

    def _restore_shutter(self) -> None:
        """After a bracketed scan, the camera's shutter time as it was when the scan began (it was left
        at the last frame's), so the next single picture is not taken at a bracket's extreme."""
        base = (self.dataset.manifest.get("bracket") or {}).get("base_shutter_s")
        if self.frame_shutter_s is None or not isinstance(base, (int, float)) or base <= 0:
            return
        try:
            self._camera_call("set_setting", "shutter_s", float(base), timeout_s=30)
            self._emit(EventKind.LOG, f"camera shutter time set back to {base:.6g} s")
        except Exception as exc:      # the scan's pictures are safe; the operator is told
            self._emit(EventKind.LOG, f"the camera's shutter time could not be set back to {base:.6g} s ({exc}); "
                                      "check it before the next picture")

    def _finish(self) -> None:
        counts = self.dataset.status_counts()
        text = (f"{counts['done']} of {self.total} views captured" +
                (f", {counts['failed']} failed" if counts["failed"] else "") +
                (f", {counts['skipped']} skipped" if counts["skipped"] else ""))
        if self._state is ScanState.STOPPING and self.remaining:
            self._transition(Trigger.DONE, f"Aborted: {text}. Resume the scan to capture the rest.", aborted=True)
        else:
            self._transition(Trigger.DONE, f"Finished: {text}.")

    def _next_view(self) -> PlannedView | None:
        if self._retry:
            return self._retry.popleft()
        while self._queue:
            view = self._queue.popleft()
            if view.cell in self._skip_cells:
                self._record_skip(view)
                continue
            return view
        return None

    def _record_skip(self, view: PlannedView) -> None:
        self._skip_cells.discard(view.cell)
        error = self._last_error.get(view.cell)
        status = "failed" if error else "skipped"
        fields: ViewUpdate = {"status": status}
        if error:
            fields["error"] = error
        self.dataset.record_view(view.row, view.column, **fields)
        self._emit(EventKind.VIEW_SKIPPED, f"{status} by the operator", row=view.row, column=view.column)

    def _checkpoint(self) -> bool:
        """Between views: act on pause/abort/faults. True when the scan must end."""
        self._handle_inbox()
        while True:
            state = self._state
            if state is ScanState.RUNNING:
                return False
            if state is ScanState.STOPPING:
                self._drain_store()
                self.store.save()
                self._finish()
                return True
            if state is ScanState.PAUSING:
                self._drain_store()
                if self._state is not ScanState.PAUSING:
                    continue
                self.store.save()
                done_text = f"{self.done} of {self.total} views captured"
                fault = self.fault
                if self._resumes_by_itself(fault):
                    k = self.auto_resumed + 1
                    self._transition(Trigger.CHECKPOINT, f"{fault} Waiting: resumes by itself when {fault.clears} "
                                     f"(auto-resume {k} of {self.auto_resume}).",
                                     auto_resume={"waiting_for": fault.clears, "next": k, "of": self.auto_resume})
                else:
                    self._transition(Trigger.CHECKPOINT, str(fault) if fault else f"{done_text}; Resume continues.")
                continue
            # paused: wait for resume or abort (or, with auto_resume, for the fault's cause to clear)
            self._wait_paused()
            if self._state is ScanState.RUNNING:
                fault, self.fault = self.fault, None
                if fault is not None:
                    stops = self._stops
                    try:
                        self._recover(fault)
                    except ScanFault as again:
                        # a STOP while recovering cancels its rig calls: that is the operator's STOP, not a
                        # lost connection (a reconnect after it is refused while the controller holds)
                        self._raise_fault(stop_fault() if self._stops != stops else again)

    def _resumes_by_itself(self, fault: ScanFault | None) -> TypeGuard[ScanFault]:
        return fault is not None and bool(fault.clears) and self.auto_resumed < self.auto_resume

    @property
    def resumes_by_itself(self) -> bool:
        """True while the scan is paused on a fault it resumes from by itself when the cause clears."""
        return self._state is ScanState.PAUSED and self._resumes_by_itself(self.fault)

    def _wait_paused(self) -> None:
        """Paused: wait for the operator; with a fault that clears by itself (and auto-resumes left),
        look every ``auto_resume_poll_s`` whether it has cleared and resume when it has."""
        fault = self.fault
        if not self._resumes_by_itself(fault):
            self._wait(lambda: self._state is not ScanState.PAUSED)
            return
        while True:
            if self._wait(lambda: self._state is not ScanState.PAUSED or self.fault is not fault,
                          self.auto_resume_poll_s):
                return                  # the operator resumed or aborted, or another fault came in
            cleared = self._cleared(fault)
            if self._state is not ScanState.PAUSED or self.fault is not fault:
                return
            if cleared:
                self.auto_resumed += 1
                self._transition(Trigger.RESUME, f"resumed by itself: {fault.clears} (auto-resume "
                                 f"{self.auto_resumed} of {self.auto_resume})", auto_resumed=self.auto_resumed)
                return

    def _cleared(self, fault: ScanFault) -> bool:
        """Whether ``fault``'s cause has cleared (engine thread, while paused: the devices are not
        held). The disk: free space for the next view. A device: it reconnects and answers (the rig
        homed and idle, as before any view)."""
        try:
            if fault.device == "disk":
                return self.store.has_room(fault.need_bytes)
            if fault.device == "camera":
                free_hung_camera(self.camera)
                try:
                    self._camera_call("disconnect", timeout_s=30)
                except Exception:
                    pass
                self._camera_call("connect", timeout_s=60)
                self._camera_call("settings", timeout_s=10)
                fault.reconnected = True
                return True
            if fault.device == "rig":
                try:
                    connected = self._rig_call("status", timeout_s=10).state is not RigState.DISCONNECTED
                except Exception:
                    connected = False
                if not connected:
                    self._rig_call("connect", timeout_s=60)
                fault.reconnected = True
                problem = self._rig_problem()
                if problem is not None and not problem.clears:     # back, but in alarm / not homed: a person
                    self.fault = problem
                    self._emit(EventKind.FAULT, str(problem), extra={"device": problem.device})
                    self._transition(Trigger.FAULT, str(problem), fault_changed=True)
                return problem is None
        except Exception as exc:        # not yet: looked at again after auto_resume_poll_s
            log.info("auto-resume: %s not yet (%s)", fault.clears, error_text(exc))
        return False

    def _recover(self, fault: ScanFault) -> None:
        """After a fault: journal the views the disk refused to record, reconnect the faulty device when
        it does not answer, then check the rig."""
        self.store.record_kept()
        if fault.device == "disk":
            self.store.repair_thumbnails()
        if fault.reconnected:
            pass                        # the auto-resume probe reconnected it just now
        elif fault.device == "camera":
            free_hung_camera(self.camera)
            try:
                self._camera_call("disconnect", timeout_s=30)
            except Exception:
                pass
            try:
                self._camera_call("connect", timeout_s=60)
            except Exception as exc:
                raise ScanFault(f"Camera: reconnecting failed: {error_text(exc)}. Check its cable, power and "
                                "USB mode, then Resume.", "camera", CLEARS_CAMERA) from None
        elif fault.device == "rig":
            try:
                connected = self._rig_call("status", timeout_s=10).state is not RigState.DISCONNECTED
            except Exception:
                connected = False
            if not connected:
                try:
                    self._rig_call("connect", timeout_s=60)
                except Exception as exc:
                    raise ScanFault(f"Rig: reconnecting failed: {error_text(exc)}. Check the cable and power, "
                                    "then Resume.", "rig", CLEARS_RIG) from None
        self._attempts = {cell: 0 for cell in self._attempts}
        problem = self._rig_problem()
        if problem is not None:
            raise problem

    # -- one view ----------------------------------------------------------------------------------
    def _capture_view(self, view: PlannedView) -> None:
        cell = view.cell
        while True:
            attempt = self._attempts.get(cell, 0) + 1
            self._attempts[cell] = attempt
            try:
                self._attempt(view, attempt)
                return
            except (ScanFault, _Interrupted):
                raise
            except Exception as caught:
                exc, device = (caught.error, "rig") if isinstance(caught, _RigFailed) else (caught, "camera")
                disk = self.store.disk_fault(exc, self.dataset.root / "raw", "storing the capture of "
                                        + view_label(view.row, view.column))
                if disk is not None:            # the disk's fault, never the camera's: no retry
                    raise disk from None
                message = error_text(exc)
                if isinstance(exc, (DeviceTimeout, DeviceRefused, InputError)):   # no retry
                    self._last_error[cell] = message
                    self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                               will_retry=False, extra={"attempt": attempt, "device": device})
                    if isinstance(exc, DeviceTimeout):     # a device that does not answer: waiting again won't help
                        raise self._silent(device, view, exc) from None
                    # a value or a file: no cable advice
                    raise ScanFault(refused_text(device, f"view {view_label(view.row, view.column)}", message), device) from None
                self._handle_inbox()
                if self._state is not ScanState.RUNNING:
                    # STOP, a pause, an abort or a fault came in: no retry now (the view is queued again)
                    self._attempts[cell] = attempt - 1
                    self._emit(EventKind.LOG, f"view {view_label(view.row, view.column)}: {message} "
                                              f"({self._state.value}; captured after Resume)")
                    raise _Interrupted() from None
                will_retry = attempt <= self.retries
                self._last_error[cell] = message
                self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                           will_retry=will_retry, extra={"attempt": attempt, "device": device})
                if not will_retry:
                    raise ScanFault(fault_text(device, message, attempt), device,
                                    clears_by_itself(device, exc)) from None
                self._wait(lambda: self._state is not ScanState.RUNNING,
                           self.backoff_s * 2 ** (attempt - 1) * min(1.0, self.time_scale))
                if self.frame_shutter_s is not None:
                    self._drain_store()     # the failed attempt's frames are stored before they are taken again
                if self._state is not ScanState.RUNNING:
                    raise _Interrupted()

    def _silent(self, device: str, view: PlannedView, exc: BaseException | None = None) -> ScanFault:
        """The fault of a device that stopped answering during ``view`` (no retry: it would wait again).
        ``exc``: the driver's own timeout (a hot folder that got no file), told as it is."""
        where = f"view {view_label(view.row, view.column)}"
        if exc is not None and not isinstance(exc, CallTimedOut):
            what = f"{device.capitalize()} does not answer ({where}): {error_text(exc).rstrip('.')}."
        elif device == "rig":
            what = (f"Rig does not answer: the move to ({view.x_mm:g}, {view.y_mm:g}) mm for {where} did not end "
                    f"within {self.move_timeout_s:g} s.")
        else:
            what = (f"Camera does not answer: the picture of {where} did not arrive within "
                    f"{self.capture_call_timeout_s():g} s (exposure and transfer, twice over, plus 10 s).")
        return ScanFault(f"{what} {FIX[device]}", device, clears_by_itself(device, exc))

    def capture_call_timeout_s(self) -> float:
        """How long a capture may take before the camera counts as silent: twice its exposure and
        transfer times (from its settings; a transfer it does not tell counts as
        :data:`TRANSFER_ALLOWANCE_S`) plus 10 s for the trigger and the bus, at most
        ``capture_timeout_s``. A camera that does not even answer for its settings is silent already."""
        if self._capture_timeout is None:
            try:
                settings = self._camera_call("settings", timeout_s=10)
            except DeviceTimeout:
                raise
            except Exception as exc:
                log.info("camera settings not read (%s)", exc)
                settings = {}
            settings = settings if isinstance(settings, dict) else {}
            exposure = settings.get("shutter_s", settings.get("exposure_s"))
            transfer = settings.get("transfer_s")
            exposure = _valid(Number(), exposure)
            exposure = max([1.0 if exposure is None else exposure, *(self.frame_shutter_s or ())])   # a bracket's longest
            transfer = _valid(Number(), transfer)
            transfer = TRANSFER_ALLOWANCE_S if transfer is None else transfer
            driver = self.camera.driver
            scale = _valid(Number(low=0), driver.time_scale if isinstance(driver, Paced) else 1.0)   # a simulation's pace
            scale = 1.0 if scale is None else min(1.0, scale)
            timeout = self._capture_timeout = min(self.capture_timeout_s, 2 * (exposure + transfer) * scale + 10.0)
            log.info("capture timeout %.1f s (exposure %g s, transfer %g s)", timeout, exposure, transfer)
            return timeout
        return self._capture_timeout

    def _check_card(self) -> None:
        """Once a run, when the first view's frames are measured (by the store): a camera that keeps its
        pictures on its card (:meth:`GPhotoCamera.card_space`) has room there for the frames still to take."""
        frame_bytes = self.store.take_card_frame_bytes()
        if frame_bytes is None:
            return
        try:
            card = self._camera_call("card_space", timeout_s=30)
        except (ScanFault, _Interrupted):
            raise
        except Exception as exc:          # where the driver cannot read it: the card's own errors tell later
            log.info("the camera's card space not read: %s", error_text(exc))
            return
        short = card_shortfall(card, self.remaining, len(self.frame_shutter_s or (None,)), frame_bytes)
        if short is not None:
            raise ScanFault(f"{short} Then Resume.", "camera")

    def _attempt(self, view: PlannedView, attempt: int) -> None:
        self._check_card()
        self.store.check_disk()
        t0 = time.monotonic()
        self._emit(EventKind.VIEW_STARTED, index=view.index, row=view.row, column=view.column,
                   extra={"position_mm": view.position_mm, "attempt": attempt})
        self._handle_inbox()
        if self._state is not ScanState.RUNNING:     # STOP, a pause or an abort came in: do not move
            self._attempts[view.cell] = attempt - 1
            raise _Interrupted()
        self._moving = True
        try:
            status = self._rig_call("move_to", view.x_mm, view.y_mm, timeout_s=self.move_timeout_s)
        except (ScanFault, _Interrupted):
            raise
        except Exception as exc:
            raise _RigFailed(exc) from exc
        finally:
            self._moving = False
        t_moved = time.monotonic()
        settle = self.plan.settle_s * self.time_scale
        if settle > 0:   # an abort shortens it; this view is still captured: the rig is there
            self._wait(lambda: self._state is ScanState.STOPPING or self._faulted(), settle)
        t_settled = time.monotonic()
        # the camera must have finished the previous transfer before it can expose again
        prev = self._prev_future
        if prev is not None:
            prev.add_done_callback(self._wake)
            self._wait(lambda: prev.done() or self._drop_by is not None, self.capture_call_timeout_s() + 10)
        self._handle_inbox()
        if self._drop_by is not None or self._faulted():   # abort(grace_s), STOP or a fault: no new exposure
            self._attempts[view.cell] = attempt - 1
            raise _Interrupted()
        t_ready = time.monotonic()
        pos = getattr(status, "position_mm", None)
        reported = None if pos is None else [float(pos[0]), float(pos[1])]
        shutters: tuple[float | None, ...] = self.frame_shutter_s or (None,)
        bracketed = self.frame_shutter_s is not None
        for k, shutter in enumerate(shutters):
            if k > 0:       # the camera takes the next frame once the previous one is downloaded
                prev_frame = self._prev_future
                if prev_frame is not None:
                    prev_frame.add_done_callback(self._wake)
                    prev_done = prev_frame.done
                    self._wait(lambda: prev_done() or self._drop_by is not None,
                               self.capture_call_timeout_s() + 10)
                self._handle_inbox()
                if self._drop_by is not None or self._faulted():   # the view is not done: taken again whole
                    self._attempts[view.cell] = attempt - 1
                    raise _Interrupted()
            if shutter is not None:
                try:
                    self._camera_call("set_setting", "shutter_s", shutter, timeout_s=30)
                except InputError as exc:   # a value the camera refuses (one whose range nothing told): no retry
                    assert self.bracket is not None
                    fault = ScanFault(f"Camera refused frame {k + 1} of the bracket ({self.bracket.describe()}) at "
                                      f"view {view_label(view.row, view.column)}: {error_text(exc).rstrip('.')}. Every "
                                      "view of a dataset has the same frames, so the bracket cannot change in this "
                                      "one: stop this scan (Abort), then scan into a new folder with a bracket the "
                                      "camera takes.", "camera")
                    fault.resumable = False
                    raise fault from None
            stem = self.dataset.root / "raw" / (view_stem(view.row, view.column) + (f".f{k}" if bracketed else ""))
            fut = self._expose(view, attempt, stem)
            t_exposed = time.monotonic()
            self._prev_future = fut
            last = k == len(shutters) - 1
            timings = {"move": t_moved - t0, "settle": t_settled - t_moved, "camera_wait": t_ready - t_settled,
                       "expose": t_exposed - t_ready} if last else {}
            job = StoreJob(view, attempt, fut, t_exposed, reported, timings, k if bracketed else None,
                           len(shutters), shutter, self.bracket.reference_index if self.bracket is not None else 0)
            if last:
                self._emit(EventKind.VIEW_EXPOSED, index=view.index, row=view.row, column=view.column,
                           timings_s=dict(job.timings_s))
            self.store.submit(job)

    def _expose(self, view: PlannedView, attempt: int, stem: Path) -> Future:
        """Trigger one picture to ``stem``; return its future once the shutter has closed (the transfer
        may go on). Raises _Interrupted when an abort's grace time ends first, the capture's error
        when it failed before that."""
        exposed = threading.Event()

        def on_exposed(*_: Any) -> None:
            exposed.set()
            self._wake()

        timeout_s = self.capture_call_timeout_s()
        if self._pipelined:
            fut = self._camera_submit("capture", stem, on_exposed=on_exposed, timeout_s=timeout_s)
        else:
            fut = self._camera_submit("capture", stem, timeout_s=timeout_s)
        fut.add_done_callback(on_exposed)
        self._wait(lambda: exposed.is_set() or self._drop_by is not None)
        drop_by = self._drop_by                        # not None when the exposure is not done (the wait above)
        if not exposed.is_set() and drop_by is not None and \
                not self._wait(exposed.is_set, max(0.0, drop_by - time.monotonic())):
            self._stop_camera()                       # abort(grace_s) and the exposure goes on: drop it
            self._await(fut, 10.0)
            self._attempts[view.cell] = attempt - 1
            raise _Interrupted()
        failed = fut.exception() if fut.done() else None
        if failed is not None:
            free_hung_camera(self.camera, failed)
            raise failed
        return fut

    def _faulted(self) -> bool:
        """Pausing on a fault (STOP pressed, an alarm, a disk problem): the view being taken is not
        exposed (the rig may not be where it was sent; after STOP the operator expects nothing more)."""
        return self._state is ScanState.PAUSING and self.fault is not None

    def _drain_store(self) -> None:
        """Wait (applying requests) until every exposed view is stored; after ``abort(grace_s)``, only
        until the grace time is over: then the camera is stopped and what it has not delivered is
        dropped (those views stay not done)."""
        self._wait(lambda: self.store.inflight == 0 or self._drop_by is not None)
        if self.store.inflight and self._drop_by is not None and \
                not self._wait(lambda: self.store.inflight == 0, max(0.0, self._drop_by - time.monotonic())):
            self._stop_camera()
            self._wait(lambda: self.store.inflight == 0, 10.0)

    def _stop_camera(self) -> None:
        """abort(grace_s): cut the capture under way short; its view is dropped, not failed."""
        self.store.drop_transfers()
        try:
            self.camera.stop_now()
        except Exception as exc:
            log.info("stopping the camera: %s", exc)
