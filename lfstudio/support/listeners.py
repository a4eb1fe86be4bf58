"""Listeners: the one subscribe-and-notify mechanism of the core's publishers (the scan engine's
events, a device worker's snapshots, the live check's verdicts).

``Listeners(what, log)``: :meth:`add` takes a callable and returns the function that removes it;
:meth:`notify` calls every listener with a value on the caller's thread. Adding and removing are safe
from any thread, also while a notification runs (it calls the listeners there were when it began). A
listener that raises is logged as ``"<what> failed"`` and the others are still called, so a broken
listener never stops the thread that publishes.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Callable, Generic, TypeVar

T = TypeVar("T")


class Listeners(Generic[T]):
    def __init__(self, what: str, log: logging.Logger):
        self._what = what
        self._log = log
        self._items: list[Callable[[T], Any]] = []
        self._lock = threading.Lock()

    def add(self, listener: Callable[[T], Any]) -> Callable[[], None]:
        """Call ``listener(value)`` on each :meth:`notify`; returns a function that stops it."""
        with self._lock:
            self._items.append(listener)

        def remove() -> None:
            with self._lock:
                if listener in self._items:
                    self._items.remove(listener)
        return remove

    def notify(self, value: T) -> None:
        with self._lock:
            items = list(self._items)
        for listener in items:
            try:
                listener(value)
            except Exception:  # noqa: BLE001 - a broken listener must not stop the publisher's thread
                self._log.exception("%s failed", self._what)
