"""The hot-folder camera: for cameras run by their vendor's software, which drops each picture
into a folder.

A capture optionally runs a trigger command (an argument list, never a shell string), then waits
for a *new* file in the folder that has stopped growing, and moves it to the dataset under the
view's name. Names that look temporary or partial (``.x``, ``~x``, ``x.tmp``, ``x.part``,
``x.crdownload``, ...), files that were there before the capture and text files beside the picture
(XMP sidecars, notes, logs) are ignored. Which file is the picture is decided by reading it, as
everywhere (:mod:`lfstudio.dataset.images`: a RAW LibRaw reads, whatever its suffix, or an image
OpenCV reads), not by a list of suffixes; a new binary file that is neither stops the capture
with its name.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from lfstudio.dataset import images
from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.paths import is_utf8_name, shown_name
from lfstudio.errors import DeviceError, DeviceRefused, DeviceTimeout, InputError
from lfstudio.numbers import FILE_STABLE_S, FILE_WAIT_S
from lfstudio.rig.camera import CaptureResult

log = logging.getLogger(__name__)

_PARTIAL_SUFFIXES = (".tmp", ".temp", ".part", ".partial", ".crdownload", ".download", ".lock", ".swp", "~")


def is_partial_name(name: str) -> bool:
    """True for names a writer uses while a file is incomplete (hidden, temporary, partial)."""
    low = name.lower()
    return (low.startswith((".", "~", "_tmp")) or low.endswith(_PARTIAL_SUFFIXES)
            or ".tmp" in low or ".part" in low)


@dataclass(frozen=True)
class FolderStatus:
    connected: bool
    folder: str
    shots: int = 0
    busy: bool = False
    message: str = ""


class HotFolderCamera:
    """Camera driver over a watched folder (see the module docstring).

    ``trigger_command``: argument list run for each capture (e.g. ``["vendorcli", "--shoot"]``);
    None: the operator or the vendor software triggers. ``timeout_s``: how long to wait for the
    new file; ``stable_s``: how long its size must stay unchanged; ``poll_s``: polling period.
    ``keep_source``: copy instead of move. ``extensions``: only files with these suffixes count
    (None: any picture). ``clock``/``wait`` exist for tests (simulated time).
    """

    name = "Hot folder"

    def __init__(self, folder: str | os.PathLike, trigger_command: Sequence[str] | None = None, *,
                 extensions: Sequence[str] | None = None, timeout_s: float = 30.0,
                 stable_s: float = 0.5, poll_s: float = 0.1, trigger_timeout_s: float = 30.0,
                 keep_source: bool = False, clock: Callable[[], float] = time.monotonic,
                 wait: Callable[[float], bool] | None = None):
        if isinstance(trigger_command, (str, bytes)):
            raise InputError("trigger command", "must be a list of arguments, not a shell string",
                             'e.g. ["vendorcli", "--capture"]')
        self.folder = Path(folder)
        self.trigger_command = list(trigger_command) if trigger_command else None
        self.extensions = None if extensions is None else \
            tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)
        self.timeout_s = float(timeout_s)
        self.stable_s = float(stable_s)
        self.poll_s = float(poll_s)
        self.trigger_timeout_s = float(trigger_timeout_s)
        self.keep_source = bool(keep_source)
        self._clock = clock
        self._abort = threading.Event()
        self._wait = wait or self._abort.wait
        self._connected = False
        self._busy = False
        self._message = ""
        self.shots = 0
        self._seen: set[str] = set()

    # -- connection ---------------------------------------------------------------------------------
    def connect(self) -> None:
        if not self.folder.is_dir():
            raise DeviceError(f"hot folder {self.folder}: not found or not a folder; create it or choose the "
                              "folder the camera software saves into")
        if not os.access(self.folder, os.R_OK | os.W_OK | os.X_OK):
            raise DeviceError(f"hot folder {self.folder}: no read/write permission; files must be moved out of it")
        self._seen = set(self._listing())
        self._abort.clear()
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False
        self._abort.set()

    def stop(self) -> None:
        self._abort.set()

    def status(self) -> FolderStatus:
        return FolderStatus(self._connected, str(self.folder), self.shots, self._busy, self._message)

    def settings(self) -> dict[str, Any]:
        return {"folder": str(self.folder), "trigger_command": list(self.trigger_command or []),
                "timeout_s": self.timeout_s, "stable_s": self.stable_s, "format": "as saved by the camera"}

    def set_setting(self, name: str, value: Any) -> None:
        if name == "timeout_s":
            self.timeout_s = FILE_WAIT_S.parse(name, value)
        elif name == "stable_s":
            self.stable_s = FILE_STABLE_S.parse(name, value)
        elif name == "trigger_command":
            if isinstance(value, (str, bytes)):
                raise InputError("trigger command", "must be a list of arguments, not a shell string")
            self.trigger_command = list(value) if value else None
        else:
            raise InputError(name, "no such setting of the hot-folder camera",
                             f"timeout_s {FILE_WAIT_S.valid()}, stable_s {FILE_STABLE_S.valid()}, "
                             "trigger_command (argument list)")

    def preview(self) -> None:
        return None

    # -- capture ------------------------------------------------------------------------------------
    def _listing(self) -> list[str]:
        try:
            return [e.name for e in os.scandir(self.folder) if e.is_file()]
        except OSError as exc:
            raise DeviceError(f"hot folder {self.folder}: cannot be read ({exc.strerror}); is the drive there?") \
                from None

    def _candidates(self) -> list[str]:
        """New, complete-looking names in the folder. A new name that is not valid UTF-8 stops the
        capture naming it by its escaped bytes (remembered as seen, so it is told once): the image
        libraries cannot open such a name, and OpenCV crashes the process on it."""
        names = [n for n in self._listing()
                 if n not in self._seen and not is_partial_name(n)
                 and (self.extensions is None or os.path.splitext(n)[1].lower() in self.extensions)]
        for n in names:
            if not is_utf8_name(n):
                self._seen.add(n)
                raise DeviceRefused(f"hot folder {shown_name(self.folder)}: {shown_name(n)} arrived but its name is not "
                                  "valid UTF-8, which the image libraries cannot open; set the camera software to "
                                  "name its files in ASCII or UTF-8, or rename the file")
        return sorted(names)

    def _trigger(self) -> None:
        assert self.trigger_command is not None
        try:
            proc = subprocess.run(self.trigger_command, shell=False, capture_output=True, text=True,
                                  timeout=self.trigger_timeout_s, stdin=subprocess.DEVNULL)
        except FileNotFoundError:
            raise DeviceError(f"trigger command {self.trigger_command[0]!r} not found; give the full path "
                              "of the camera software's command-line tool") from None
        except subprocess.TimeoutExpired:
            raise DeviceError(f"trigger command {' '.join(self.trigger_command)} did not finish within "
                              f"{self.trigger_timeout_s:g} s") from None
        if proc.returncode != 0:
            detail = (proc.stderr or proc.stdout or "").strip().splitlines()
            raise DeviceError(f"trigger command {' '.join(self.trigger_command)} failed with exit code "
                              f"{proc.returncode}" + (f": {detail[-1]}" if detail else ""))

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Trigger (if configured), wait for one new complete file, move it to ``stem_path`` + suffix."""
        if not self._connected:
            raise DeviceError(f"hot folder {self.folder}: not connected; connect the camera first")
        stem_path = Path(stem_path)
        self._abort.clear()
        self._busy = True
        try:
            if self.trigger_command:
                # anything already there predates this shot; without a trigger, a file that arrived
                # since the last capture (shutter pressed by hand) is this shot's
                self._seen |= set(self._listing())
            t0 = self._clock()
            if self.trigger_command:
                self._trigger()
            t_triggered = self._clock()
            name, size = self._wait_for_complete_file(t0)
            t_appeared = self._clock()
            if on_exposed is not None:
                on_exposed()
            src = self.folder / name
            dest = stem_path.with_name(stem_path.name + os.path.splitext(name)[1].lower())
            self._transfer(src, dest, size)
            self._seen.add(name)
            self.shots += 1
            self._message = ""
            t_done = self._clock()
            log.debug("hot folder: %s arrived as %s", self.folder, dest.name)
            return CaptureResult(files=(dest,), trigger_s=t_triggered - t0, exposure_s=0.0,
                                 transfer_s=t_done - t_appeared,
                                 metadata={"source": str(src), "bytes": size, "format": dest.suffix[1:].upper()})
        except DeviceError as exc:
            self._message = str(exc)
            raise
        finally:
            self._busy = False

    def _wait_for_complete_file(self, t0: float) -> tuple[str, int]:
        last: dict[str, tuple[int, float, float]] = {}     # name -> (size, mtime, since)
        while True:
            now = self._clock()
            for name in self._candidates():
                try:
                    st = os.stat(self.folder / name)
                except FileNotFoundError:          # renamed or removed meanwhile
                    last.pop(name, None)
                    continue
                key = (st.st_size, st.st_mtime)
                prev = last.get(name)
                if prev is None or (prev[0], prev[1]) != key:
                    last[name] = (st.st_size, st.st_mtime, now)
                elif st.st_size > 0 and now - prev[2] >= self.stable_s:
                    if self._is_picture(name):
                        return name, int(st.st_size)
                    last.pop(name, None)            # a sidecar or a note: keep waiting for the picture
            if now - t0 > self.timeout_s:
                growing = [n for n in last]
                hint = (f"; {growing[0]} kept changing" if growing else
                        "; check that the camera software saves into this folder")
                raise DeviceTimeout(f"hot folder {self.folder}: no new complete file within {self.timeout_s:g} s{hint}")
            if self._wait(self.poll_s):
                raise DeviceError(f"hot folder {self.folder}: stopped while waiting for the file")

    def _is_picture(self, name: str) -> bool:
        """A complete new file: the picture (LibRaw or OpenCV reads it), or text beside it (False,
        remembered as seen); DeviceError naming it when it is neither."""
        path = self.folder / name
        if images.is_text(path):
            self._seen.add(name)
            return False
        try:
            images.kind(path)
        except images.NotACapture as exc:
            self._seen.add(name)
            raise DeviceError(f"hot folder {self.folder}: {name} arrived but is not a picture ({exc.reason}); "
                              "set the camera software to save RAW, TIFF or JPEG files") from None
        return True

    def _transfer(self, src: Path, dest: Path, size: int) -> None:
        """Move (or copy) ``src`` to ``dest`` atomically, and check the size arrived complete."""
        def move(tmp: Path) -> None:
            if self.keep_source:
                shutil.copyfile(src, tmp)
            else:
                try:
                    os.replace(src, tmp)
                except OSError:                    # another file system: copy, then remove
                    shutil.copyfile(src, tmp)
                    src.unlink()
            got = tmp.stat().st_size
            if got != size:
                raise DeviceError(f"{src}: {got} bytes arrived of {size}; the file changed while it was "
                                  "being moved; retry the shot")

        try:
            atomic_write_with(dest, move)
        except OSError as exc:
            raise DeviceError(f"cannot move {src} to {dest}: {exc.strerror or exc}; check free disk space "
                              "and permissions") from None
