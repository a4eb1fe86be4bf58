"""A shell command run on the operator's behalf (``--on-finish``), kept on a short leash.

:func:`run_contained` runs ``command`` through ``/bin/sh`` in a process group of its own and returns
a :class:`ChildResult` by ``limit_s`` (plus :data:`KILL_GRACE_S` at most), whatever the command does:

- at the time limit its process group **and every process it started** are ended (SIGTERM, then
  SIGKILL after :data:`KILL_GRACE_S`). "Every process" includes those that left the group
  (``setsid``, a double fork): each child gets a marker in its environment (:data:`MARK_ENV`) and, on
  Linux, every process of this user whose environment carries this run's marker is ended too;
- its output (stdout and stderr together) is read as it comes and never held whole: at most
  :data:`KEEP_BYTES` are kept (the start and the end), each line is cut at :data:`MAX_LINE_CHARS`,
  and only the first :data:`HEAD_LINES` and the last :data:`TAIL_LINES` lines are handed to
  ``on_line`` (the log), with one line saying how many were left out, so 1 GB of output costs a few
  hundred kB of memory and a few hundred log lines;
- a command that ends while something it started in the background still holds its output open is
  done when that ends too, or at the time limit (then ended as above).
"""

from __future__ import annotations

import os
import secrets
import select
import signal
import subprocess
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

#: the environment variable that marks every process a run started (its value is unique per run)
MARK_ENV = "LFSTUDIO_CHILD_RUN"
#: after SIGTERM at the time limit, how long before SIGKILL (and then how long to wait for the pipe)
KILL_GRACE_S = 3.0
KEEP_BYTES = 64 * 1024          # output kept in the result: the first and last half of this
MAX_LINE_CHARS = 2000           # a line longer than this is cut (the rest is counted, not kept)
HEAD_LINES = 200                # the first lines handed to on_line ...
TAIL_LINES = 50                 # ... and the last ones, with one line saying how many between were not
READ_BYTES = 65536


@dataclass
class ChildResult:
    returncode: int | None = None
    timed_out: bool = False          # the time limit ended it (or what it left running)
    output: str = ""                 # at most KEEP_BYTES of it: the start and the end
    output_bytes: int = 0            # all it wrote
    lines: int = 0                   # all the lines it wrote
    lines_not_shown: int = 0         # lines not handed to on_line
    killed: int = 0                  # processes ended at the time limit
    error: str = ""                  # could not start


class _Lines:
    """Splits the output into lines with bounded memory; hands the first and last to ``on_line``."""

    def __init__(self, on_line: Callable[[str], None]):
        self.on_line = on_line
        self.partial = bytearray()
        self.partial_cut = False
        self.count = 0
        self.tail: deque[str] = deque(maxlen=TAIL_LINES)
        self.head = bytearray()
        self.end: deque[bytes] = deque()
        self.end_bytes = 0
        self.total = 0

    def feed(self, data: bytes) -> None:
        self.total += len(data)
        if len(self.head) < KEEP_BYTES // 2:
            self.head += data[:KEEP_BYTES // 2 - len(self.head)]
        else:
            self.end.append(data[-KEEP_BYTES // 2:])
            self.end_bytes += len(self.end[-1])
            while self.end_bytes - len(self.end[0]) >= KEEP_BYTES // 2:
                self.end_bytes -= len(self.end.popleft())
        start = 0
        while True:
            nl = data.find(b"\n", start)
            piece = data[start:] if nl < 0 else data[start:nl]
            room = MAX_LINE_CHARS - len(self.partial)
            if room > 0:
                self.partial += piece[:room]
            if len(piece) > room:
                self.partial_cut = True
            if nl < 0:
                return
            self._line()
            start = nl + 1

    def _line(self) -> None:
        text = self.partial.decode(errors="replace").rstrip("\r") + (" …(cut)" if self.partial_cut else "")
        self.partial.clear()
        self.partial_cut = False
        self.count += 1
        if self.count <= HEAD_LINES:
            self.on_line(text)
        else:
            self.tail.append(text)

    def close(self) -> tuple[str, int]:
        if self.partial or self.partial_cut:
            self._line()
        hidden = max(0, self.count - HEAD_LINES - len(self.tail))
        if hidden:
            self.on_line(f"… {hidden} lines not shown ({self.total} bytes of output in all) …")
        for text in self.tail:
            self.on_line(text)
        end = b"".join(self.end)[-KEEP_BYTES // 2:]
        kept = bytes(self.head) + ("\n…\n".encode() if self.total > len(self.head) + len(end) else b"") + end
        return kept.decode(errors="replace"), hidden


def run_contained(command: str, *, limit_s: float, env: Mapping[str, str] | None = None,
                  cwd: str | os.PathLike | None = None,
                  on_line: Callable[[str], None] = lambda text: None) -> ChildResult:
    """Run ``command`` (a shell command line) as the module docstring says."""
    mark = secrets.token_hex(8)
    result = ChildResult()
    try:
        proc = subprocess.Popen(command, shell=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env={**(os.environ if env is None else env), MARK_ENV: mark},
                                start_new_session=True, cwd=str(cwd) if cwd else None)
    except OSError as exc:
        result.error = f"could not start: {exc.strerror or exc}"
        return result
    assert proc.stdout is not None
    pipe = proc.stdout.fileno()
    os.set_blocking(pipe, False)
    lines = _Lines(on_line)
    deadline = time.monotonic() + limit_s
    give_up = None                            # after the kill: the pipe's last chance to close
    try:
        while True:
            now = time.monotonic()
            if give_up is None and now >= deadline:
                result.timed_out = True
                result.killed = end_all(proc.pid, mark)
                give_up = time.monotonic() + KILL_GRACE_S
            if give_up is not None and now >= give_up:
                break                          # something outside our reach holds the pipe: stop reading
            until = give_up if give_up is not None else deadline
            ready, _, _ = select.select([pipe], [], [], max(0.0, min(until - now, 1.0)))
            if not ready:
                continue
            try:
                data = os.read(pipe, READ_BYTES)
            except BlockingIOError:
                continue
            if not data:
                break                          # every writer is gone
            lines.feed(data)
    finally:
        proc.stdout.close()
    # the pipe is closed (or given up): the shell, then anything it left running, until the time limit
    try:
        result.returncode = proc.wait(max(0.0, deadline - time.monotonic()) if give_up is None else KILL_GRACE_S)
    except subprocess.TimeoutExpired:
        pass
    while give_up is None and marked(mark) and time.monotonic() < deadline:
        time.sleep(0.2)                        # background processes it started: theirs is the same limit
    if give_up is None and (result.returncode is None or marked(mark)):
        result.timed_out = True
        result.killed = end_all(proc.pid, mark)
    if result.returncode is None:
        try:
            result.returncode = proc.wait(KILL_GRACE_S)
        except subprocess.TimeoutExpired:      # cannot happen after SIGKILL unless the kernel is stuck
            pass
    result.output, result.lines_not_shown = lines.close()
    result.output_bytes, result.lines = lines.total, lines.count
    return result


def marked(mark: str) -> list[int]:
    """The processes of this user whose environment carries ``MARK_ENV=mark`` (Linux; elsewhere none)."""
    needle = f"{MARK_ENV}={mark}".encode()
    found = []
    proc = Path("/proc")
    if not proc.is_dir():
        return found
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            environ = (entry / "environ").read_bytes()
        except OSError:                   # gone, or another user's
            continue
        if needle in environ.split(b"\0"):
            found.append(int(entry.name))
    return found


def end_all(pid: int, mark: str) -> int:
    """End the process group ``pid`` and every process carrying ``mark``: SIGTERM, then after
    :data:`KILL_GRACE_S` SIGKILL to what is left. The number of processes found running."""
    found = set(marked(mark))

    def signal_all(sig: int) -> None:
        try:
            os.killpg(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        for other in marked(mark):
            try:
                os.kill(other, sig)
            except (ProcessLookupError, PermissionError):
                pass

    signal_all(signal.SIGTERM)
    end = time.monotonic() + KILL_GRACE_S
    while time.monotonic() < end and _alive(pid, mark):
        time.sleep(0.05)
    signal_all(signal.SIGKILL)
    return len(found) or 1


def _alive(pid: int, mark: str) -> bool:
    if Path("/proc").is_dir():            # a zombie (ended, not yet waited for) carries no environment
        return bool(marked(mark))
    try:
        os.killpg(pid, 0)
        return True
    except (ProcessLookupError, PermissionError):
        return False
