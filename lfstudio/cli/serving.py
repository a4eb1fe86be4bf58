"""What ``lfstudio sim-rig`` and ``lfstudio sim-drive`` share: serve an emulator in the foreground,
print how to reach it, and stop it cleanly on Ctrl-C or SIGTERM."""

from __future__ import annotations

import signal
import sys
import threading
from typing import Any, Callable


def serve_until_stopped(word: str, how_to_connect: str, emulator: Any, truth: Any, what: str,
                        running: Callable[[], bool] = lambda: True) -> int:
    """Print ``word`` (stdout, for scripts) and ``how_to_connect`` (stderr), then wait until Ctrl-C,
    SIGTERM or ``running()`` turns false; close the studio's ``truth`` (if any) and the ``emulator``.
    Exit code 1 when the emulator stopped by itself, else 0."""
    done = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        print(word, flush=True)
        print(how_to_connect, file=sys.stderr, flush=True)
        while not done.wait(0.5):
            if not running():
                print(f"the {what} stopped", file=sys.stderr)
                return 1
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        if truth is not None:
            truth.close()
        emulator.close()
    print(f"{what} stopped", file=sys.stderr)
    return 0
