"""The fault matrix's shared parts: a folder outside the dataset that must never change, the one-line
error check, real small file systems (tmpfs) for the disk faults, datasets made by real scans."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import uuid
from pathlib import Path

import pytest

from tests.rig.conftest import grbl_firmware, grbl_firmware_exe  # noqa: F401  (the fixtures, for test_devices)


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder``: kind, content hash, size, mtime and mode (symlinks not followed)."""
    out: dict[str, tuple] = {}
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = p.lstat()
            rel = str(p.relative_to(folder))
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
            elif p.is_file():
                out[rel] = ("file", hashlib.sha256(p.read_bytes()).hexdigest(), st.st_size, st.st_mtime_ns, st.st_mode)
            else:
                out[rel] = ("dir", st.st_mode)
    return out


@pytest.fixture
def outside(tmp_path):
    """A folder beside the dataset with a file in it; ``outside.unchanged()`` checks nothing in it changed."""
    folder = tmp_path / "outside"
    folder.mkdir()
    (folder / "keep.txt").write_text("not the dataset's\n")

    class Outside:
        """``mark()`` after setting up the fault (which may move files out here), ``unchanged()`` after the run."""

        path = folder
        before = snapshot(folder)

        def mark(self) -> None:
            self.before = snapshot(folder)

        def unchanged(self) -> bool:
            return snapshot(folder) == self.before

    return Outside()


def error_lines(stderr: str) -> list[str]:
    """The lines of ``stderr`` that report the failure (``lfstudio CMD: error: ...`` or ``... stopped: ...``)."""
    return [line for line in stderr.splitlines() if ": error:" in line or ": stopped:" in line]


def assert_one_line_error(proc: subprocess.CompletedProcess, status: int, *needles: str) -> str:
    """Exit ``status``, exactly one error line that holds every needle, no traceback; returns the line."""
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == status, (proc.returncode, proc.stderr)
    lines = error_lines(proc.stderr)
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, proc.stderr)
    return lines[0]


def manifest_of(root: Path) -> dict:
    return json.loads((root / "dataset.json").read_text())


def write_manifest(root: Path, manifest: dict) -> None:
    (root / "dataset.json").write_text(json.dumps(manifest))


@pytest.fixture
def scanned(run_cli, tmp_path_factory):
    """``scanned(cols, rows) -> folder``: a dataset captured by ``lfstudio scan`` with the instant rig and
    camera (real engine, journal, thumbnails, manifest), copied fresh for each call."""
    cache: dict = {}

    def make(cols: int = 3, rows: int = 2) -> Path:
        if (cols, rows) not in cache:
            src = tmp_path_factory.mktemp("scanned") / "ds"
            proc = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", f"{cols}x{rows}",
                           "--out", src)
            assert proc.returncode == 0, proc.stderr
            cache[(cols, rows)] = src
        dst = tmp_path_factory.mktemp("ds") / "ds"
        shutil.copytree(cache[(cols, rows)], dst, symlinks=True)
        return dst

    return make


def set_pending(root: Path, cells) -> None:
    """Mark views as not captured yet (as an interrupted scan leaves them), keeping their files on disk."""
    m = manifest_of(root)
    for v in m["views"]:
        if (v["row"], v["column"]) in cells:
            v.update(status="pending", file=None, sha256=None, thumb=None)
    write_manifest(root, m)


# -- real small file systems ------------------------------------------------------------------------------
def _can_mount() -> bool:
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    probe = Path(f"/tmp/lfstudio-mount-probe-{uuid.uuid4().hex[:8]}")
    probe.mkdir()
    try:
        ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(probe)],
                            capture_output=True).returncode == 0
        if ok:
            subprocess.run(["umount", str(probe)], capture_output=True)
        return ok
    finally:
        probe.rmdir()


CAN_MOUNT = _can_mount()


class SmallDisk:
    """A tmpfs of ``size`` mounted at ``path`` (root only): a real ENOSPC when full, a real EROFS
    when remounted read-only."""

    def __init__(self, path: Path, size_bytes: int):
        self.path = path
        path.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_bytes},mode=0755", "tmpfs", str(path)],
                       check=True, capture_output=True)

    def read_only(self, on: bool = True) -> None:
        subprocess.run(["mount", "-o", f"remount,{'ro' if on else 'rw'}", str(self.path)], check=True,
                       capture_output=True)

    def fill(self, leave_bytes: int = 0) -> Path:
        """Take the free space but ``leave_bytes`` with a filler file (removed to make room again)."""
        filler = self.path / "filler.bin"
        free = shutil.disk_usage(self.path).free - leave_bytes
        block = b"\0" * 65536
        try:
            with open(filler, "ab", buffering=0) as fh:
                while free > 0:
                    free -= fh.write(block[:min(len(block), free)])
        except OSError:            # full before the count said so (the file system's own blocks)
            pass
        return filler

    def unmount(self) -> None:
        subprocess.run(["umount", "-l", str(self.path)], capture_output=True)


@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size_bytes) -> SmallDisk`` on a real tmpfs; skips where mounting is not allowed."""
    if not CAN_MOUNT:
        pytest.skip("mounting a tmpfs needs root and a kernel that allows it here")
    disks: list[SmallDisk] = []

    def make(size_bytes: int) -> SmallDisk:
        disk = SmallDisk(tmp_path / f"disk{len(disks)}", size_bytes)
        disks.append(disk)
        return disk

    yield make
    for disk in disks:
        disk.unmount()
