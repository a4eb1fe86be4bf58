"""Atomic file writes: write a temporary file in the same folder, fsync it, rename it over the
target, fsync the folder. A reader (or a crash) sees the old file or the new one, never a half.
Files get the permissions of any file the user creates (0666 minus the umask)."""

from __future__ import annotations

import json
import os
import re
import secrets
from pathlib import Path
from typing import Any, Callable


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _create_temporary(path: Path) -> Path:
    """A new empty file beside ``path`` under a temporary name, created with the user's umask
    (0666 & ~umask, as any ordinary file; mkstemp would make it 0600 and the rename keeps that)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"{path.parent}: no free temporary name for {path.name}")


def atomic_write_with(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Let ``write(tmp_path)`` produce the file under a temporary name, then move it into place.

    Use this for libraries that only write to a path (cv2.imwrite, tifffile). The temporary name
    keeps the target's suffix so such libraries pick the right format.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = _create_temporary(path)
    try:
        write(tmp_path)
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
    except BaseException as exc:
        tmp_path.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno is not None and exc.filename in (None, str(tmp_path)):
            exc.filename = str(path)          # the operator knows the file, not its temporary name (a failed
            #                                   write names none: without it, messages named the working folder's disk;
            #                                   an OSError(message) of the writer's own keeps its words)
        raise
    _fsync_dir(path.parent)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    return atomic_write_with(path, lambda p: p.write_bytes(data))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=1, sort_keys=False, allow_nan=False) + "\n")


#: exactly the names :func:`_create_temporary` makes: ``.STEM.XXXXXXXX.tmpSUFFIX`` (8 hex digits)
_TEMPORARY = re.compile(r"\..+\.[0-9a-f]{8}\.tmp(\.[^./\\]+)?")


def is_temporary(path: str | os.PathLike) -> bool:
    """True for the temporary names :func:`atomic_write_with` uses (left behind only by a crash), and
    for nothing else: a file of the operator's that merely starts with '.' and holds '.tmp' is kept."""
    return _TEMPORARY.fullmatch(Path(path).name) is not None
