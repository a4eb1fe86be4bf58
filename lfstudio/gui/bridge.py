"""Run a core job (``fn(..., progress=, cancel=)``) on a worker thread and report through Qt signals."""

from __future__ import annotations

import logging
import threading
from typing import Any, Callable

from PySide6.QtCore import QObject, Signal

from lfstudio.errors import LfError
from lfstudio.jobs import Cancelled, CancelToken, EtaEstimator

log = logging.getLogger(__name__)


class JobRunner(QObject):
    """Runs one job at a time off the GUI thread.

    ``started()`` is emitted by :meth:`start` itself (on the caller's thread, before the job runs).
    Signals arrive on the GUI thread (queued): ``progress(done, total, message, eta_s or -1)``,
    then exactly one of ``finished(result)``, ``failed(message)`` or ``cancelled()``.
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

        def progress(done: int, total: int, message: str = "") -> None:
            left = eta.update(done, total)
            self.progress.emit(int(done), int(total), str(message), -1.0 if left is None else float(left))

        def body() -> None:
            try:
                result = fn(*args, progress=progress, cancel=cancel, **kwargs)
            except Cancelled:
                self._active = False
                self.cancelled.emit()
            except LfError as exc:
                self._active = False
                self.failed.emit(str(exc))
            except Exception as exc:  # an unexpected bug: say so plainly, keep the details in the log
                log.error("job %s failed unexpectedly", getattr(fn, "__name__", fn), exc_info=True)
                self._active = False
                self.failed.emit(f"Unexpected error: {type(exc).__name__}: {exc}")
            else:
                self._active = False
                self.finished.emit(result)

        self._thread = threading.Thread(target=body, name=f"job-{getattr(fn, '__name__', 'job')}", daemon=True)
        self._active = True
        self.started.emit()
        self._thread.start()

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
