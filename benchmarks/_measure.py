"""Measuring on a shared, noisy machine: CPU seconds beside wall seconds, and the load average.

CPU time counts what this process and its finished children computed, so it barely changes when
other programs compete for the cores; wall time does. Every benchmark prints both, plus the load
average, and compares ratios measured in the same invocation rather than absolute figures.
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass


def cpu_s() -> float:
    """CPU seconds (user + system) of this process and of its children that have exited."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def load_text() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} / {five:.2f} / {fifteen:.2f} (1 / 5 / 15 min) on {os.cpu_count()} cores"


@dataclass
class Span:
    """Wall and CPU seconds of a ``with Timer() as span:`` block (filled in when it ends)."""

    wall_s: float = 0.0
    cpu_s: float = 0.0
    load_1min: float = 0.0

    @property
    def cores_used(self) -> float:
        """CPU seconds per wall second: how many cores the block actually got."""
        return self.cpu_s / self.wall_s if self.wall_s > 0 else 0.0


class Timer:
    def __enter__(self) -> Span:
        self.span = Span()
        self._wall, self._cpu = time.perf_counter(), cpu_s()
        return self.span

    def __exit__(self, *exc) -> None:
        self.span.wall_s = time.perf_counter() - self._wall
        self.span.cpu_s = cpu_s() - self._cpu
        self.span.load_1min = os.getloadavg()[0]
