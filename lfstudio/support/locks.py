"""OS-level locks: one process per serial port, per camera and per dataset folder.

A lock is an exclusive, non-blocking ``fcntl.flock`` on a lock file. The kernel drops it when the
holding process ends in any way (exit, crash, ``kill -9``), so a lock left by a dead process is
never in the way: the next process takes it and says so. While held, the lock file names its
holder in one JSON line (pid, command line, what it is doing, since when), so a refused process
can tell the operator who holds it::

    with lock_dataset(folder, "scanning"):          # raises LockBusy naming the holder
        ...

Where the lock files are:

- a dataset: ``DATASET/dataset.lock`` (held for the whole scan or resume; its owner alone writes the
  journal), and ``DATASET/manifest.lock`` (:func:`manifest_lock`: held for milliseconds by any stage
  while it merges its records into the manifest, see docs/dataset-format.md "Two commands at once");
- a serial port or a camera: ``RUNTIME/port-dev-ttyUSB0.lock``, ``RUNTIME/camera-gphoto2.lock``,
  with ``RUNTIME`` = ``$LFSTUDIO_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/lfstudio``, else
  ``TMP/lfstudio-UID`` (see :func:`runtime_dir`). A serial port is also flock'ed on the device node
  itself (as pyserial's ``Serial(exclusive=True)`` does), so programs that lock ports the same way
  are kept out too; the runtime lock comes first, so a refused lfstudio process never opens the port.

Lock files are opened without following symlinks and must be ordinary files
(:func:`open_lock_file`): a ``dataset.lock`` that is a symlink is refused, never emptied through.

POSIX only (``fcntl``); on Windows the locks are not enforced.

The holder line is written only while the lock is held and emptied on release; a dead process's
line stays until the next holder overwrites it, and is never reported as a holder (its flock is gone).
"""

from __future__ import annotations

import datetime as _dt
import errno
import hashlib
import json
import os
import re
import socket
import stat
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator
from pathlib import Path

from lfstudio.errors import LfError
from lfstudio.support.secrets import command_line, scrub

try:
    import fcntl
except ImportError:                    # Windows: no flock; these locks are not enforced there
    fcntl = None

DATASET_LOCK_NAME = "dataset.lock"
#: the short lock of a dataset's manifest (:func:`manifest_lock`): held only while one process reads
#: the manifest and journal, merges its changes in and writes it
MANIFEST_LOCK_NAME = "manifest.lock"
#: how long :func:`manifest_lock` waits for another process's merge before it gives up
MANIFEST_LOCK_WAIT_S = 60.0
RUNTIME_ENV = "LFSTUDIO_RUNTIME_DIR"


class LockBusy(LfError):
    """Another process holds the lock; ``holder`` says who (None when it is not an lfstudio process)."""

    kind = "busy"

    def __init__(self, what: str, holder: "Holder | None", hint: str = ""):
        self.what = what
        self.holder = holder
        who = holder.describe() if holder is not None else "another program"
        super().__init__(f"{what} is in use by {who}" + (f"; {hint}" if hint else ""))


@dataclass(frozen=True)
class Holder:
    """Who holds a lock (read from its lock file)."""

    pid: int
    command: str
    doing: str = ""
    since: str = ""
    host: str = ""     # the computer it runs on (named only when it is another one: a shared folder)

    def describe(self) -> str:
        """``lfstudio scan --out D (pid 123, scanning D since 12:01:05)``; ``pid 123 on HOST`` when it
        runs on another computer."""
        if not self.pid:
            return self.command
        where = f" on {self.host}" if self.host and self.host != socket.gethostname() else ""
        extra = ", ".join(p for p in (self.doing, f"since {self.since}" if self.since else "") if p)
        return f"{self.command} (pid {self.pid}{where}{', ' + extra if extra else ''})"

    def to_json(self) -> str:
        return json.dumps({"pid": self.pid, "command": self.command, "doing": self.doing, "since": self.since,
                           "host": self.host})

    @classmethod
    def parse(cls, text: str) -> "Holder | None":
        try:
            data = json.loads(text)
            return cls(int(data["pid"]), str(data["command"]), str(data.get("doing", "")),
                       str(data.get("since", "")), str(data.get("host", "")))
        except (ValueError, KeyError, TypeError):
            return None


def this_command() -> str:
    """The command line of this process as an operator typed it (``lfstudio scan --out D``), its
    secret values redacted: as the CLI recorded it when it read its options
    (:func:`lfstudio.support.secrets.set_command_line`), else ``sys.argv`` without any secret this
    process knows. A lock file is read by other processes and may outlive this one."""
    shown = command_line()
    if shown is not None:
        text = scrub(" ".join(shown)) or "lfstudio"
    else:
        argv = list(sys.argv)
        if argv and (argv[0].endswith("__main__.py") or Path(argv[0]).name in ("lfstudio", "__main__.py")):
            argv[0] = "lfstudio"
        elif argv and argv[0] == "-m":
            argv[0] = "lfstudio"
        text = scrub(" ".join(argv)) if argv and argv[0] else "lfstudio"
    return text if len(text) <= 200 else text[:197] + "..."


def runtime_dir() -> Path:
    """The folder of the port and camera lock files (created, private to this user).

    Chosen by hand, not with ``platformdirs.user_runtime_dir``: every lfstudio process on the
    computer must find the same lock files whatever platformdirs version its environment has, and
    platformdirs' fallback without ``$XDG_RUNTIME_DIR`` changed between versions (3.x:
    ``/run/user/UID`` unchecked; 4.x: checked, else ``TMP/runtime-UID``, with a warning)."""
    env = os.environ.get(RUNTIME_ENV)
    if env:
        folder = Path(env)
    elif os.environ.get("XDG_RUNTIME_DIR") and Path(os.environ["XDG_RUNTIME_DIR"]).is_dir():
        folder = Path(os.environ["XDG_RUNTIME_DIR"]) / "lfstudio"
    else:
        uid = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
        folder = Path(tempfile.gettempdir()) / f"lfstudio-{uid}"
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    return folder


#: the longest key in a lock file's name (a file name has at most 255 bytes; a hot folder's path may not)
MAX_KEY_CHARS = 120


def _key(text: str) -> str:
    key = re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-.") or "unnamed"
    if len(key) > MAX_KEY_CHARS:        # its start to read, a digest of the whole to tell long names apart
        digest = hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()[:16]
        key = f"{key[:MAX_KEY_CHARS - len(digest) - 1]}-{digest}"
    return key


class NotALockFile(LfError):
    """A lock file that is a symlink, a folder or a device: never opened, never written through."""

    kind = "not-a-lock-file"


def open_lock_file(path: str | os.PathLike, *, create: bool = True) -> int:
    """Open the lock file ``path`` for reading and writing without following a symlink
    (``O_NOFOLLOW``); refuse anything that is not a regular file (:class:`NotALockFile` naming it and
    the fix), so taking a lock never empties or writes a file elsewhere."""
    flags = os.O_RDWR | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NONBLOCK", 0)
    fix = "it must be an ordinary file lfstudio makes itself; remove it (lfstudio makes it again)"
    try:
        fd = os.open(path, flags | (os.O_CREAT if create else 0), 0o666)   # the umask applies, as to any file
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.EISDIR, errno.ENXIO) or os.path.islink(path):
            raise NotALockFile(f"{path}: not an ordinary file (a symlink, folder or device); {fix}") from None
        raise
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise NotALockFile(f"{path}: not an ordinary file (a symlink, folder or device); {fix}")
    except BaseException:
        os.close(fd)
        raise
    return fd


def _try_lock(fd: int) -> bool:
    """Exclusive, non-blocking; False when another open file holds it."""
    if fcntl is None:  # pragma: no cover - Windows
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES, errno.EDEADLK):
            return False
        raise
    return True


class Lock:
    """One held lock (see the module docstring). ``taken_over``: the holder line a dead process left."""

    def __init__(self, path: Path, what: str, doing: str = "", hint: str = "", device: str | None = None):
        self.path = Path(path)
        self.what = what
        self.doing = doing
        self.hint = hint
        self.device = device          # also flock this device node (a serial port)
        self.taken_over: Holder | None = None
        self._fd: int | None = None
        self._device_fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "Lock":
        if self._fd is not None:
            return self
        for _attempt in range(5):
            fd = self._open_locked()
            if fd is not None:
                break
        else:
            raise LockBusy(self.what, None, "its lock file keeps being replaced; try again")
        self._fd = fd
        return self

    def _open_locked(self) -> int | None:
        """Open and lock the lock file; None when it was removed meanwhile (by :meth:`remove`)."""
        fd = open_lock_file(self.path)
        try:
            if not _try_lock(fd):
                holder = Holder.parse(os.pread(fd, 4096, 0).decode("utf-8", "replace").strip())
                raise LockBusy(self.what, holder or Holder(0, "another lfstudio process"), self.hint)
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:                 # locked a file that was removed in the meantime
                os.close(fd)
                return None
            left = Holder.parse(os.pread(fd, 4096, 0).decode("utf-8", "replace").strip())
            if left is not None and left.pid != os.getpid():
                self.taken_over = left
            self._device_fd = self._lock_device()
            since = _dt.datetime.now().strftime("%H:%M:%S")
            line = (Holder(os.getpid(), this_command(), self.doing, since, socket.gethostname()).to_json() + "\n").encode()
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, line, 0)
            except OSError as exc:        # e.g. a full disk: the message names this file's disk
                if exc.filename is None:
                    exc.filename = str(self.path)
                raise
        except BaseException:
            dfd, self._device_fd = self._device_fd, None
            if dfd is not None:            # the device node's lock goes with the failure (else this process
                os.close(dfd)              # would be refused by its own leftover: "in use by another program")
            os.close(fd)
            raise
        return fd

    def _lock_device(self) -> int | None:
        if not self.device or fcntl is None:
            return None
        try:
            dfd = os.open(self.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return None              # not openable here: the driver reports why when it opens it
        if not _try_lock(dfd):
            os.close(dfd)
            raise LockBusy(self.what, None, "close the other program using it (it holds an exclusive lock)")
        return dfd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        dfd, self._device_fd = self._device_fd, None
        if dfd is not None:
            os.close(dfd)
        if fd is not None:
            try:
                os.ftruncate(fd, 0)     # no holder any more (still ours: the lock is held until close)
            except OSError:
                pass
            os.close(fd)

    def remove(self) -> None:
        """Delete the lock file, then release (a process that opened it meanwhile notices and retries)."""
        if self._fd is not None:
            self.path.unlink(missing_ok=True)
        self.release()

    def __enter__(self) -> "Lock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self) -> None:   # a forgotten lock must not outlive its object
        if self._fd is not None:
            self.release()


def holder_of(path: str | os.PathLike) -> Holder | None:
    """Who holds the lock file ``path`` now (None when nobody does). Does not take the lock."""
    path = Path(path)
    if path.is_symlink() or not path.is_file():
        return None
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError:
                text = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip()
                return Holder.parse(text) or Holder(0, "another lfstudio process")
            fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def port_device(port: str) -> str | None:
    """The device node of a serial port name (symlinks resolved), or None for a pyserial URL."""
    if "://" in port:
        return None
    return os.path.realpath(port) if os.path.isabs(port) or os.path.exists(port) else port


def port_lock(port: str, doing: str = "", shown: str = "") -> Lock:
    """The (not yet acquired) lock of a serial port: ``/dev/ttyUSB0``, ``/dev/pts/5``, ``COM3``
    (``shown``: how a message names the rig, default ``rig port PORT``)."""
    device = port_device(port)
    key = _key(device or port)
    return Lock(runtime_dir() / f"port-{key}.lock", shown or f"rig port {port}", doing,
                hint="wait for it to finish, or stop it there (its STOP, or Ctrl-C in its terminal)",
                device=device if device and os.path.exists(device) else None)


def rig_record_path(port: str) -> Path:
    """The file that says which dataset's scan last used the rig on ``port`` (a serial port or a
    drive pair's device word), beside the port's lock: ``RUNTIME/rig-dev-ttyUSB0.last-scan.json``."""
    return runtime_dir() / f"rig-{_key(port_device(port) or port)}.last-scan.json"


def drive_lock(address: str, doing: str = "") -> Lock:
    """The (not yet acquired) lock of one axis drive: ``192.168.1.10:502`` (Modbus TCP), ``can0 node 1``."""
    return Lock(runtime_dir() / f"drive-{_key(address)}.lock", f"axis drive {address}", doing,
                hint="wait for it to finish, or stop it there (its STOP, or Ctrl-C in its terminal)")


def camera_lock(name: str, doing: str = "", shown: str = "") -> Lock:
    """The (not yet acquired) lock of a camera: ``gphoto2``, or a hot folder's path; ``shown``: how a
    message names the camera (its device word, ``folder:PATH``; default ``name``)."""
    return Lock(runtime_dir() / f"camera-{_key(name)}.lock", f"camera {shown or name}", doing,
                hint="disconnect it there first")


def dataset_lock(root: str | os.PathLike, doing: str = "",
                 hint: str = "wait for that scan to finish, or stop it there; then resume") -> Lock:
    """The (not yet acquired) lock of a dataset folder (the folder must exist); ``hint``: the fix
    named when another process holds it."""
    root = Path(root)
    return Lock(root / DATASET_LOCK_NAME, f"dataset {root}", doing, hint=hint)


@contextmanager
def manifest_lock(root: str | os.PathLike, *, shared: bool = False,
                  wait_s: float = MANIFEST_LOCK_WAIT_S) -> Iterator[bool]:
    """Hold the short lock of the dataset in ``root`` (``root/manifest.lock``) while reading the
    manifest and journal (``shared``) or merging into and writing the manifest (exclusive).

    Independent of ``dataset.lock`` (the scan's lock, held for the whole scan): a stage may merge
    its records into the manifest while a scan runs; the scan takes this lock for each of its own
    manifest writes. Held for milliseconds, so it waits (up to ``wait_s``, then
    :class:`LockBusy`). Yields True when locked; False when the lock file cannot be made (a
    read-only dataset: nobody can write it either, so reading it unlocked is safe).
    """
    path = Path(root) / MANIFEST_LOCK_NAME
    try:
        fd = open_lock_file(path)
    except NotALockFile:
        raise
    except OSError as exc:
        if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM) and shared:
            yield False
            return
        raise
    try:
        if fcntl is not None:
            mode = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB
            deadline = time.monotonic() + wait_s
            pause = 0.001
            while True:
                try:
                    fcntl.flock(fd, mode)
                    break
                except OSError as exc:
                    if exc.errno not in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES):
                        raise
                if time.monotonic() > deadline:
                    raise LockBusy(f"dataset {root}", holder_of(Path(root) / DATASET_LOCK_NAME),
                                   f"its manifest stayed locked for {wait_s:g} s; try again")
                time.sleep(pause)          # another process's merge takes milliseconds
                pause = min(0.05, pause * 2)
        yield True
    finally:
        os.close(fd)                       # closing releases the flock
