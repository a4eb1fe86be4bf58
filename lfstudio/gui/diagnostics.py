"""The GUI watchdog's diagnostics, loaded only when asked for (``LFSTUDIO_WATCHDOG=1``, the
benchmarks): an application-wide Qt event tap (:class:`EventTap`: which event was being delivered to
which object, and which used the most GUI-thread CPU) and a garbage-collection watch (:class:`GcWatch`:
every collection's time, generation and thread). Both cost time of their own (the tap runs Python
for every Qt event, taking the GIL each time), so the always-on watchdog (``gui/heartbeat.py``) does
without them.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass

from PySide6.QtCore import QEvent, QObject


def _event_name(event_type: int) -> str:
    try:
        return QEvent.Type(event_type).name
    except ValueError:
        return f"event {event_type}"


def _describe_receiver(obj: QObject) -> str:
    """``Class 'objectName'``; an unnamed object with the object it belongs to (a QTimer or an inbox
    says whose it is)."""
    try:
        name = obj.objectName()
        text = f"{type(obj).__name__} '{name}'" if name else type(obj).__name__
        parent = obj.parent() if not name else None
        if parent is not None:
            pname = parent.objectName()
            text += f" of {type(parent).__name__}" + (f" '{pname}'" if pname else "")
        return text
    except RuntimeError:            # its C++ object is gone meanwhile
        return "a deleted object"


class EventTap(QObject):
    """Application-wide event filter: remembers the event whose delivery started last, and charges
    the GUI thread's CPU time between two event starts to the earlier one, so each tick interval
    names its costliest event (``take_costliest``). The receiver is described on the GUI thread as
    the event starts (the sampler thread only reads the text)."""

    def __init__(self) -> None:
        super().__init__()
        self.current: tuple[int, str] | None = None      # (event type, receiver)
        self.delivered: collections.Counter = collections.Counter()   # (event type, receiver) -> how many
        self._started_cpu = 0.0
        self._costliest: tuple[float, int, str] | None = None     # (CPU s, event type, receiver)

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:   # noqa: N802 (Qt name)
        now = time.thread_time()
        current = self.current
        if current is not None:
            spent = now - self._started_cpu
            if self._costliest is None or spent > self._costliest[0]:
                self._costliest = (spent, current[0], current[1])
        self.current = (int(event.type()), _describe_receiver(obj))
        self.delivered[self.current] += 1
        self._started_cpu = now
        return False

    def describe_current(self) -> str | None:
        current = self.current
        return None if current is None else _describe_event(*current)

    def most_delivered(self, n: int) -> list[tuple[str, int]]:
        """The ``n`` kinds of event delivered most often since the tap was installed, with their counts."""
        return [(_describe_event(*key), count) for key, count in self.delivered.most_common(n)]

    def take_costliest(self) -> tuple[float, str]:
        """The event that used the most GUI-thread CPU since the last call: (CPU ms, description)."""
        costliest, self._costliest = self._costliest, None
        if costliest is None:
            return 0.0, ""
        return costliest[0] * 1000.0, _describe_event(costliest[1], costliest[2])


def _describe_event(event_type: int, receiver: str) -> str:
    return f"Qt {_event_name(event_type)} → {receiver}"


class GcWatch:
    """Every cyclic garbage collection (``gc.callbacks``): how long it took and in which thread. A
    collection holds the GIL, so it stops the GUI thread wherever it runs; in the GUI thread it also
    counts as the GUI thread's own CPU."""

    def __init__(self, gui_ident: int, started: float) -> None:
        self.gui_ident = gui_ident
        self.started = started
        self.log: list[GcPass] = []      # every collection of 1 ms or longer, and every full one
        self.counts = [0, 0, 0]          # collections per generation
        self.total_ms = [0.0, 0.0, 0.0]
        self.gui_ms = 0.0                # collection time not yet taken by a tick: in the GUI thread,
        self.other_ms = 0.0              # in other threads
        self._t0: float | None = None

    def __call__(self, phase: str, info: dict) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._t0 = now
            return
        if self._t0 is None:
            return
        ms = (now - self._t0) * 1000.0
        self._t0 = None
        gen = int(info.get("generation", 0))
        self.counts[gen] += 1
        self.total_ms[gen] += ms
        on_gui = threading.get_ident() == self.gui_ident
        if on_gui:
            self.gui_ms += ms
        else:
            self.other_ms += ms
        if ms >= 1.0 or gen == 2:
            self.log.append(GcPass(at_s=now - self.started, generation=gen, duration_ms=ms, on_gui_thread=on_gui,
                                   collected=int(info.get("collected", 0))))


@dataclass(frozen=True)
class GcPass:
    """One garbage collection: ``at_s`` after the heartbeat started, ``duration_ms`` of generation
    ``generation`` (2: a full collection), run by the GUI thread or another one."""

    at_s: float
    generation: int
    duration_ms: float
    on_gui_thread: bool
    collected: int
