"""Long jobs: plain functions that take a progress callback and a cancel token.

A job looks like ``def run(..., progress: Progress = no_progress, cancel: CancelToken | None = None)``.
It calls ``progress(done, total, message)`` now and then and ``cancel.check()`` at safe points;
``check`` raises :class:`Cancelled`. The GUI bridges this to Qt signals (``lfstudio.gui.bridge``),
the CLI to a terminal progress bar (:class:`TerminalProgress`).
"""

from __future__ import annotations

import shutil
import sys
import threading
import time
from collections import deque
from typing import Callable, Protocol


class Cancelled(Exception):
    """Raised inside a job when its cancel token was set."""


class CancelToken:
    """Thread-safe cancel flag shared by the caller and the job."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise Cancelled()

    def wait(self, timeout_s: float) -> bool:
        """Sleep up to ``timeout_s`` seconds; return True early if cancelled."""
        return self._event.wait(timeout_s)


class Progress(Protocol):
    """``progress(done, total, message)``, called positionally (any names will do)."""

    def __call__(self, done: int, total: int, message: str = "", /) -> None: ...


def no_progress(done: int, total: int, message: str = "") -> None:
    """Progress callback that ignores everything."""


class EtaEstimator:
    """Remaining-time estimate from the rate of recently finished items (the last ``window_s``
    seconds): a job whose steps change cost (hundreds of fast file checks, then a slow measurement)
    is estimated from the steps it is doing now, not from its start. Items may start late (resume)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, window_s: float = 30.0) -> None:
        self._clock = clock
        self.window_s = window_s
        self._points: deque[tuple[float, int]] = deque()     # (time, done), oldest first

    def update(self, done: int, total: int) -> float | None:
        """Return the estimated seconds left, or None while no rate is known yet."""
        now = self._clock()
        points = self._points
        if points and done < points[-1][1]:
            points.clear()                           # counted again from the start: a new job
        points.append((now, done))
        while len(points) > 2 and now - points[1][0] >= self.window_s:
            points.popleft()                         # the window still reaches back window_s
        t0, done0 = points[0]
        finished = done - done0
        if finished <= 0:
            return None
        rate = finished / max(now - t0, 1e-9)
        return max(total - done, 0) / rate


def count(n: int, noun: str, plural: str | None = None) -> str:
    """``count(1, "view")`` -> "1 view", ``count(27, "view")`` -> "27 views" (``plural`` when not noun + s)."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def format_duration(seconds: float | None) -> str:
    """'1 h 02 min', '3 min 05 s', '12 s' or '–' when unknown."""
    if seconds is None:
        return "–"
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600} h {(s % 3600) // 60:02d} min"
    if s >= 60:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s} s"


class TerminalProgress:
    """A one-line progress bar with ETA on stderr (plain lines when stderr is not a terminal)."""

    def __init__(self, label: str, stream=None, width: int = 30) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.width = width
        self.eta = EtaEstimator()
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last_line = 0.0
        self._shown = 0          # characters of the line shown last (a terminal)

    def __call__(self, done: int, total: int, message: str = "") -> None:
        eta = self.eta.update(done, total)
        frac = done / total if total else 1.0
        bar = "#" * int(frac * self.width)
        line = (f"{self.label} [{bar:<{self.width}}] {done}/{total} {frac:6.1%}"
                f"  ETA {format_duration(eta)}  {message}")
        now = time.monotonic()
        if self._tty:   # one terminal line (a longer one wraps, and every update scrolls a new line)
            line = line[:max(20, shutil.get_terminal_size((80, 24)).columns - 1)]
            self.stream.write("\r" + line + " " * max(0, self._shown - len(line)))   # clears a longer last one
            self._shown = len(line)
            if done >= total:
                self.stream.write("\n")
        elif done >= total or now - self._last_line > 2.0:
            self.stream.write(line + "\n")
            self._last_line = now
        self.stream.flush()
