"""Killing a real ``lfstudio`` process at a chosen point of its journal: the shared half of the
crash tests (``kill -9`` of a scan, then ``--resume``)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.conftest import REPO_ROOT


def journal_lines(root: Path) -> int:
    """How many records the dataset at ``root`` has journaled (0 before the journal exists)."""
    try:
        return (root / "journal.jsonl").read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def lfstudio_env() -> dict:
    """This process's environment with the repository first on ``PYTHONPATH``."""
    return dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def kill_9_after(args: list, out: Path, lines: int, rng: random.Random, *, jitter_s: float,
                 timeout_s: float = 60) -> None:
    """Start ``python -m lfstudio ARGS``, wait until the dataset at ``out`` exists and has
    journaled ``lines`` records (or the process ended), wait a random part of ``jitter_s`` more
    and ``kill -9`` it."""
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", *map(str, args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, env=lfstudio_env(), cwd=REPO_ROOT)
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and time.monotonic() < deadline:
        if (out / "dataset.json").is_file() and journal_lines(out) >= lines:
            break
        time.sleep(0.002)       # polling the journal, not synchronising on a duration
    time.sleep(rng.uniform(0.0, jitter_s))
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    proc.stderr.close()


def gone(pid: int) -> bool:
    """The process ``pid`` has ended (a zombie nobody has reaped yet counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")
