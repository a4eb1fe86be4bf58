"""Where lfstudio logs, and the one place that sets logging up (CLI and GUI alike).

Every module logs through ``logging.getLogger(__name__)``. :func:`setup_logging` sends

- everything from DEBUG up to a rotating file ``lfstudio.log`` in :func:`log_dir` (device traffic: the
  lines sent to and read from the GRBL controller, every call on a device worker, camera captures;
  INFO: scan, calibration, processing and export milestones);
- WARNING and up to the console (FFmpeg's own log lines only with ``--debug``), or everything with ``--debug``.

The rig's status polling (``?`` and its ``<Idle|...>`` reports, several a second) goes to the
``lfstudio.rig.grbl.status`` logger, which only ``--debug`` lets through, so the file keeps weeks of
commands rather than hours of polls.

Third-party libraries (pymodbus, python-can, canopen, PIL, matplotlib, urllib3, asyncio, dask ...) log
only WARNING and up, with or without ``--debug``: pymodbus alone wrote about 18 000 DEBUG lines per
simulated-drive view (every Modbus telegram), so the file rotated every minute and the day's
milestones were gone. Their loggers are set to WARNING (no record is even made below it) and the
handlers drop any other library's record below WARNING.
"""

from __future__ import annotations

import logging
import logging.handlers
import os
import sys
from pathlib import Path

from lfstudio.support.secrets import ScrubFilter

LOG_FILE_NAME = "lfstudio.log"
#: per file; with BACKUP_COUNT older files at most 60 MB of logs. A scan writes about 7 lines (0.7 kB) a
#: view on a GRBL rig and 3.4 lines (0.3 kB) on CiA 402 drives (benchmarks/log_lines_per_view.py), so the
#: files keep about 74 h of an unattended scan at one view every 3 s: a day with room for retries,
#: warnings and a --debug session
MAX_BYTES = 10_000_000
BACKUP_COUNT = 5
#: loggers of the libraries we use: WARNING and up only (their DEBUG is protocol traffic, not the operator's)
LIBRARY_LOGGERS = ("pymodbus", "can", "canopen", "PIL", "matplotlib", "urllib3", "asyncio", "distributed",
                   "tornado", "fsspec", "bokeh", "tifffile", "rawpy", "lensfunpy", "gphoto2", "serial",
                   "numba", "h5py", "imageio", "av")
FILE_FORMAT = "%(asctime)s %(levelname)-7s %(threadName)s %(name)s: %(message)s"
CONSOLE_FORMAT = "%(asctime)s %(name)s %(levelname)s: %(message)s"
#: loggers that are quiet unless --debug (high-rate traffic)
CHATTY_LOGGERS = ("lfstudio.rig.grbl.status",)
#: loggers kept off the console unless --debug (the file still gets them): FFmpeg's own error lines
#: (PyAV logs them as ``libav.*``) repeat what our error message already says ("last error log: ...")
FILE_ONLY_LOGGERS = ("libav",)


def _console_filter(record: logging.LogRecord) -> bool:
    return not any(record.name == n or record.name.startswith(n + ".") for n in FILE_ONLY_LOGGERS)


def _ours(name: str) -> bool:
    return name in ("lfstudio", "root", "__main__", "py.warnings") or name.startswith(("lfstudio.", "libav"))


def _library_filter(record: logging.LogRecord) -> bool:
    """Another library's record reaches our handlers only from WARNING up (a library we do not list
    in LIBRARY_LOGGERS, or one that set its own logger's level)."""
    return record.levelno >= logging.WARNING or _ours(record.name)

_HANDLER_TAG = "_lfstudio_handler"


def log_dir() -> Path:
    """``$LFSTUDIO_LOG_DIR``, else the platform's user log folder (``~/.local/state/lfstudio/log`` on
    Linux, ``~/Library/Logs/lfstudio`` on macOS, ``%LOCALAPPDATA%\\lfstudio\\Logs`` on Windows)."""
    env = os.environ.get("LFSTUDIO_LOG_DIR")
    if env:
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_log_dir("lfstudio", appauthor=False))


def log_file() -> Path:
    """The current log file (older ones sit next to it as ``lfstudio.log.1`` ...)."""
    return log_dir() / LOG_FILE_NAME


def debug_requested() -> bool:
    """``$LFSTUDIO_DEBUG`` set to anything but empty/0."""
    return os.environ.get("LFSTUDIO_DEBUG", "") not in ("", "0")


def is_configured() -> bool:
    """True once :func:`setup_logging` ran in this process."""
    return any(getattr(h, _HANDLER_TAG, False) for h in logging.getLogger().handlers)


def setup_logging(debug: bool = False, console: bool = True) -> Path | None:
    """Configure the root logger: rotating file (DEBUG) + console (WARNING, DEBUG with ``debug``).

    Idempotent: a second call replaces the handlers of the first. Returns the log file path, or None
    when the log folder cannot be created (then only the console logs, with a warning)."""
    debug = debug or debug_requested()
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, _HANDLER_TAG, False):
            root.removeHandler(handler)
            handler.close()
    root.setLevel(logging.DEBUG)
    for name in CHATTY_LOGGERS:
        logging.getLogger(name).setLevel(logging.DEBUG if debug else logging.INFO)
    for name in LIBRARY_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)

    if console:
        stream = logging.StreamHandler(sys.stderr)
        stream.setLevel(logging.DEBUG if debug else logging.WARNING)
        if not debug:
            stream.addFilter(_console_filter)
        stream.addFilter(_library_filter)
        stream.setFormatter(logging.Formatter(CONSOLE_FORMAT))
        stream.addFilter(ScrubFilter())            # a secret value given to this process never shows
        setattr(stream, _HANDLER_TAG, True)
        root.addHandler(stream)

    path = log_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handler = logging.handlers.RotatingFileHandler(path, maxBytes=MAX_BYTES, backupCount=BACKUP_COUNT,
                                                       encoding="utf-8", errors="backslashreplace", delay=True)
    except OSError as exc:
        logging.getLogger(__name__).warning("cannot write the log file %s (%s); logging to the console only",
                                            path, exc)
        return None
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter(FILE_FORMAT))
    handler.addFilter(_library_filter)
    handler.addFilter(ScrubFilter())
    setattr(handler, _HANDLER_TAG, True)
    root.addHandler(handler)
    return path


def flush_logs() -> None:
    """Flush our handlers (before showing a crash dialog that names the log)."""
    for handler in logging.getLogger().handlers:
        if getattr(handler, _HANDLER_TAG, False):
            try:
                handler.flush()
            except Exception:  # noqa: BLE001 - never fail while reporting a failure
                pass
