"""Detect GUI-thread stalls and say where they came from.

:class:`Heartbeat` is a timer that should fire every ``interval_ms``; how late each tick comes is a
stall of the GUI thread (``max_stall_ms``, ``stalls``). With ``watch=True`` it is also a watchdog:

- a sampler thread looks at the GUI thread every ``sample_ms`` while a tick is overdue and records
  its Python stack (``sys._current_frames``), so a stall is reported with the code that ran;
- with ``events=True`` also an application-wide event filter notes which Qt event was being
  delivered to which object, for stalls spent in Qt's own C++ code (painting, layout), where the
  Python stack shows only the event loop. It runs Python for every event (so it takes the GIL for
  each), which itself slows a busy GUI: use it to find a source, not to measure.

Each stall longer than ``warn_ms`` becomes a :class:`Stall` (logged as a warning) with ``where``: the
innermost lfstudio frames seen most often during it, else the Qt event, ``others``: the other
threads seen not waiting meanwhile (who competes for the GIL), and ``queued_ms``: how long the GUI
thread was ready to run but had no core (Linux ``schedstat``; a busy computer, not our code). With ``record`` every tick is
kept (:class:`Tick`): its stall, the GUI thread's own CPU since the previous tick, and, for finding a
burst of GUI work, the event that used most of that CPU (``events``: the tap charges the CPU between
two event starts to the earlier event; after stop() ``delivered`` counts them by kind and receiver)
and the garbage collections meanwhile (``gc_watch``:
``gc.callbacks`` time each collection, per generation and thread). The sampler needs the GIL to
look; the application sets a short switch interval (``gui/app.py``), so it gets it within a
millisecond or two even while the GUI thread runs Python code.

One stall source no code change removes: Python's cyclic garbage collector. A full collection walks
every tracked object, ~60 ms of GUI-thread CPU with the window and a 2121-view dataset open, at a
moment no one chooses (often while a dataset opens). :func:`keep_out_of_gc` moves the objects that
live long (the window, an opened dataset) out of its reach (``gc.freeze``); they are still freed by
reference counting when dropped (a dataset holds no reference cycles).

The application runs a watchdog all the time (:func:`install_watchdog`): stalls over 50 ms go to the
log file with their source. The event tap and the garbage-collection watch are diagnostics
(``gui/diagnostics.py``), imported only when ``events`` or ``gc_watch`` asks for them. ``LFSTUDIO_WATCHDOG=1`` adds the Qt event tap and logs them as warnings;
``benchmarks/grid_gui.py`` prints the worst stalls of a scan with their sources.
"""

from __future__ import annotations

import collections
import gc
import logging
import os
import sys
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from PySide6.QtCore import QCoreApplication, QObject, QTimer

if TYPE_CHECKING:       # loaded only when asked for (events, gc_watch)
    from lfstudio.gui.diagnostics import EventTap, GcWatch

log = logging.getLogger(__name__)

ENV_VAR = "LFSTUDIO_WATCHDOG"
_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))   # .../lfstudio
_THIS_FILE = os.path.abspath(__file__)


@dataclass(frozen=True)
class Stall:
    """One late heartbeat: ``duration_ms`` beyond the interval, ending ``at_s`` after start()."""

    at_s: float
    duration_ms: float
    cpu_ms: float       # CPU time the GUI thread itself used meanwhile (the rest: waiting for the GIL or a core)
    where: str          # the code (innermost lfstudio frames) or the Qt event the GUI thread was in
    samples: int        # how many stack samples the watchdog took during the stall (0: not watched)
    gc_ms: float = 0.0  # with gc_watch: garbage collection meanwhile (any thread: each holds the GIL)
    event: str = ""     # with events: the Qt event that used most of the GUI thread's CPU meanwhile
    others: str = ""    # the other threads seen most often not waiting meanwhile (GIL or core competitors)
    queued_ms: float = 0.0   # how long the GUI thread was ready to run but waited for a core (Linux)

    def __str__(self) -> str:
        extra = f", waited for a core {self.queued_ms:.0f} ms" if self.queued_ms >= 1 else ""
        extra += f", garbage collection {self.gc_ms:.0f} ms" if self.gc_ms >= 1 else ""
        text = (f"{self.duration_ms:.0f} ms (GUI thread CPU {self.cpu_ms:.0f} ms{extra}) at {self.at_s:.2f} s "
                f"in {self.where}")
        text += f"; costliest event: {self.event}" if self.event else ""
        return text + (f"; other threads busy: {self.others}" if self.others else "")


def _where(frame) -> str:
    """Where ``frame``'s thread is: its innermost frames that belong to lfstudio (up to three,
    innermost first), or, when none does, its three innermost frames."""
    ours: list[str] = []
    innermost: list[str] = []
    f = frame
    while f is not None and len(ours) < 3:
        code = f.f_code
        path = os.path.abspath(code.co_filename)
        if len(innermost) < 3:
            innermost.append(f"{os.path.basename(path)}:{f.f_lineno} {code.co_name}" if not innermost
                             else code.co_name)
        if path.startswith(_PACKAGE_DIR) and path != _THIS_FILE:
            rel = os.path.relpath(path, os.path.dirname(_PACKAGE_DIR))
            ours.append(f"{rel}:{f.f_lineno} {code.co_name}" if not ours else f"{code.co_name}")
        f = f.f_back
    return " ← ".join(ours or innermost) or "?"


def _open_run_delay() -> int | None:
    """A descriptor of the calling thread's ``schedstat`` (Linux), or None."""
    try:
        return os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    except (OSError, AttributeError):
        return None


def _run_delay_s(fd: int | None) -> float:
    """Seconds the thread of ``fd`` has spent ready to run but waiting for a core (0 without one)."""
    if fd is None:
        return 0.0
    try:
        return int(os.pread(fd, 128, 0).split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return 0.0


#: innermost functions of a thread that waits (for a lock, a queue, a pipe, a timer)
_WAITING = frozenset({"wait", "wait_for", "acquire", "get", "select", "poll", "recv", "_recv", "_recv_bytes",
                      "recv_bytes", "accept", "_wait_for_tstate_lock", "join", "sleep", "_poll",
                      # an idle concurrent.futures pool thread (its work's frame is innermost while it
                      # works); a thread blocked reading a pipe or socket (e.g. pytest-xdist's)
                      "_worker", "read", "readline", "readinto"})


def _busy_threads(frames: dict, skip: tuple[int, ...]) -> list[str]:
    """``name: where`` of each thread in ``frames`` (``sys._current_frames()``) whose innermost
    Python frame is not a wait: who may hold the GIL or a core while the GUI thread is late. (A
    thread blocked in C code called from Python looks busy too: a hint, not a proof.)"""
    names = {t.ident: t.name for t in threading.enumerate()}
    busy = []
    for ident, frame in frames.items():
        if ident in skip or frame.f_code.co_name in _WAITING:
            continue
        busy.append(f"{names.get(ident, ident)}: {_where(frame)}")
    return busy


class Tick(NamedTuple):
    """One heartbeat tick (recorded with ``record``): ``at_s`` after start(), how late it came
    (``stall_ms``), the GUI thread's CPU since the previous tick (``cpu_ms``), the part of it spent in
    garbage collection (``gc_ms``, with ``gc_watch``; ``gc_other_ms``: collections in other threads,
    which hold the GIL meanwhile), the event that used most of it (with ``events``:
    ``event_cpu_ms`` and ``event``), and how long it was ready to run but waited for a core
    (``queued_ms``: the rest of a stall is waiting for the GIL or a lock)."""

    at_s: float
    stall_ms: float
    cpu_ms: float
    gc_ms: float = 0.0
    gc_other_ms: float = 0.0
    event_cpu_ms: float = 0.0
    event: str = ""
    queued_ms: float = 0.0      # of the interval, how long the GUI thread waited for a core (Linux)


class Heartbeat(QObject):
    """Records the longest gap between timer ticks beyond the interval (``max_stall_ms``) and every
    stall over ``warn_ms`` (``stalls``, each a :class:`Stall`; with ``watch`` they say where)."""

    def __init__(self, interval_ms: int = 10, warn_ms: float = 50.0, watch: bool = False, events: bool = False,
                 sample_ms: float = 2.0, record: bool = False, log_level: int = logging.WARNING,
                 gc_watch: bool = False, parent: QObject | None = None):
        super().__init__(parent)
        self.interval_ms = interval_ms
        self.warn_ms = warn_ms
        self.watch = watch
        self.events = events
        self.log_level = log_level
        self.sample_ms = sample_ms
        self.max_stall_ms = 0.0
        self.max_cpu_ms = 0.0       # most CPU time the GUI thread used between two ticks (load-independent)
        self.cpu_ms = 0.0           # CPU time of the GUI thread from start() to the last tick
        self.ticks = 0
        self.stalls: list[Stall] = []
        self.record = record
        self.tick_log: list[Tick] = []     # with ``record``: every tick
        self.gc_watch = gc_watch
        self.gc: GcWatch | None = None     # with ``gc_watch``: the garbage collections since start()
        self._started = 0.0
        self._last: float | None = None
        self._started_cpu = self._last_cpu = 0.0
        self._run_delay_fd: int | None = None
        self._last_queued = 0.0
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self._tick)
        self._lock = threading.Lock()
        self._samples: list[str] = []
        self._others: list[str] = []     # other threads seen busy meanwhile (see _busy_threads)
        self._sampler: threading.Thread | None = None
        self._stop_sampling = threading.Event()
        self._gui_ident = threading.get_ident()
        self._tap: EventTap | None = None
        self.on_sample = None       # called (from the sampler thread) after each sample; for tests
        self.delivered: list[tuple[str, int]] = []   # with ``events``, after stop(): the events delivered most

    def start(self) -> None:
        self._gui_ident = threading.get_ident()
        self._started = self._last = time.perf_counter()
        self._started_cpu = self._last_cpu = time.thread_time()
        if self._run_delay_fd is None:
            self._run_delay_fd = _open_run_delay()      # (opened on the GUI thread: its own schedstat)
        self._last_queued = _run_delay_s(self._run_delay_fd)
        if self.gc_watch and self.gc is None:
            from lfstudio.gui.diagnostics import GcWatch
            self.gc = GcWatch(self._gui_ident, self._started)
            gc.callbacks.append(self.gc)
        self._timer.start()
        if self.watch and self._sampler is None:
            app = QCoreApplication.instance()
            if app is not None and self.events:
                from lfstudio.gui.diagnostics import EventTap
                self._tap = EventTap()
                app.installEventFilter(self._tap)
            self._stop_sampling.clear()
            self._sampler = threading.Thread(target=self._sample_loop, name="gui-watchdog", daemon=True)
            self._sampler.start()

    def stop(self) -> None:
        self._timer.stop()
        if self._run_delay_fd is not None:
            os.close(self._run_delay_fd)
            self._run_delay_fd = None
        if self.gc is not None and self.gc in gc.callbacks:
            gc.callbacks.remove(self.gc)
        if self._sampler is not None:
            self._stop_sampling.set()
            self._sampler.join(2)
            self._sampler = None
        if self._tap is not None:
            app = QCoreApplication.instance()
            if app is not None:
                app.removeEventFilter(self._tap)
            self.delivered = self._tap.most_delivered(50)
            self._tap = None

    def worst(self, n: int = 3) -> list[Stall]:
        return sorted(self.stalls, key=lambda s: -s.duration_ms)[:n]

    # -- the GUI thread ------------------------------------------------------------------------------
    def _tick(self) -> None:
        if self._last is None:          # not started: no tick to measure from (the timer runs after start())
            return
        now, now_cpu, queued = time.perf_counter(), time.thread_time(), _run_delay_s(self._run_delay_fd)
        stall_ms = (now - self._last) * 1000.0 - self.interval_ms
        cpu_ms = (now_cpu - self._last_cpu) * 1000.0
        queued_ms = (queued - self._last_queued) * 1000.0
        self._last, self._last_cpu, self._last_queued = now, now_cpu, queued
        self.ticks += 1
        self.cpu_ms = (now_cpu - self._started_cpu) * 1000.0
        self.max_cpu_ms = max(self.max_cpu_ms, cpu_ms)
        with self._lock:
            samples, self._samples = self._samples, []
            others, self._others = self._others, []
        gc_ms = gc_other_ms = 0.0
        if self.gc is not None:
            gc_ms, gc_other_ms, self.gc.gui_ms, self.gc.other_ms = self.gc.gui_ms, self.gc.other_ms, 0.0, 0.0
        event_cpu_ms, event = self._tap.take_costliest() if self._tap is not None else (0.0, "")
        if self.record:
            self.tick_log.append(Tick(now - self._started, stall_ms, cpu_ms, gc_ms, gc_other_ms, event_cpu_ms, event,
                                      queued_ms))
        if stall_ms > self.max_stall_ms:
            self.max_stall_ms = stall_ms
        if stall_ms > self.warn_ms:
            if samples:
                where, _ = collections.Counter(samples).most_common(1)[0]
            else:
                where = "not watched" if not self.watch else "no sample (the watchdog did not get to run)"
            stall = Stall(at_s=now - self._started, duration_ms=stall_ms, cpu_ms=cpu_ms, where=where,
                          samples=len(samples), gc_ms=gc_ms + gc_other_ms,
                          event=f"{event} ({event_cpu_ms:.0f} ms CPU)" if event else "",
                          others="; ".join(f"{text} ×{n}" for text, n in collections.Counter(others).most_common(3)),
                          queued_ms=queued_ms)
            self.stalls.append(stall)
            log.log(self.log_level, "GUI thread stalled: %s", stall)

    # -- the sampler thread --------------------------------------------------------------------------
    def _sample_loop(self) -> None:
        period_s = self.sample_ms / 1000.0
        overdue_s = (self.interval_ms + min(self.warn_ms, 20.0) / 2) / 1000.0
        wait_s = period_s
        while not self._stop_sampling.wait(wait_s):
            last = self._last
            late_s = time.perf_counter() - last if last is not None else 0.0
            if last is None or late_s < overdue_s:     # sleep until this tick would be overdue
                wait_s = max(period_s, overdue_s - late_s)
                continue
            wait_s = period_s
            frames = sys._current_frames()
            frame = frames.get(self._gui_ident)
            where = _where(frame) if frame is not None else "?"
            event = self._tap.describe_current() if self._tap is not None else None
            if event is not None:
                where = f"{where} [{event}]"
            others = _busy_threads(frames, (self._gui_ident, threading.get_ident()))
            del frame, frames
            with self._lock:
                if self._last == last:      # still the same overdue tick
                    self._samples.append(where)
                    self._others.extend(others)
            hook = self.on_sample
            if hook is not None:
                hook(where)


def install_watchdog(parent: QObject) -> Heartbeat:
    """The application's watchdog: every GUI stall over 50 ms goes to the log with its source (the
    log file; the console too with ``--debug``). ``LFSTUDIO_WATCHDOG=1`` (or a threshold in ms, e.g.
    ``=30``) also names the Qt event of each stall and logs them as warnings: for finding a source."""
    value = os.environ.get(ENV_VAR, "").strip()
    diagnose = value not in ("", "0")
    try:
        warn_ms = float(value) if diagnose and value != "1" else 50.0
    except ValueError:
        warn_ms = 50.0
    heart = Heartbeat(interval_ms=20, warn_ms=warn_ms, watch=True, events=diagnose,
                      log_level=logging.WARNING if diagnose else logging.INFO, parent=parent)
    heart.start()
    app = QCoreApplication.instance()
    if app is not None:
        app.aboutToQuit.connect(heart.stop)
    if diagnose:
        log.warning("GUI watchdog: stalls over %.0f ms are logged with their source and Qt event", warn_ms)
    return heart


def keep_out_of_gc() -> None:
    """Freeze every object alive now out of the cyclic garbage collector's full collections (see the
    module docstring). Young garbage is collected first (cheap), so little of it is kept for good."""
    gc.collect(1)
    gc.freeze()
