"""The one way from other threads to the GUI thread, and the one way to run a job off it.

Background threads (device workers, the scan engine, jobs, thumbnail and image decoders, the live
quality checker, the exception hook) never touch widgets. They hand what they have to a
:class:`GuiInbox`; the GUI thread gets it, in order, in batches:

    inbox = GuiInbox(handle_batch, parent)   # handle_batch(items: list) runs on the GUI thread
    inbox.post(item)                         # from any thread; returns at once

However many items arrive, one queued wake-up is pending at a time, so a flood (a fast scan's
events, a device's status snapshots) costs one slot call per turn of the event loop, not one per
item. With ``every_ms`` the handler runs at most that often (what arrives meanwhile waits for the
next batch): for a flood whose handler only collects for a frame-paced repaint anyway, this spares
the GUI thread a Python call (and a wait for the GIL) per turn of the loop. :class:`JobRunner` runs a core job (``fn(..., progress=, cancel=)``) on a worker thread and
reports it through its own inbox as Qt signals.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

from PySide6.QtCore import QObject, Qt, QTimer, Signal, Slot

from lfstudio.errors import LfError, window_message
from lfstudio.jobs import Cancelled, CancelToken, EtaEstimator

log = logging.getLogger(__name__)


class Pacer(QObject):
    """Runs ``fn()`` on the thread that owns it at most every ``every_ms``: :meth:`request` runs it at
    once when the last run is long enough ago (and none is waiting), else once when the interval has
    passed; the requests made meanwhile fold into that one run. ``every_ms`` 0: at once, each time.
    (A flood's handler, :class:`GuiInbox`; a label's text, :class:`lfstudio.gui.widgets.QuietLabel`.)"""

    def __init__(self, fn: Callable[[], None], every_ms: int = 0, parent: QObject | None = None):
        super().__init__(parent)
        self._fn = fn
        self.every_ms = every_ms
        self._last_s = float("-inf")
        self._timer: QTimer | None = None

    @Slot()
    def request(self) -> None:
        waiting = self._timer is not None and self._timer.isActive()
        wait_ms = self.every_ms - (time.perf_counter() - self._last_s) * 1000.0
        if wait_ms <= 0 and not waiting:
            self._run()
            return
        if self._timer is None:
            self._timer = QTimer(self)
            self._timer.setSingleShot(True)
            self._timer.setTimerType(Qt.TimerType.PreciseTimer)
            self._timer.timeout.connect(self._run)
        if not waiting:
            self._timer.start(int(wait_ms) + 1)

    def _run(self) -> None:
        self._last_s = time.perf_counter()
        self._fn()


class GuiInbox(QObject):
    """Items posted from any thread, handed to ``handler(items)`` on the thread that owns the inbox
    (the GUI thread), in posting order, at most every ``every_ms`` (0: at the next turn of the
    event loop). :meth:`close` drops everything posted afterwards."""

    _wake = Signal()

    def __init__(self, handler: Callable[[list], object], parent: QObject | None = None, every_ms: int = 0):
        super().__init__(parent)
        self._handler = handler
        self._items: list = []
        self._lock = threading.Lock()
        self._pending = False
        self._closed = False
        self._pacer = Pacer(self._drain, every_ms, self)
        self._wake.connect(self._pacer.request, Qt.ConnectionType.QueuedConnection)

    def post(self, item: Any) -> None:
        with self._lock:
            if self._closed:
                return
            self._items.append(item)
            if self._pending:
                return
            self._pending = True
        try:
            self._wake.emit()
        except RuntimeError:          # the inbox's Qt object is gone (its window closed meanwhile)
            pass

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._items = []

    @Slot()
    def _drain(self) -> None:
        with self._lock:
            items, self._items = self._items, []
            self._pending = False
        if items:
            self._handler(items)      # an exception goes to sys.excepthook (the crash dialog), as in any slot


class JobRunner(QObject):
    """Runs one job at a time off the GUI thread.

    ``started()`` is emitted by :meth:`start` itself (on the caller's thread, before the job runs).
    Signals arrive on the GUI thread: ``progress(done, total, message, eta_s or -1)``, then exactly
    one of ``finished(result)``, ``failed(message)`` or ``cancelled()``.
    """

    started = Signal()
    progress = Signal(int, int, str, float)
    finished = Signal(object)
    failed = Signal(str)
    cancelled = Signal()

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self._thread: threading.Thread | None = None
        self._cancel: CancelToken | None = None
        self._active = False    # False before the final signal is emitted: its slots see "not running"
        self._job = 0           # which start() the reports belong to
        self._inbox = GuiInbox(self._deliver, self)

    @property
    def running(self) -> bool:
        return self._active and self._thread is not None and self._thread.is_alive()

    def start(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Call ``fn(*args, progress=..., cancel=..., **kwargs)`` on a new thread."""
        if self.running:
            raise RuntimeError("a job is already running")
        cancel = CancelToken()
        eta = EtaEstimator()
        self._cancel = cancel
        self._job += 1
        job = self._job
        post = self._inbox.post

        def progress(done: int, total: int, message: str = "") -> None:
            left = eta.update(done, total)
            post((job, "progress", (int(done), int(total), str(message), -1.0 if left is None else float(left))))

        def body() -> None:
            try:
                result = fn(*args, progress=progress, cancel=cancel, **kwargs)
            except Cancelled:
                post((job, "cancelled", ()))
            except LfError as exc:
                post((job, "failed", (window_message(exc),)))
            except Exception as exc:  # an unexpected bug: say so plainly, keep the details in the log
                log.error("job %s failed unexpectedly", getattr(fn, "__name__", fn), exc_info=True)
                post((job, "failed", (f"Unexpected error: {type(exc).__name__}: {exc}",)))
            else:
                post((job, "finished", (result,)))

        self._thread = threading.Thread(target=body, name=f"job-{getattr(fn, '__name__', 'job')}", daemon=True)
        self._active = True
        self.started.emit()
        self._thread.start()

    def _deliver(self, reports: list) -> None:
        for job, kind, args in reports:
            if kind != "progress" and job == self._job:
                self._active = False
            getattr(self, kind).emit(*args)

    def cancel(self) -> None:
        if self._cancel is not None:
            self._cancel.cancel()

    def stop(self, timeout_s: float | None = None) -> bool:
        """Cancel a running job and join its thread (for closing and shutdown); True if it has ended."""
        if self.running:
            self.cancel()
        return self.wait(timeout_s)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Join the worker thread (for shutdown); True if it has ended."""
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()


def run_off_gui(parent: QObject, fn: Callable[[], Any], on_result: Callable[[Any], None],
                on_error: Callable[[str], None] | None = None) -> JobRunner:
    """``fn()`` (no progress, no cancel) on a worker thread; ``on_result(value)`` or
    ``on_error(message)`` on the GUI thread. The runner lives as long as ``parent``."""
    runner = JobRunner(parent)
    runner.finished.connect(on_result)
    if on_error is not None:
        runner.failed.connect(on_error)
    runner.start(lambda progress, cancel: fn())
    return runner
