"""Storage errors: a disk that is full, read-only, not writable or failing, told as such.

Every stage that writes (capture, thumbnail, journal, manifest, processed view, export, calibration)
turns an ``OSError`` from the disk into a :class:`StorageError` with :func:`storage_error`: one line
naming the disk (its mount point and file system), what was being written, the free space and, when
known, the space needed — never blamed on the camera or the rig. The rule at every write is
*stop, keep, resume*: stop the run with that line, keep everything already written (atomic writes
leave no half file; the journal keeps every captured view), and let the operator resume once the
disk has room, without capturing or computing again what was kept.

:func:`disk_problem` looks at a folder's disk without writing (read-only mount, no write permission,
too little free space), for when a device reports a failure that may really be the disk's.
"""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from lfstudio.errors import LfError

#: errno -> (kind, what the operator reads)
STORAGE_ERRNOS: dict[int, tuple[str, str]] = {
    errno.ENOSPC: ("full", "is full"),
    errno.EDQUOT: ("full", "is over its quota"),
    errno.EROFS: ("read-only", "is read-only"),
    errno.EACCES: ("not writable", "is not writable for this user"),
    errno.EPERM: ("not writable", "does not allow this write"),
    errno.EIO: ("failing", "reports an input/output error (it may be failing or was unplugged)"),
}
_FIX = {"full": "free space there or choose a folder on another disk",
        "read-only": "remount it writable or choose a folder on another disk",
        "not writable": "fix the folder's permissions or choose another folder",
        "failing": "check the disk and its cable and copy what it holds somewhere safe"}


class StorageError(LfError, OSError):
    """A disk refused a write (``kind``: full, read-only, not writable, failing). ``path``: what was
    being written; ``disk``: the mount point holding it; ``need_bytes``: the space needed, if known."""

    def __init__(self, message: str, *, kind: str, path: str | os.PathLike | None = None, disk: str = "",
                 need_bytes: int | None = None, errno_: int | None = None):
        LfError.__init__(self, message)
        self.errno = errno_
        self.strerror = message
        self.filename = None if path is None else str(path)
        self.kind = kind
        self.disk = disk
        self.need_bytes = need_bytes

    def __str__(self) -> str:
        return self.args[0]


def megabytes(n: float) -> str:
    """``12 kB``, ``3.4 MB``, ``512 MB``, ``58.3 GB``."""
    if n >= 10e9:
        return f"{n / 1e9:.1f} GB"
    if n < 0.1e6:
        return f"{n / 1e3:.0f} kB"
    return f"{n / 1e6:.1f} MB" if n < 10e6 else f"{n / 1e6:.0f} MB"


def mount_point(path: str | os.PathLike) -> Path:
    """The mount point of the file system holding ``path`` (or its nearest existing parent)."""
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        dev = p.stat().st_dev
        while p != p.parent and p.parent.stat().st_dev == dev:
            p = p.parent
    except OSError:
        pass
    return p


def describe_disk(path: str | os.PathLike) -> str:
    """``the disk at /mnt/data (ext4, 1.2 GB free)`` for messages."""
    mount = mount_point(path)
    fs = _fs_type(mount)
    try:
        free = shutil.disk_usage(mount).free
        return f"the disk at {mount} ({fs + ', ' if fs else ''}{megabytes(free)} free)"
    except OSError:
        return f"the disk at {mount}{f' ({fs})' if fs else ''}"


def _fs_type(mount: Path) -> str:
    try:
        with open("/proc/self/mounts", encoding="utf-8") as fh:
            for line in fh:
                parts = line.split()
                if len(parts) > 2 and parts[1].replace("\\040", " ") == str(mount):
                    fs = parts[2]
        return fs  # the last mount at that point is the one in effect
    except (OSError, UnboundLocalError):
        return ""


def storage_error(exc: BaseException, path: str | os.PathLike | None = None, *, doing: str = "writing",
                  need_bytes: int | None = None, then: str = "resume",
                  at: str | os.PathLike | None = None) -> StorageError | None:
    """The :class:`StorageError` ``exc`` stands for (an OSError whose errno is a disk's), else None.

    ``path``: what was being written (default: the error's file name); ``doing``: what for, e.g.
    "saving the manifest"; ``need_bytes``: the space it needs, when known; ``then``: how to go on
    ("resume", "run it again"); ``at``: a folder on the disk, when neither ``path`` nor the error names
    a file."""
    if isinstance(exc, StorageError):
        return exc
    if not isinstance(exc, OSError) or exc.errno not in STORAGE_ERRNOS:
        return None
    target = path if path is not None else exc.filename
    kind, told = STORAGE_ERRNOS[exc.errno]
    where = target if target is not None else at if at is not None else "."
    disk = describe_disk(where)
    need = f"; about {megabytes(need_bytes)} needed" if need_bytes and kind == "full" else ""
    what = f"{doing} {target}" if target is not None else doing
    if kind == "not writable":            # the folder's permissions, not the disk as a whole
        folder = Path(where) if Path(where).is_dir() else Path(where).parent
        disk, told = f"the folder {folder}", f"{told} ({describe_disk(where)})"
    return StorageError(f"Disk problem while {what}: {disk} {told}{need}. Everything written so far is kept: "
                        f"{_FIX[kind]}, then {then}.", kind=kind, path=target, disk=str(mount_point(where)),
                        need_bytes=need_bytes, errno_=exc.errno)


def disk_problem(folder: str | os.PathLike, need_bytes: int = 0) -> StorageError | None:
    """Why ``folder``'s disk cannot take a write of ``need_bytes`` now (read-only, not writable, too
    full), found without writing; None when it looks fine."""
    folder = Path(folder)
    try:
        st = os.statvfs(folder)
    except OSError as exc:
        return storage_error(exc, folder, doing="checking")
    if st.f_flag & os.ST_RDONLY:
        return storage_error(OSError(errno.EROFS, os.strerror(errno.EROFS)), folder, doing="writing into")
    if not os.access(folder, os.W_OK):
        return storage_error(OSError(errno.EACCES, os.strerror(errno.EACCES)), folder, doing="writing into")
    if need_bytes and st.f_bavail * st.f_frsize < need_bytes:
        return storage_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), folder, doing="writing into",
                             need_bytes=need_bytes)
    return None
