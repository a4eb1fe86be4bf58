"""Atomic writes create files with the user's umask (not mkstemp's private 0600)."""

from __future__ import annotations

import contextlib
import os

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.atomic import atomic_write_bytes, atomic_write_json, atomic_write_with, is_temporary


@contextlib.contextmanager
def umask(mask: int):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def mode(path) -> int:
    return path.stat().st_mode & 0o777


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077, 0o027], ids=lambda m: f"umask{m:03o}")
def test_files_get_the_users_umask(tmp_path, mask):
    with umask(mask):
        atomic_write_bytes(tmp_path / "a.bin", b"x")
        atomic_write_json(tmp_path / "b.json", {"a": 1})
        atomic_write_with(tmp_path / "c.png", lambda p: cv2.imwrite(str(p), np.zeros((4, 4), np.uint8)))
        atomic_write_bytes(tmp_path / "a.bin", b"replaced")          # replacing keeps the same rule
        ds = Dataset.create(tmp_path / "ds", camera={"name": "c"}, lens={"name": "l"},
                            grid={"columns": 2, "rows": 1, "spacing_mm": [1, 1]})
    want = 0o666 & ~mask
    for path in (tmp_path / "a.bin", tmp_path / "b.json", tmp_path / "c.png", ds.manifest_path):
        assert mode(path) == want, f"{path.name}: {oct(mode(path))}, want {oct(want)}"
    assert (tmp_path / "a.bin").read_bytes() == b"replaced"
    assert not [p for p in tmp_path.rglob("*") if is_temporary(p)]


def test_temporary_names_do_not_collide(tmp_path):
    names = set()

    def record(p):
        names.add(p.name)
        p.write_bytes(b"1")

    for _ in range(50):
        atomic_write_with(tmp_path / "v.jpg", record)
    assert len(names) == 50 and all(is_temporary(tmp_path / n) and n.endswith(".jpg") for n in names)


def test_a_writers_own_error_message_is_kept_whole(tmp_path):
    """``OSError("PATH: cv2.imwrite failed")`` raised by the writer: its words, not "[Errno None] None: PATH"."""
    target = tmp_path / "x.png"

    def write(tmp):
        raise OSError(f"{target}: cv2.imwrite failed")

    with pytest.raises(OSError) as info:
        atomic_write_with(target, write)
    assert str(info.value) == f"{target}: cv2.imwrite failed"
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_names_the_target_not_its_temporary(tmp_path):
    target = tmp_path / "x.bin"

    def write(tmp):
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError) as info:
        atomic_write_with(target, write)
    assert info.value.filename == str(target) and "No space left" in str(info.value)
