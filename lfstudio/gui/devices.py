"""Qt adapter over :class:`lfstudio.rig.worker.DeviceWorker`: device calls and snapshots as signals.

Every signal is delivered on the GUI thread (queued), so slots may touch widgets::

    device = QtDevice(DeviceWorker(controller, name="rig"))
    device.statusChanged.connect(panel.show_status)
    device.errorOccurred.connect(panel.show_error)
    device.run("move_to", 10.0, 5.0, on_result=lambda status: ..., on_error=lambda text: ...)
    device.stop_now()          # bypasses the queue; the driver's stop runs on a thread of its own
"""

from __future__ import annotations

import logging
import threading
import traceback
from concurrent.futures import CancelledError, Future
from typing import Any, Callable

from PySide6.QtCore import QObject, Signal

from lfstudio.errors import LfError, window_message
from lfstudio.gui.bridge import GuiInbox
from lfstudio.rig.worker import DeviceWorker, DeviceFault

log = logging.getLogger(__name__)


def error_text(exc: BaseException) -> str:
    """The message an operator reads for an exception from a device call."""
    if isinstance(exc, LfError):
        return window_message(exc)
    if isinstance(exc, CancelledError):
        return "cancelled"
    # the traceback goes to the log file (where a bug report finds it), never to the terminal's stderr
    log.error("unexpected error from a device call:\n%s", "".join(traceback.format_exception(exc)))
    return f"Unexpected error: {type(exc).__name__}: {exc}"


class QtDevice(QObject):
    """Signals (all on the GUI thread):

    - ``statusChanged(snapshot)``: the driver's status (rate-bounded by the worker)
    - ``faultOccurred(str)``: the status call itself failed (e.g. connection lost)
    - ``callStarted(str)`` / ``callFinished(str, result)`` / ``callFailed(str, message)``
    - ``errorOccurred(str)``: any call failed (operator message)
    - ``busyChanged(bool)``: calls are running or queued
    """

    statusChanged = Signal(object)
    faultOccurred = Signal(str)
    callStarted = Signal(str)
    callFinished = Signal(str, object)
    callFailed = Signal(str, str)
    errorOccurred = Signal(str)
    busyChanged = Signal(bool)

    def __init__(self, worker: DeviceWorker, parent: QObject | None = None):
        super().__init__(parent)
        self.worker = worker
        self._pending = 0
        self._closed = False
        self._inbox = GuiInbox(self._run_delivered, self)     # zero-argument callables to run on the GUI thread
        self._unsubscribe = worker.subscribe(self._on_snapshot)

    @property
    def name(self) -> str:
        return self.worker.name

    @property
    def driver(self) -> Any:
        return self.worker.driver

    @property
    def latest(self) -> Any:
        return self.worker.latest

    # -- worker thread -> GUI thread ---------------------------------------------------------------
    def _post(self, fn: Callable[[], None]) -> None:
        if not self._closed:
            self._inbox.post(fn)

    def _run_delivered(self, fns: list[Callable[[], None]]) -> None:
        for fn in fns:
            try:
                fn()
            except Exception:
                log.exception("%s: GUI callback failed", self.name)

    def _on_snapshot(self, snapshot: Any) -> None:
        def deliver() -> None:
            if self._closed:         # posted before close(): a closed device's status is no one's news
                return
            if isinstance(snapshot, DeviceFault):
                self.faultOccurred.emit(snapshot.message)
            self.statusChanged.emit(snapshot)
        self._post(deliver)

    # -- calls -------------------------------------------------------------------------------------
    def run(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
            on_result: Callable[[Any], object] | None = None, on_error: Callable[[str], object] | None = None,
            **kwargs: Any) -> Future:
        """Submit a driver call; its result/error arrive as signals (and the optional callbacks)
        on the GUI thread (what a callback returns is not used). Returns the Future (do not block on it
        from the GUI thread)."""
        name = fn_or_name if isinstance(fn_or_name, str) else getattr(fn_or_name, "__name__", "call")
        future = self.worker.submit(fn_or_name, *args, timeout_s=timeout_s, **kwargs)
        self._pending += 1
        if self._pending == 1:
            self.busyChanged.emit(True)
        self.callStarted.emit(name)

        def done(fut: Future) -> None:
            try:
                result = fut.result()
            except BaseException as exc:  # noqa: BLE001
                message = error_text(exc)

                def failed() -> None:
                    self._call_done()
                    self.callFailed.emit(name, message)
                    self.errorOccurred.emit(message)
                    if on_error is not None:
                        on_error(message)
                self._post(failed)
            else:
                def finished() -> None:
                    self._call_done()
                    self.callFinished.emit(name, result)
                    if on_result is not None:
                        on_result(result)
                self._post(finished)

        future.add_done_callback(done)
        return future

    def _call_done(self) -> None:
        self._pending = max(0, self._pending - 1)
        if self._pending == 0:
            self.busyChanged.emit(False)

    @property
    def busy(self) -> bool:
        return self._pending > 0

    def stop_now(self) -> None:
        """STOP: queued calls fail and the holder is told here, at once; the driver's stop() is
        dispatched on a thread of its own (:meth:`DeviceWorker.stop_soon`), so the GUI thread never
        waits on it, a stalled link included. A failure arrives as ``errorOccurred``."""
        try:
            future = self.worker.stop_soon()
        except Exception as exc:  # noqa: BLE001 - show it, the operator must know STOP failed
            self.errorOccurred.emit(f"STOP failed: {error_text(exc)}")
            return

        def done(fut: Future) -> None:
            exc = fut.exception()
            if exc is not None:
                message = f"STOP failed: {error_text(exc)}"
                self._post(lambda: self.errorOccurred.emit(message))
        future.add_done_callback(done)

    def close(self, disconnect: bool = True, timeout_s: float = 2.0, then: Callable[[], None] | None = None) -> None:
        """Fail queued calls, disconnect last, end the thread: never waiting on the calling (GUI)
        thread. A thread of its own closes the worker, then runs ``then()`` (e.g. the port's lock
        released) once the driver is disconnected: after a driver call still under way (a long move, a
        stalled link, bounded by the driver's own deadlines), however long past ``timeout_s`` that is,
        so the port is never released while this process may still talk on it.
        :func:`wait_for_closing` waits for these (the application, once its window is gone)."""
        if self._closed:
            return
        self._closed = True          # nothing more is posted to the GUI thread from now on
        self._unsubscribe()
        worker = self.worker

        def finish() -> None:
            try:
                worker.close(disconnect=disconnect, timeout_s=timeout_s)
                if not worker.wait_ended(0):
                    log.info("%s: closing after %s ends", worker.name, worker.current_command or "its call")
                    worker.wait_ended()     # the call, then the disconnect: only then is the port free
            finally:
                if then is not None:
                    try:
                        then()
                    except Exception:  # noqa: BLE001 - logged: nobody waits for this thread
                        log.exception("%s: closing", worker.name)

        thread = threading.Thread(target=finish, name=f"close-{worker.name}", daemon=True)
        with _closing_lock:                 # started before it is listed: wait_for_closing may join it at once
            thread.start()
            _closing[:] = [t for t in _closing if t.is_alive()] + [thread]


_closing: list[threading.Thread] = []          # QtDevice.close()'s threads
_closing_lock = threading.Lock()


def wait_for_closing(timeout_s: float = 10.0) -> bool:
    """Wait (at most ``timeout_s`` in all) until every device closed by :meth:`QtDevice.close` has
    ended its worker and run its ``then``; True when all have. For the application's exit, after its
    window is gone (never from a slot)."""
    import time

    end = time.monotonic() + timeout_s
    with _closing_lock:
        threads = list(_closing)
    for t in threads:
        t.join(max(0.0, end - time.monotonic()))
    return not any(t.is_alive() for t in threads)
