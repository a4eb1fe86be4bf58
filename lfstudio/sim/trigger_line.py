"""A digital line between two simulated devices: the GRBL simulator's spindle output (laser mode)
wired to the simulated camera's trigger input, as a fly scan's hardware trigger is wired.

The line keeps its edges as ``(time.monotonic(), level)``; the driving device sets it when its
simulated motion crosses the point where the level changes (the time of that crossing, not of when
its thread got to run), the receiving device waits for rising edges.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class TriggerLine:
    """Edges of one digital line. ``poke``: called while waiting, so a device that advances its
    simulation lazily (on questions) gets to record edges that are due."""

    def __init__(self, name: str = "line") -> None:
        self.name = name
        self.level = False
        self._edges: list[tuple[float, bool]] = []
        self._cond = threading.Condition()
        self.poke: Callable[[], object] | None = None

    def set(self, level: bool, t: float) -> None:
        """The line goes to ``level`` at monotonic time ``t`` (nothing when it is there already)."""
        with self._cond:
            if bool(level) == self.level:
                return
            self.level = bool(level)
            self._edges.append((float(t), bool(level)))
            del self._edges[:-100_000]
            self._cond.notify_all()

    def edges(self, after_s: float = -1.0) -> list[tuple[float, bool]]:
        with self._cond:
            return [e for e in self._edges if e[0] > after_s]

    def rising(self, after_s: float = -1.0) -> list[float]:
        """Times of the rising edges after ``after_s``."""
        return [t for t, level in self.edges(after_s) if level]

    def wait_rising(self, after_s: float, index: int, timeout_s: float,
                    cancelled: Callable[[], bool] = lambda: False) -> float | None:
        """The time of the ``index``-th (0-based) rising edge after ``after_s``; None on timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            poke = self.poke
            if poke is not None:
                poke()
            with self._cond:
                ups = [t for t, level in self._edges if level and t > after_s]
                if len(ups) > index:
                    return ups[index]
                left = deadline - time.monotonic()
                if left <= 0 or cancelled():
                    return None
                self._cond.wait(min(left, 0.01))


__all__ = ["TriggerLine"]
