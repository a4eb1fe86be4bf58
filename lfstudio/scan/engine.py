"""The scan engine: runs a :class:`ScanPlan` on a rig and a camera into a dataset folder.

Threads:

* the **engine thread** owns the state machine and, per view, moves the rig, waits for it to
  settle and triggers the camera; as soon as the camera reports the shutter closed
  (``Camera.capture(..., on_exposed=)``), it moves on to the next view;
* the **store thread** waits for each capture's file (download/transfer), checksums it, writes its
  thumbnail and journals the view (fsync'd) — overlapping the next move and settle;
* the devices run on their :class:`lfstudio.rig.worker.DeviceWorker` threads (the engine makes
  its own workers for bare drivers).

Checkpoints (where a pause or an abort lands) are between views: a pause finishes the current
view, waits until every file is stored, then reports ``paused``. A device fault retries the view
with backoff; when the retries are used up the scan pauses with the device's message, and
``resume()`` reconnects the device and retries the view. Too little free disk space pauses too.
Listeners get :class:`ScanEvent` objects on the engine's threads.
"""

from __future__ import annotations

import errno
import logging
import queue
import threading
import time
import traceback
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from lfstudio.dataset import Dataset
from lfstudio.dataset.manifest import now_iso
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.store import clean_temporary_files, free_bytes, sha256_file
from lfstudio.errors import DeviceError, LfError
from lfstudio.rig.camera import CaptureResult, supports_on_exposed
from lfstudio.rig.motion import RigState
from lfstudio.rig.worker import CallTimedOut, DeviceWorker
from lfstudio.scan.events import EventKind, ScanEvent, ScanState
from lfstudio.scan.scan_plan import PlannedView, ScanPlan
from lfstudio.scan.thumbs import THUMB_WIDTH_PX, make_thumbnail

log = logging.getLogger(__name__)

Listener = Callable[[ScanEvent], None]
DONE_STATUSES = ("done", "skipped")
_STOP = object()


class ScanFault(LfError):
    """A fault the operator must fix (device, disk); the scan pauses with this message."""

    def __init__(self, message: str, device: str = ""):
        super().__init__(message)
        self.device = device


@dataclass
class _Job:
    """One view in flight between the engine thread and the store thread."""

    view: PlannedView
    attempt: int
    future: Future
    exposed_at: float
    reported_mm: list[float] | None
    timings_s: dict[str, float] = field(default_factory=dict)


def _as_worker(device: Any, name: str) -> tuple[DeviceWorker, bool]:
    if isinstance(device, DeviceWorker):
        return device, False
    status = "status" if name == "rig" else None
    return DeviceWorker(device, name=name, status_method=status, publish_hz=2.0), True


def _error_text(exc: BaseException) -> str:
    text = str(exc).strip()
    return text if text else type(exc).__name__


class ScanEngine:
    """Capture ``plan`` with ``rig`` and ``camera`` into ``dataset``.

    ``rig``/``camera``: drivers (:class:`MotionController`, :class:`Camera`) or the
    :class:`DeviceWorker` already running them (the GUI shares its workers). By default only views
    not yet ``done``/``skipped`` in the dataset are captured (resume); ``recapture=True`` captures
    every view of the plan (use a plan subset for chosen views).
    """

    def __init__(self, dataset: Dataset, plan: ScanPlan, rig: Any, camera: Any, *,
                 recapture: bool = False, retries: int = 2, backoff_s: float = 0.5,
                 move_timeout_s: float = 300.0, capture_timeout_s: float = 120.0,
                 min_free_bytes: int = 256 * 2**20, time_scale: float = 1.0,
                 thumb_width_px: int = THUMB_WIDTH_PX, checkpoint_s: float = 5.0,
                 free_bytes_fn: Callable[[Path], int] = free_bytes):
        self.dataset = dataset
        self.plan = plan
        self.rig, self._own_rig = _as_worker(rig, "rig")
        self.camera, self._own_camera = _as_worker(camera, "camera")
        self.retries = int(retries)
        self.backoff_s = float(backoff_s)
        self.move_timeout_s = float(move_timeout_s)
        self.capture_timeout_s = float(capture_timeout_s)
        self.min_free_bytes = int(min_free_bytes)
        self.time_scale = max(0.0, float(time_scale))
        self.thumb_width_px = int(thumb_width_px)
        self.checkpoint_s = float(checkpoint_s)
        self.free_bytes_fn = free_bytes_fn
        self._pipelined = supports_on_exposed(self.camera.driver)

        self._cond = threading.Condition()
        self._state = ScanState.IDLE
        self._pause_req = False
        self._abort_req = False
        self._resume_req = False
        self.fault: ScanFault | None = None
        self.message = ""
        self._listeners: list[Listener] = []
        self._listeners_lock = threading.Lock()

        statuses = {(v["row"], v["column"]): v.get("status") for v in dataset.views}
        todo = [v for v in plan.views() if recapture or statuses.get(v.cell) not in DONE_STATUSES]
        missing = [v.cell for v in todo if v.cell not in statuses]
        if missing:
            raise LfError(f"{dataset.manifest_path}: the plan has views the dataset does not list "
                          f"(first: row {missing[0][0]}, column {missing[0][1]}); scan into a new dataset folder")
        self._queue: deque[PlannedView] = deque(todo)
        self._attempts: dict[tuple[int, int], int] = {}
        self._last_error: dict[tuple[int, int], str] = {}
        self._retry: deque[tuple[PlannedView, str]] = deque()   # failed during transfer, from the store thread
        self._store_fault: ScanFault | None = None
        self._skip_cells: set[tuple[int, int]] = set()
        self._current: PlannedView | None = None
        self._last_file_bytes = 0
        self._store_q: queue.Queue = queue.Queue(maxsize=2)
        self._inflight = 0
        self._prev_future: Future | None = None
        self.total = len(dataset.views)
        self.done = sum(1 for v in dataset.views if v.get("status") == "done")
        self.captured_this_run = 0
        self._active_s = 0.0
        self._active_since: float | None = None
        self._last_done_t: float | None = None
        self._last_save = time.monotonic()
        self._thread: threading.Thread | None = None
        self._store_thread: threading.Thread | None = None

    # -- listeners ---------------------------------------------------------------------------------
    def subscribe(self, listener: Listener) -> Callable[[], None]:
        with self._listeners_lock:
            self._listeners.append(listener)

        def unsubscribe() -> None:
            with self._listeners_lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)
        return unsubscribe

    def _emit(self, kind: EventKind, message: str = "", **kw: Any) -> ScanEvent:
        ev = ScanEvent(kind=kind, message=message, state=kw.pop("state", self._state), done=self.done,
                       total=self.total, **kw)
        with self._listeners_lock:
            listeners = list(self._listeners)
        for cb in listeners:
            try:
                cb(ev)
            except Exception:
                log.exception("scan listener failed")
        return ev

    # -- state -------------------------------------------------------------------------------------
    @property
    def state(self) -> ScanState:
        return self._state

    @property
    def remaining(self) -> int:
        """Views still queued in this run (including the one being captured)."""
        return len(self._queue) + len(self._retry) + (1 if self._current is not None else 0)

    @property
    def pipelined(self) -> bool:
        """True when the camera tells when the shutter closed, so transfer overlaps the next move."""
        return self._pipelined

    def _set_state(self, state: ScanState, message: str = "") -> None:
        with self._cond:
            if state is self._state and message == self.message:
                return
            now = time.monotonic()
            if state is ScanState.RUNNING and self._active_since is None:
                self._active_since = now
            elif state is not ScanState.RUNNING and self._state is ScanState.RUNNING and self._active_since:
                self._active_s += now - self._active_since
                self._active_since = None
            self._state = state
            self.message = message
            self._cond.notify_all()
        log.info("scan %s%s", state.value, f": {message}" if message else "")
        self._emit(EventKind.STATE, message, state=state)

    def eta_s(self) -> float | None:
        """Seconds left at the pace of this run so far (paused time excluded)."""
        active = self._active_s + (time.monotonic() - self._active_since if self._active_since else 0.0)
        if self.captured_this_run == 0:
            return None
        return self.remaining * active / self.captured_this_run

    # -- commands (any thread) ---------------------------------------------------------------------
    def start(self) -> None:
        with self._cond:
            if self._thread is not None:
                raise RuntimeError("a scan engine runs once; create a new one to scan again")
            self._thread = threading.Thread(target=self._run, name="scan-engine", daemon=True)
            self._store_thread = threading.Thread(target=self._store_loop, name="scan-store", daemon=True)
        self._store_thread.start()
        self._thread.start()

    def pause(self) -> None:
        """Pause after the current view (its file is stored before the state becomes ``paused``)."""
        with self._cond:
            if self._state in (ScanState.RUNNING, ScanState.IDLE):
                self._pause_req = True
                self._cond.notify_all()
        if self._state is ScanState.RUNNING:
            self._set_state(ScanState.PAUSING, "finishing the current view")

    def resume(self) -> None:
        """Continue a paused scan (after a fault: reconnect the device and retry the view)."""
        with self._cond:
            self._pause_req = False
            self._resume_req = True
            self._cond.notify_all()

    def abort(self) -> None:
        """Stop after the current view; everything captured so far stays in the dataset."""
        with self._cond:
            self._abort_req = True
            self._cond.notify_all()
        if self._state in (ScanState.RUNNING, ScanState.PAUSING):
            self._set_state(ScanState.STOPPING, "finishing the current view")

    def skip(self, cells: Iterable[tuple[int, int]] | None = None) -> None:
        """Leave views out. ``None``: the view a fault paused on (recorded as ``failed``), or the next
        view. Given cells not yet captured are recorded as ``skipped``."""
        with self._cond:
            if cells is None:
                if self._queue:
                    cells = [self._queue[0].cell]
                else:
                    cells = []
            self._skip_cells.update((int(r), int(c)) for r, c in cells)
            self._cond.notify_all()

    def recapture(self, cells: Iterable[tuple[int, int]]) -> None:
        """Queue views again (in plan order, after the views still to do); their status becomes pending."""
        wanted = {(int(r), int(c)) for r, c in cells}
        with self._cond:
            queued = {v.cell for v in self._queue}
            for v in self.plan.with_subset(None).views():
                if v.cell in wanted and v.cell not in queued:
                    self._queue.append(v)
                    self._attempts.pop(v.cell, None)
            self._skip_cells -= wanted
            self._cond.notify_all()

    def wait(self, timeout_s: float | None = None) -> ScanState:
        """Block until the scan finished or failed (or ``timeout_s``); return the state."""
        t = self._thread
        if t is not None:
            t.join(timeout_s)
        return self._state

    def wait_for_state(self, *states: ScanState, timeout_s: float | None = None) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._state in states, timeout_s)

    # -- engine thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._prepare()
            self._set_state(ScanState.RUNNING, f"{self.remaining} views to capture")
            self._check_rig_ready()
            self._loop()
        except Exception as exc:  # a bug or an unexpected library error: keep the dataset valid
            log.error("scan failed:\n%s", traceback.format_exc())
            self._drain_store()
            self._finish_storage()
            self._set_state(ScanState.FAILED, f"Unexpected error: {type(exc).__name__}: {exc}. "
                                              "Everything captured so far is saved; resume the scan to go on.")
        finally:
            self._store_q.put(_STOP)
            if self._store_thread is not None:
                self._store_thread.join(30)
            if self._own_rig:
                self.rig.close(disconnect=False)
            if self._own_camera:
                self.camera.close(disconnect=False)

    def _prepare(self) -> None:
        """Remove crash leftovers: temporary files, and files of views the journal never finished."""
        removed = clean_temporary_files(self.dataset.root)
        unfinished = {view_stem(v["row"], v["column"]) for v in self.dataset.views
                      if v.get("status") not in DONE_STATUSES}
        for sub in ("raw", "thumbs"):
            folder = self.dataset.root / sub
            if not folder.is_dir():
                continue
            for p in folder.iterdir():
                if p.is_file() and p.name.split(".")[0] in unfinished:
                    p.unlink(missing_ok=True)
                    removed.append(p)
        if removed:
            self._emit(EventKind.LOG, f"removed {len(removed)} unfinished file(s) left by an interrupted scan")
        (self.dataset.root / "raw").mkdir(exist_ok=True)
        (self.dataset.root / "thumbs").mkdir(exist_ok=True)

    def _rig_problem(self) -> ScanFault | None:
        try:
            status = self.rig.call("status", timeout_s=30)
        except Exception as exc:
            return ScanFault(f"Rig: {_error_text(exc)}. Check the cable and power, reconnect, then Resume.", "rig")
        if status.state is RigState.ALARM:
            return ScanFault(f"Rig in alarm: {status.message or 'locked'}. Home the rig (Rig → Home) "
                             "or clear the alarm, then Resume.", "rig")
        if status.state is RigState.DISCONNECTED:
            return ScanFault("Rig is not connected. Connect it, then Resume.", "rig")
        if not status.homed:
            return ScanFault("Rig is not homed: home it (Rig → Home) or set the origin, then Resume.", "rig")
        return None

    def _check_rig_ready(self) -> None:
        problem = self._rig_problem()
        if problem is not None:
            self._fault(problem)

    def _loop(self) -> None:
        while True:
            if self._checkpoint():
                return
            view = self._next_view()
            if view is None:
                # nothing queued: wait for the store stage (it may hand views back for a retry)
                self._drain_store()
                if self._retry or self._store_fault or self._queue:
                    continue
                break
            self._current = view
            try:
                self._capture_view(view)
            except ScanFault as fault:
                with self._cond:
                    self._queue.appendleft(view)
                self._current = None
                self._fault(fault)
                continue
            self._current = None
        self._drain_store()
        self._finish_storage()
        with self._cond:
            remaining = self.remaining
        self._finish(remaining)

    def _finish(self, remaining: int) -> None:
        counts = self.dataset.status_counts()
        text = (f"{counts['done']} of {self.total} views captured" +
                (f", {counts['failed']} failed" if counts["failed"] else "") +
                (f", {counts['skipped']} skipped" if counts["skipped"] else ""))
        if self._abort_req and remaining:
            self._set_state(ScanState.FINISHED, f"Aborted: {text}. Resume the scan to capture the rest.")
        else:
            self._set_state(ScanState.FINISHED, f"Finished: {text}.")

    def _next_view(self) -> PlannedView | None:
        with self._cond:
            if self._retry:
                view, _ = self._retry.popleft()
                return view
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
        fields: dict[str, Any] = {"status": status}
        if error:
            fields["error"] = error
        self.dataset.record_view(view.row, view.column, **fields)
        self._emit(EventKind.VIEW_SKIPPED, f"{status} by the operator", row=view.row, column=view.column)

    def _checkpoint(self) -> bool:
        """Between views: act on pause/abort/faults. True when the scan must end."""
        if self._store_fault is not None:
            with self._cond:
                fault, self._store_fault = self._store_fault, None
            self._fault(fault)
        while True:
            with self._cond:
                abort, pause = self._abort_req, self._pause_req
            if abort:
                self._set_state(ScanState.STOPPING, "finishing the current view")
                self._drain_store()
                self._finish_storage()
                self._finish(self.remaining)
                return True
            if not pause:
                return False
            self._set_state(ScanState.PAUSING, "finishing the current view")
            self._drain_store()
            self._finish_storage()
            if self._store_fault is not None:
                with self._cond:
                    fault, self._store_fault = self._store_fault, None
                self.fault = fault
            done_text = f"{self.done} of {self.total} views captured"
            with self._cond:
                self._resume_req = False      # before announcing: a listener may resume at once
            self._set_state(ScanState.PAUSED, str(self.fault) if self.fault else f"{done_text}; Resume continues.")
            with self._cond:
                self._cond.wait_for(lambda: self._resume_req or self._abort_req)
                if self._abort_req:
                    continue
                self._resume_req = False
            fault, self.fault = self.fault, None
            self._set_state(ScanState.RUNNING, "resumed")
            if fault is not None:
                try:
                    self._recover(fault)
                except ScanFault as again:
                    self._fault(again)

    def _fault(self, fault: ScanFault) -> None:
        """Pause on a fault at the next checkpoint, telling the operator what happened."""
        self.fault = fault
        with self._cond:
            self._pause_req = True
        self._emit(EventKind.FAULT, str(fault), extra={"device": fault.device})

    def _recover(self, fault: ScanFault) -> None:
        """After a fault: reconnect the faulty device when it does not answer, then check the rig."""
        if fault.device == "camera":
            self._free_hung_camera()
            try:
                self.camera.call("disconnect", timeout_s=30)
            except Exception:
                pass
            try:
                self.camera.call("connect", timeout_s=60)
            except Exception as exc:
                raise ScanFault(f"Camera: reconnecting failed: {_error_text(exc)}. Check its cable, power and "
                                "USB mode, then Resume.", "camera") from None
        elif fault.device == "rig":
            try:
                connected = self.rig.call("status", timeout_s=10).state is not RigState.DISCONNECTED
            except Exception:
                connected = False
            if not connected:
                try:
                    self.rig.call("connect", timeout_s=60)
                except Exception as exc:
                    raise ScanFault(f"Rig: reconnecting failed: {_error_text(exc)}. Check the cable and power, "
                                    "then Resume.", "rig") from None
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
            except ScanFault:
                raise
            except Exception as exc:
                device = getattr(exc, "_scan_device", "camera")
                message = _error_text(exc)
                will_retry = attempt <= self.retries
                self._last_error[cell] = message
                self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                           will_retry=will_retry, extra={"attempt": attempt, "device": device})
                if not will_retry:
                    raise ScanFault(self._fault_text(device, message, attempt), device) from None
                self._last_error[cell] = message
                self._wait_interruptible(self.backoff_s * 2 ** (attempt - 1) * min(1.0, self.time_scale))

    @staticmethod
    def _fault_text(device: str, message: str, attempts: int) -> str:
        what = "Rig" if device == "rig" else "Camera" if device == "camera" else "Disk"
        fix = {"rig": "Check the axis controller's cable, power and alarms, reconnect it, then Resume.",
               "camera": "Check the camera's cable, power, battery and card, reconnect it, then Resume.",
               "disk": "Free disk space or choose another folder, then Resume."}.get(device, "Then Resume.")
        return f"{what} failed {attempts} time(s): {message}. {fix}"

    def _check_disk(self) -> None:
        need = max(self.min_free_bytes, 3 * self._last_file_bytes)
        try:
            free = self.free_bytes_fn(self.dataset.root)
        except OSError as exc:
            raise ScanFault(f"Disk: cannot check free space in {self.dataset.root}: {exc}.", "disk") from None
        if free < need:
            raise ScanFault(f"Disk almost full: {free / 2**20:.0f} MB free in {self.dataset.root}, "
                            f"{need / 2**20:.0f} MB needed per view. Free disk space, then Resume.", "disk")

    def _wait_interruptible(self, seconds: float) -> bool:
        """Sleep ``seconds`` unless an abort comes first (then True)."""
        if seconds <= 0:
            return self._abort_req
        with self._cond:
            return self._cond.wait_for(lambda: self._abort_req, seconds)

    def _attempt(self, view: PlannedView, attempt: int) -> None:
        self._check_disk()
        t0 = time.monotonic()
        self._emit(EventKind.VIEW_STARTED, index=view.index, row=view.row, column=view.column,
                   extra={"position_mm": view.position_mm, "attempt": attempt})
        try:
            status = self.rig.call("move_to", view.x_mm, view.y_mm, timeout_s=self.move_timeout_s)
        except Exception as exc:
            exc._scan_device = "rig"  # type: ignore[attr-defined]
            raise
        t_moved = time.monotonic()
        settle = self.plan.settle_s * self.time_scale
        if settle > 0:
            self._wait_interruptible(settle)   # an abort still captures this view: the rig is there
        t_settled = time.monotonic()
        # the camera must have finished the previous transfer before it can expose again
        prev = self._prev_future
        if prev is not None:
            try:
                prev.exception(timeout=self.capture_timeout_s + 10)
            except Exception:
                pass
        t_ready = time.monotonic()
        exposed = threading.Event()
        stem = self.dataset.root / "raw" / view_stem(view.row, view.column)
        if self._pipelined:
            fut = self.camera.submit("capture", stem, on_exposed=exposed.set, timeout_s=self.capture_timeout_s)
        else:
            fut = self.camera.submit("capture", stem, timeout_s=self.capture_timeout_s)
        fut.add_done_callback(lambda _f: exposed.set())
        exposed.wait()
        if fut.done() and fut.exception() is not None:
            self._free_hung_camera(fut.exception())
            raise fut.exception()
        t_exposed = time.monotonic()
        self._prev_future = fut
        pos = getattr(status, "position_mm", None)
        job = _Job(view, attempt, fut, t_exposed, None if pos is None else [float(pos[0]), float(pos[1])],
                   {"move": t_moved - t0, "settle": t_settled - t_moved, "camera_wait": t_ready - t_settled,
                    "expose": t_exposed - t_ready})
        with self._cond:
            self._inflight += 1
        self._emit(EventKind.VIEW_EXPOSED, index=view.index, row=view.row, column=view.column,
                   timings_s=dict(job.timings_s))
        self._store_q.put(job)

    def _free_hung_camera(self, exc: BaseException | None = None) -> None:
        """A capture that timed out may still hang in the driver: stop it so the camera is usable."""
        if exc is not None and not isinstance(exc, CallTimedOut):
            return
        if self.camera.current_command == "capture":
            try:
                self.camera.stop_now()
            except Exception as exc:
                log.debug("stopping the camera: %s", exc)

    # -- store thread ------------------------------------------------------------------------------
    def _store_loop(self) -> None:
        while True:
            job = self._store_q.get()
            if job is _STOP:
                return
            try:
                self._store(job)
            except Exception as exc:
                log.error("storing a view failed:\n%s", traceback.format_exc())
                self._store_failed(job, ScanFault(f"Storing view r{job.view.row:02d} c{job.view.column:03d} "
                                                  f"failed: {_error_text(exc)}.", "disk"))
            finally:
                with self._cond:
                    self._inflight -= 1
                    self._cond.notify_all()

    def _store_failed(self, job: _Job, fault: ScanFault) -> None:
        with self._cond:
            self._store_fault = fault
            self._pause_req = True
            self._queue.appendleft(job.view)
            self._cond.notify_all()
        self._emit(EventKind.FAULT, str(fault), row=job.view.row, column=job.view.column,
                   extra={"device": fault.device})

    def _store(self, job: _Job) -> None:
        view = job.view
        try:
            result: CaptureResult = job.future.result()
        except Exception as exc:
            self._free_hung_camera(exc)
            message = _error_text(exc)
            if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
                self._store_failed(job, ScanFault(f"Disk full while storing view r{view.row:02d} "
                                                  f"c{view.column:03d}: {message}. Free disk space, then Resume.",
                                                  "disk"))
                return
            will_retry = job.attempt <= self.retries
            self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                       will_retry=will_retry, extra={"attempt": job.attempt, "device": "camera"})
            if will_retry:
                with self._cond:
                    self._retry.append((view, message))
                    self._cond.notify_all()
            else:
                self._store_failed(job, ScanFault(self._fault_text("camera", message, job.attempt), "camera"))
            return
        t_transferred = time.monotonic()
        path = Path(result.path).resolve()
        rel = path.relative_to(self.dataset.root).as_posix()
        sha = sha256_file(path)
        self._last_file_bytes = path.stat().st_size
        thumb_rel = f"thumbs/{view_stem(view.row, view.column)}.jpg"
        preview = result.metadata.get("preview") if isinstance(result.metadata, dict) else None
        try:
            thumb = make_thumbnail(result.files, self.dataset.root / thumb_rel, self.thumb_width_px, preview)
        except Exception:
            log.exception("thumbnail of %s failed", rel)
            thumb = None
        timings = dict(job.timings_s)
        timings["transfer"] = t_transferred - job.exposed_at
        now = time.monotonic()
        timings["store"] = now - t_transferred
        if self._last_done_t is not None:
            timings["period"] = now - self._last_done_t
        self._last_done_t = now
        meta = result.metadata if isinstance(result.metadata, dict) else {}
        exposure = meta.get("shutter_s") or meta.get("exposure_s") or result.exposure_s
        fields = {"status": "done", "file": rel, "sha256": sha, "captured_at": now_iso(),
                  "exposure_s": float(exposure) if exposure else None,
                  "commanded_mm": [view.x_mm, view.y_mm], "reported_mm": job.reported_mm,
                  "thumb": thumb_rel if thumb is not None else None, "attempts": job.attempt,
                  "timings_s": {k: round(v, 4) for k, v in timings.items()}}
        sidecars = [Path(f).resolve().relative_to(self.dataset.root).as_posix() for f in result.files[1:]]
        if sidecars:
            fields["sidecars"] = sidecars
        self.dataset.record_view(view.row, view.column, **fields)
        with self._cond:
            self._attempts.pop(view.cell, None)
            self.done += 1
            self.captured_this_run += 1
        if time.monotonic() - self._last_save > self.checkpoint_s:
            self.dataset.save()
            self._last_save = time.monotonic()
        self._emit(EventKind.VIEW_DONE, index=view.index, row=view.row, column=view.column, eta_s=self.eta_s(),
                   timings_s=timings, file=rel, thumb=fields["thumb"])

    def _drain_store(self) -> None:
        with self._cond:
            self._cond.wait_for(lambda: self._inflight == 0)

    def _finish_storage(self) -> None:
        try:
            self.dataset.save()
        except OSError as exc:
            self._emit(EventKind.LOG, f"saving {self.dataset.manifest_path} failed ({exc}); "
                                      "the journal keeps every captured view")
        self._last_save = time.monotonic()


def dataset_views(plan: ScanPlan) -> list[dict[str, Any]]:
    """One pending manifest entry per grid cell of ``plan`` (row-major), with its commanded position."""
    full = plan.with_subset(None)
    return [{"row": r, "column": c, "commanded_mm": list(full.position_mm(r, c)), "reported_mm": None,
             "captured_at": None, "exposure_s": None, "file": None, "sha256": None, "status": "pending"}
            for r in range(plan.rows) for c in range(plan.columns)]


def create_scan_dataset(root: str | Path, plan: ScanPlan, *, rig: dict, camera: dict, lens: dict,
                        scene_plan: dict | None = None) -> Dataset:
    """A new dataset folder for ``plan`` with every view pending."""
    return Dataset.create(root, camera=camera, lens=lens, grid=plan.grid_dict(), rig=rig, plan=scene_plan or {},
                          views=dataset_views(plan))


def check_resume_matches(dataset: Dataset, plan: ScanPlan) -> list[str]:
    """Differences between an existing dataset's grid and ``plan`` that make resuming into it wrong."""
    g = dataset.grid
    problems = []
    if (g.get("columns"), g.get("rows")) != (plan.columns, plan.rows):
        problems.append(f"grid: the dataset is {g.get('columns')} x {g.get('rows')}, "
                        f"the scan asks for {plan.columns} x {plan.rows}")
    spacing = g.get("spacing_mm")
    if spacing and any(abs(float(a) - b) > 1e-6 for a, b in zip(spacing, plan.spacing_mm)):
        problems.append(f"spacing_mm: the dataset has {spacing[0]:g} x {spacing[1]:g} mm, "
                        f"the scan asks for {plan.spacing_mm[0]:g} x {plan.spacing_mm[1]:g} mm")
    return problems
