"""Crash safety of a dataset folder: the journal, checksums, free disk space, crash leftovers.

The journal ``journal.jsonl`` holds one line per finished view, appended and fsync'd before the
view counts as captured::

    {"seq": 17, "row": 0, "column": 16, "set": {"status": "done", "file": "raw/r00_c016.dng", ...}}

and, from a checkpoint (``Dataset.checkpoint``), whole views that changed otherwise::

    {"seq": 18, "row": 0, "column": 3, "view": {"row": 0, "column": 3, "status": "failed", ...}}

``seq`` grows by one per line. The manifest records the last sequence number it already contains
(``journal_seq``); opening a dataset replays the lines after it, so a ``kill -9`` between a journal
line and the next manifest save loses nothing. A torn last line (the process died while writing
it) is ignored: its view was not finished. Saving the manifest folds the journal in and empties it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any, Iterator

from lfstudio.dataset.atomic import is_temporary
from lfstudio.dataset.paths import resolve_inside

JOURNAL_NAME = "journal.jsonl"
#: folders of a dataset that hold view files and may hold crash leftovers
DATA_FOLDERS = ("", "raw", "thumbs", "thumbs/generated", "processed")


def _not_a_number(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


def read_journal(path: str | os.PathLike) -> tuple[list[dict[str, Any]], list[str]]:
    """The journal's records in order and the problems found (torn or corrupt lines).

    A torn *last* line is expected after a crash and not reported as a problem.
    """
    path = Path(path)
    if not path.is_file():
        return [], []
    records: list[dict[str, Any]] = []
    problems: list[str] = []
    data = path.read_bytes()
    lines = data.split(b"\n")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        last = i == len(lines) - 1   # no newline after it: the write did not finish
        try:
            rec = json.loads(line.decode("utf-8"), parse_constant=_not_a_number)
            if not (isinstance(rec, dict) and isinstance(rec.get("seq"), int) and isinstance(rec.get("row"), int)
                    and isinstance(rec.get("column"), int)
                    and isinstance(rec.get("set", rec.get("view")), dict)):
                raise ValueError("needs seq, row, column and set (or view)")
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            if isinstance(exc, RecursionError):
                exc = ValueError("nested too deeply to be a journal record")
            if not last:
                problems.append(f"{JOURNAL_NAME}: line {i + 1}: unreadable record ignored ({exc})")
            continue
        if last:
            continue   # complete JSON but no newline: treat as torn too (its fsync never returned)
        records.append(rec)
    return records, problems


class Journal:
    """Append-only, fsync'd journal file. Not thread-safe on its own (the Dataset holds a lock)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fh = None
        self._size: int | None = None

    def size_bytes(self) -> int:
        """The journal's length in bytes (0 when there is none)."""
        if self._size is None:
            try:
                self._size = self.path.stat().st_size
            except FileNotFoundError:
                self._size = 0
        return self._size

    def append(self, record: dict[str, Any]) -> None:
        self.append_many([record])

    def append_many(self, records: list[dict[str, Any]]) -> None:
        """Append ``records`` (one line each) with one write and one fsync: durable when this returns."""
        if self._fh is None:
            self._repair_tail()
            self._fh = open(self.path, "ab", buffering=0)
            self._size = None
        dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
        line = "".join(dumps(r) + "\n" for r in records).encode("utf-8")
        self.size_bytes()
        try:
            rest = memoryview(line)
            while rest:                        # a full disk may take part of the line: the rest raises ENOSPC
                rest = rest[self._fh.write(rest):]
            os.fsync(self._fh.fileno())
        except BaseException:
            self.close()                       # the next append cuts the torn line first (_repair_tail)
            self._size = None
            raise
        self._size = (self._size or 0) + len(line)

    def _repair_tail(self) -> None:
        """Cut a torn last line so the next record starts on a line of its own."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return
        if data and not data.endswith(b"\n"):
            keep = data.rfind(b"\n") + 1
            with open(self.path, "rb+") as fh:
                fh.truncate(keep)
                os.fsync(fh.fileno())

    def clear(self) -> None:
        """Empty the journal (after its records were folded into a saved manifest)."""
        self.close()
        if self.path.exists():
            with open(self.path, "wb") as fh:
                os.fsync(fh.fileno())
        self._size = 0

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def sha256_file(path: str | os.PathLike, chunk_bytes: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            block = fh.read(chunk_bytes)
            if not block:
                break
            h.update(block)
    return h.hexdigest()


def free_bytes(path: str | os.PathLike) -> int:
    """Free space for an unprivileged writer on the file system holding ``path``."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def temporary_files(root: str | os.PathLike, folders: tuple[str, ...] = DATA_FOLDERS) -> Iterator[Path]:
    """Temporary files left by an interrupted atomic write (``.NAME.XXXX.tmpSUFFIX``) in ``folders``."""
    root = Path(root)
    for sub in folders:
        folder = resolve_inside(root, sub, what="folder") if sub else root   # never delete outside it
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            if entry.is_file() and is_temporary(entry):
                yield entry


def clean_temporary_files(root: str | os.PathLike, folders: tuple[str, ...] = DATA_FOLDERS) -> list[Path]:
    """Delete crash leftovers in ``folders`` of the dataset; return what was removed."""
    removed = []
    for p in list(temporary_files(root, folders)):
        try:
            p.unlink()
            removed.append(p)
        except FileNotFoundError:
            pass
    return removed
