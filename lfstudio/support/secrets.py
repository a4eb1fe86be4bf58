"""Secrets an operator gives (a notification URL with its password or webhook path, the status page's
token, an SMTP password), redacted once, where the options are read.

A :class:`Secret` carries the value and its redacted form: ``str()``, ``repr()`` and f-strings give
the redacted form, so a secret passed through a message, a log line, a printed command or a lock file
shows as ``https://hooks.example.com/…`` or ``…``; only :meth:`Secret.reveal` gives the value, and
only the code that uses it (the notifier sending, the status page comparing a token) calls it.

:func:`set_command_line` records the command line as it may be shown (its secret values redacted);
the lock files' holder lines (:func:`lfstudio.support.locks.this_command`) write that, never
``sys.argv``. :func:`scrub` removes every secret value known to this process from a text: the log
file's last line of defence (:class:`ScrubFilter`).
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Iterable

_known: set[str] = set()
_known_lock = threading.Lock()
_command_line: list[str] | None = None
#: a secret shorter than this is not scrubbed from texts (it would hit ordinary words)
MIN_SCRUBBED_CHARS = 6


class Secret:
    """A secret value; ``str()`` and ``repr()`` give ``shown`` (see the module docstring)."""

    __slots__ = ("_value", "shown")

    def __init__(self, value: str, shown: str = "…"):
        self._value = str(value)
        self.shown = shown
        if len(self._value) >= MIN_SCRUBBED_CHARS:
            with _known_lock:
                _known.add(self._value)

    def reveal(self) -> str:
        """The value itself: for the one place that uses it, never for a message or a log."""
        return self._value

    def __str__(self) -> str:
        return self.shown

    def __repr__(self) -> str:
        return f"Secret({self.shown!r})"

    def __format__(self, spec: str) -> str:
        return format(self.shown, spec)

    def __bool__(self) -> bool:
        return bool(self._value)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Secret) and other._value == self._value

    def __hash__(self) -> int:
        return hash(("Secret", self._value))

    def __reduce__(self) -> Any:          # pickled (a job sent to another process) as a Secret still
        return (Secret, (self._value, self.shown))


def reveal(value: "Secret | str") -> str:
    """The value of a :class:`Secret`, or ``value`` itself when it is a plain text."""
    return value.reveal() if isinstance(value, Secret) else str(value)


def scrub(text: str) -> str:
    """``text`` with every secret value this process knows replaced by ``…``."""
    with _known_lock:
        known = sorted(_known, key=len, reverse=True)
    for value in known:
        if value in text:
            text = text.replace(value, "…")
    return text


def set_command_line(words: Iterable[str]) -> None:
    """The command line of this process as it may be shown (secret values already redacted)."""
    global _command_line
    _command_line = [str(w) for w in words]


def command_line() -> list[str] | None:
    """What :func:`set_command_line` recorded (None: nothing yet)."""
    return None if _command_line is None else list(_command_line)


class ScrubFilter(logging.Filter):
    """A log handler's filter: the record's message with every known secret value scrubbed."""

    def filter(self, record: logging.LogRecord) -> bool:
        with _known_lock:
            if not _known:
                return True
        message = record.getMessage()
        clean = scrub(message)
        if record.exc_info and record.exc_text is None:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = scrub(record.exc_text)
        if clean != message:
            record.msg, record.args = clean, None
        return True
