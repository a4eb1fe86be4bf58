"""One generic threaded worker for every device driver (axis controller, camera, ...).

A driver is a plain synchronous object; :class:`DeviceWorker` runs its methods in order on one
thread and hands back :class:`concurrent.futures.Future` objects::

    worker = DeviceWorker(controller, name="rig")
    fut = worker.submit("move_to", 100.0, 20.0, timeout_s=60)   # returns at once
    status = worker.call("status")                               # submit + wait for the result
    worker.subscribe(lambda snapshot: ...)                       # status snapshots, rate-bounded
    worker.stop_now()                                            # driver.stop() on *this* thread
    worker.stop_soon()                                           # ... on a thread of its own (GUI)
    worker.close()

    lease = worker.claim("the scan of studio_day (started 14:02)")   # one owner at a time
    lease.call("move_to", 100.0, 20.0)        # the owner's calls run; everybody else's are refused
    lease.release()

Contract:

- Calls run one at a time, in submission order, on the worker thread.
- ``timeout_s``: when a call runs longer, its future fails with :class:`CallTimedOut` (a DeviceError) naming the
  command. The driver call itself cannot be interrupted; the queue moves on when it returns.
- ``stop_now()`` calls ``driver.stop()`` on the caller's thread (never queued) and fails every call
  still waiting in the queue ("cancelled by STOP"). ``stop_soon()`` does the same but runs
  ``driver.stop()`` on a thread of its own and returns at once (the window's STOP: the GUI thread
  never waits on a driver, a stalled link included).
- Snapshots: the result of ``driver.<status_method>()``, or ``error_snapshot(message)`` when that
  raises, are passed to subscribers at most ``publish_hz`` times per second. The worker polls
  while idle. While a long call runs, a driver may report fresher snapshots itself by calling the
  ``status_listener`` attribute the worker sets on it (if the driver has such an attribute).
- Subscriber callbacks run on the worker thread and must be quick; the Qt adapter
  (:mod:`lfstudio.gui.devices`) turns them into queued signals.
- Interlock: ``claim(holder)`` gives one owner (a running scan) a :class:`Lease`. While it is held,
  ``submit``/``call`` from anybody else fail with :class:`DeviceBusy`, whose message names the
  holder; calls accepted before the claim still run in order. ``stop_now()`` is never refused: it
  runs, and tells the lease's ``on_stop`` callback (the scan pauses instead of moving on).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import os
import queue
import threading
import time
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

from lfstudio.errors import DeviceError, DeviceTimeout, LfError
from lfstudio.support.listeners import Listeners

log = logging.getLogger(__name__)

Subscriber = Callable[[Any], None]


@runtime_checkable
class RunsOnWorker(Protocol):
    """A device whose driver runs on a thread of its own (:class:`DeviceWorker`): ``driver`` is the
    driver, ``call(name, *args, timeout_s=…)`` runs one of its methods there and waits for the result."""

    @property
    def driver(self) -> Any: ...

    def call(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
             **kwargs: Any) -> Any: ...


def driver_of(device: Any) -> Any:
    """The driver of ``device`` (a :class:`RunsOnWorker`'s), or the device itself when it is a driver."""
    return device.driver if isinstance(device, RunsOnWorker) else device


def caller_of(device: Any, timeout_s: float = 30) -> Callable[[str], Any]:
    """``call(name)``: the driver's method ``name`` run without arguments, through the device's worker
    when it has one (waiting at most ``timeout_s``)."""
    if isinstance(device, RunsOnWorker):
        return lambda name: device.call(name, timeout_s=timeout_s)
    return lambda name: getattr(device, name)()


class CallTimedOut(DeviceTimeout):
    """A call ran longer than its ``timeout_s`` (the driver may still be stuck in it)."""

    kind = "call-timed-out"


class DeviceBusy(DeviceError):
    """A command was refused because another owner (a running scan) holds the device.

    ``holder`` says who, e.g. "the scan of studio_day (started 14:02)"."""

    kind = "device-busy"

    def __init__(self, message: str, holder: str):
        super().__init__(message)
        self.holder = holder


class Lease:
    """The right to command a claimed :class:`DeviceWorker` (see :meth:`DeviceWorker.claim`).

    ``submit``/``call`` work like the worker's; ``release()`` gives the device back (idempotent).
    """

    def __init__(self, worker: "DeviceWorker", holder: str, on_stop: Callable[[], None] | None):
        self.worker = worker
        self.holder = holder
        self.on_stop = on_stop
        self.released = False

    def submit(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
               **kwargs: Any) -> Future:
        return self.worker._submit(fn_or_name, args, kwargs, timeout_s, self)

    def call(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
             **kwargs: Any) -> Any:
        return self.submit(fn_or_name, *args, timeout_s=timeout_s, **kwargs).result()

    def release(self) -> None:
        self.worker._release(self)

    def __enter__(self) -> "Lease":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


@dataclass(frozen=True)
class DeviceFault:
    """The generic snapshot published when a driver's status call fails."""

    device: str
    message: str


@dataclass
class _Call:
    name: str
    fn: Callable[..., Any]
    args: tuple
    kwargs: dict
    future: Future
    timeout_s: float | None


_CLOSE = object()
#: how long the disconnect at :meth:`DeviceWorker.close` waits for each stop still under way
STOPPER_WAIT_S = 10.0


def describe_call(name: str, args: tuple, kwargs: dict) -> str:
    """``move_to(10, 5)`` style text for messages: numbers and words as given, a path by its file name,
    callbacks left out (an operator never reads a Python repr)."""
    parts = [_short(a) for a in args if not callable(a)] + \
        [f"{k}={_short(v)}" for k, v in kwargs.items() if not callable(v)]
    return f"{name}({', '.join(parts)})"


def _short(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, os.PathLike):
        return os.path.basename(os.fspath(value))
    text = repr(value) if isinstance(value, str) else type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."


class DeviceWorker:
    """Runs one driver's calls on one thread; see the module docstring for the contract."""

    def __init__(self, driver: Any, name: str | None = None, status_method: str | None = "status",
                 publish_hz: float = 10.0,
                 error_snapshot: Callable[[str], Any] | None = None,
                 stop_method: str = "stop"):
        if publish_hz <= 0:
            raise ValueError("publish_hz must be positive")
        self.driver = driver
        self.name = name or type(driver).__name__
        self.publish_hz = float(publish_hz)
        self._status_method = status_method
        self._stop_method = stop_method
        self._error_snapshot = error_snapshot or (lambda message: DeviceFault(self.name, message))
        self._queue: queue.Queue = queue.Queue()
        self._subscribers: Listeners[Any] = Listeners(f"{self.name}: snapshot subscriber", log)
        self._publish_lock = threading.Lock()
        self._last_publish = float("-inf")
        self._pending: Any = None
        self._has_pending = False
        self._flush_timer: list | None = None       # a _LATER entry: the held-back snapshot's publication
        self._latest: Any = None
        self._current: str | None = None
        self._closed = False
        self._lease: Lease | None = None
        self._lease_lock = threading.Lock()
        self._stoppers: list[threading.Thread] = []     # stop_soon()'s threads
        self._thread = threading.Thread(target=self._run, name=f"device-{self.name}", daemon=True)
        if hasattr(driver, "status_listener"):
            try:
                driver.status_listener = self._offer
            except AttributeError:  # read-only property: the driver does not want it
                pass
        self._thread.start()

    # -- calls -------------------------------------------------------------------------------------
    def submit(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
               **kwargs: Any) -> Future:
        """Queue ``driver.<name>(*args, **kwargs)`` (or ``fn(*args, **kwargs)``); returns its Future.

        While another owner holds the device (:meth:`claim`), the Future fails with :class:`DeviceBusy`."""
        return self._submit(fn_or_name, args, kwargs, timeout_s, None)

    def _submit(self, fn_or_name: str | Callable[..., Any], args: tuple, kwargs: dict, timeout_s: float | None,
                lease: Lease | None) -> Future:
        if isinstance(fn_or_name, str):
            fn = getattr(self.driver, fn_or_name, None)
            if fn is None or not callable(fn):
                raise AttributeError(f"{self.name}: the driver has no command {fn_or_name!r}")
            name = fn_or_name
        else:
            fn = fn_or_name
            name = getattr(fn, "__name__", "call")
        future: Future = Future()
        with self._lease_lock:            # _closed is set under this lock: no call is queued after _CLOSE
            if self._closed:
                future.set_exception(DeviceError(f"{self.name}: {name} refused: the device connection is closed"))
                return future
            holder = self._lease
            if holder is not None and holder is not lease:
                future.set_exception(DeviceBusy(
                    f"{self.name}: {describe_call(name, args, kwargs)} refused: the {self.name} is in use by "
                    f"{holder.holder}; STOP is always available", holder.holder))
                return future
            if lease is not None and lease.released:
                future.set_exception(DeviceError(f"{self.name}: {name} refused: the lease of {lease.holder} "
                                                 "was released"))
                return future
            self._queue.put(_Call(name, fn, args, kwargs, future, timeout_s))
        return future

    def call(self, fn_or_name: str | Callable[..., Any], *args: Any, timeout_s: float | None = None,
             **kwargs: Any) -> Any:
        """Submit and wait for the result (raises the call's exception)."""
        return self.submit(fn_or_name, *args, timeout_s=timeout_s, **kwargs).result()

    def stop_now(self) -> None:
        """Run ``driver.stop()`` on this thread, bypassing the queue; fail every queued call.

        Never refused, whoever holds the device. The holder's ``on_stop`` is told first, so that it
        knows why its running command is about to fail."""
        stop = self._stop_prologue()
        if stop is not None:
            stop()

    def stop_soon(self) -> Future:
        """STOP for a caller that must never wait (the window's GUI thread): the holder's ``on_stop``
        and the queue are dealt with here, at once, as in :meth:`stop_now`; ``driver.stop()`` runs on
        a thread of its own (it may wait on a stalled link, e.g. a drive's quick stop). Returns a
        Future with stop()'s outcome. :meth:`close` lets it end before the driver is disconnected."""
        future: Future = Future()
        stop = self._stop_prologue()
        if stop is None:
            future.set_result(None)
            return future

        def run() -> None:
            try:
                stop()
            except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
                future.set_exception(exc)
            else:
                future.set_result(None)

        thread = threading.Thread(target=run, name=f"stop-{self.name}", daemon=True)
        with self._lease_lock:              # started before it is listed: close() may join it at once
            thread.start()
            self._stoppers = [t for t in self._stoppers if t.is_alive()] + [thread]
        return future

    def _stop_prologue(self) -> Callable[[], Any] | None:
        """Tell the holder, fail the queued calls; the driver's stop method (None: it has none)."""
        lease = self._lease
        if lease is not None and lease.on_stop is not None:
            try:
                lease.on_stop()
            except Exception:  # the holder's bookkeeping must never keep STOP from running
                log.exception("%s: on_stop of %s failed", self.name, lease.holder)
        self._drop_queued("cancelled by STOP")
        return getattr(self.driver, self._stop_method, None)

    def _disconnect_after_stops(self) -> None:
        """The driver's disconnect, once the stops under way (:meth:`stop_soon`) have ended (each
        waited for at most :data:`STOPPER_WAIT_S`: a stop is bounded by its driver)."""
        with self._lease_lock:
            stoppers = list(self._stoppers)
        for t in stoppers:
            t.join(STOPPER_WAIT_S)
        self.driver.disconnect()

    # -- ownership ---------------------------------------------------------------------------------
    def claim(self, holder: str, on_stop: Callable[[], None] | None = None) -> Lease:
        """Make ``holder`` the only one whose calls run until the lease is released.

        Raises :class:`DeviceBusy` when someone else holds it. ``on_stop`` is called (on the caller
        of :meth:`stop_now`, before the driver stops) when STOP is pressed while the lease is held."""
        with self._lease_lock:
            if self._lease is not None:
                raise DeviceBusy(f"{self.name}: cannot be taken by {holder}: it is in use by "
                                 f"{self._lease.holder}", self._lease.holder)
            if self._closed:
                raise DeviceError(f"{self.name}: cannot be taken by {holder}: the device connection is closed")
            self._lease = Lease(self, holder, on_stop)
            return self._lease

    def _release(self, lease: Lease) -> None:
        with self._lease_lock:
            lease.released = True
            if self._lease is lease:
                self._lease = None

    @property
    def holder(self) -> str | None:
        """Who holds the device (see :meth:`claim`), or None."""
        lease = self._lease
        return None if lease is None else lease.holder

    @property
    def busy(self) -> bool:
        """True while a call runs or waits in the queue."""
        return self._current is not None or not self._queue.empty()

    @property
    def current_command(self) -> str | None:
        return self._current

    @property
    def latest(self) -> Any:
        """The most recent snapshot (published or not), or None."""
        return self._latest

    # -- snapshots ---------------------------------------------------------------------------------
    def subscribe(self, callback: Subscriber) -> Callable[[], None]:
        """Receive snapshots (on the worker thread); returns a function that unsubscribes."""
        return self._subscribers.add(callback)

    def _offer(self, snapshot: Any) -> None:
        """Take a fresh snapshot; publish it now if the rate bound allows, else keep it pending."""
        with self._publish_lock:
            self._latest = snapshot
            self._pending = snapshot
            self._has_pending = True
        self._flush()

    def _flush(self, force: bool = False) -> None:
        with self._publish_lock:
            if not self._has_pending:
                return
            now = time.monotonic()
            wait_s = self._last_publish + 1.0 / self.publish_hz - now
            if not force and wait_s > 0:
                # held back by the rate bound: publish it when the window opens, even if the
                # device thread is busy in a long call by then (a late "no answer" must show)
                if self._flush_timer is None:
                    self._flush_timer = _LATER.call(wait_s, self._timed_flush)
                return
            snapshot = self._pending
            self._has_pending = False
            self._pending = None
            self._last_publish = now
        self._subscribers.notify(snapshot)   # a broken subscriber is logged, the device thread goes on

    def _timed_flush(self) -> None:
        with self._publish_lock:
            self._flush_timer = None
        if not self._closed:
            self._flush()

    def _poll_status(self) -> None:
        if self._status_method is None:
            return
        method = getattr(self.driver, self._status_method, None)
        if method is None:
            return
        try:
            snapshot = method()
        except Exception as exc:
            snapshot = self._error_snapshot(_message(exc))
        self._offer(snapshot)

    # -- thread ------------------------------------------------------------------------------------
    def _run(self) -> None:
        period = 1.0 / self.publish_hz
        next_poll = time.monotonic()
        while True:
            wait = max(0.0, next_poll - time.monotonic())
            try:
                item = self._queue.get(timeout=wait) if wait > 0 else self._queue.get_nowait()
            except queue.Empty:
                item = None
            if item is _CLOSE:
                self._drop_queued("cancelled: the device connection is closed")   # never left waiting
                return
            if item is not None:
                self._execute(item)
                continue
            # idle: poll the status at the publishing rate
            self._poll_status()
            self._flush()
            next_poll = time.monotonic() + period

    def _execute(self, call: _Call) -> None:
        if not call.future.set_running_or_notify_cancel():
            return
        self._current = call.name
        log.debug("%s: %s", self.name, describe_call(call.name, call.args, call.kwargs))
        timer = None
        if call.timeout_s is not None:
            text = describe_call(call.name, call.args, call.kwargs)
            timer = _LATER.call(call.timeout_s, _fail, call.future, CallTimedOut(
                f"{self.name}: no answer to {text} within {call.timeout_s:g} s; "
                f"check the {self.name}'s cable and power, then reconnect"))
        try:
            result = call.fn(*call.args, **call.kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            _fail(call.future, exc)
        else:
            try:
                call.future.set_result(result)
            except InvalidStateError:  # already failed by its timeout
                pass
        finally:
            if timer is not None:
                _LATER.cancel(timer)
            self._current = None
        self._poll_status()
        self._flush()

    def _drop_queued(self, reason: str) -> None:
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            if item is _CLOSE:
                self._queue.put(_CLOSE)
                return
            _fail(item.future, DeviceError(f"{self.name}: {describe_call(item.name, item.args, item.kwargs)} "
                                           f"{reason}"))

    def close(self, disconnect: bool = True, timeout_s: float = 10.0) -> None:
        """Fail queued calls, optionally run ``driver.disconnect()`` last, and end the thread."""
        with self._lease_lock:            # a call queued from now on is refused (see _submit)
            if self._closed:
                return
            self._closed = True
        self._drop_queued("cancelled: the device connection is closing")
        if disconnect and hasattr(self.driver, "disconnect"):
            fut: Future = Future()
            self._queue.put(_Call("disconnect", self._disconnect_after_stops, (), {}, fut, None))
        self._queue.put(_CLOSE)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        with self._publish_lock:
            if self._flush_timer is not None:
                _LATER.cancel(self._flush_timer)
                self._flush_timer = None
        if hasattr(self.driver, "status_listener"):
            try:
                self.driver.status_listener = None
            except AttributeError:
                pass

    def wait_ended(self, timeout_s: float | None = None) -> bool:
        """Wait until the worker's thread has ended (after :meth:`close`: the call under way, then the
        disconnect); False after ``timeout_s``."""
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> "DeviceWorker":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class _Later:
    """Runs ``fn(*args)`` after a delay, on one thread shared by every worker: the calls' timeouts and
    the held-back snapshots. (A ``threading.Timer`` started a thread for each: two or more per view of
    a scan, each start a wait for the GIL.) :meth:`call` returns a handle for :meth:`cancel`; a
    cancelled entry is dropped when its time comes. ``fn`` must be quick (it runs on the shared
    thread): failing a future, publishing a snapshot."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._heap: list[list] = []          # [due (monotonic s), sequence, fn or None, args]
        self._sequence = itertools.count()
        self._thread: threading.Thread | None = None

    def call(self, delay_s: float, fn: Callable[..., Any], *args: Any) -> list:
        entry = [time.monotonic() + delay_s, next(self._sequence), fn, args]
        with self._cond:
            heapq.heappush(self._heap, entry)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._run, name="device-timeouts", daemon=True)
                self._thread.start()
            elif self._heap[0] is entry:      # due before what the thread waits for
                self._cond.notify()
        return entry

    @staticmethod
    def cancel(entry: list) -> None:
        entry[2] = None

    def _run(self) -> None:
        while True:
            with self._cond:
                while True:
                    while self._heap and self._heap[0][2] is None:
                        heapq.heappop(self._heap)          # cancelled
                    now = time.monotonic()
                    if self._heap and self._heap[0][0] <= now:
                        entry = heapq.heappop(self._heap)
                        break
                    self._cond.wait(self._heap[0][0] - now if self._heap else None)
            fn, args = entry[2], entry[3]
            if fn is not None:
                try:
                    fn(*args)
                except Exception:  # a failing callback must not stop the others' timeouts
                    log.exception("device timer callback failed")


_LATER = _Later()


def _fail(future: Future, exc: BaseException) -> None:
    try:
        future.set_exception(exc)
    except InvalidStateError:
        pass


def _message(exc: BaseException) -> str:
    if isinstance(exc, LfError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"
