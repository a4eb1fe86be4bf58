"""Where lfstudio keeps the user's configuration and its lock files on Linux: the config folder
through platformdirs (``$XDG_CONFIG_HOME/lfstudio``, else ``~/.config/lfstudio``), the runtime folder
of the port and camera locks by its own rule (``$XDG_RUNTIME_DIR/lfstudio``, else
``TMP/lfstudio-UID``), each overridden by its LFSTUDIO_* variable."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

from lfstudio.resources import user_config_dir
from lfstudio.support.locks import runtime_dir

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the XDG folders are Linux's")


@linux
def test_the_config_folder_follows_xdg_config_home_then_home(monkeypatch, tmp_path):
    monkeypatch.delenv("LFSTUDIO_CONFIG_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    assert user_config_dir() == tmp_path / "xdg" / "lfstudio"
    monkeypatch.delenv("XDG_CONFIG_HOME")
    assert user_config_dir() == tmp_path / "home" / ".config" / "lfstudio"
    monkeypatch.setenv("XDG_CONFIG_HOME", "")          # empty counts as unset, as before
    assert user_config_dir() == tmp_path / "home" / ".config" / "lfstudio"
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path / "mine"))
    assert user_config_dir() == tmp_path / "mine"


@linux
def test_the_runtime_folder_follows_xdg_runtime_dir_then_the_temporary_folder(monkeypatch, tmp_path):
    monkeypatch.delenv("LFSTUDIO_RUNTIME_DIR", raising=False)
    xdg = tmp_path / "run"
    xdg.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(xdg))
    assert runtime_dir() == xdg / "lfstudio"
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "missing"))    # not a folder: the fallback
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()

    assert runtime_dir() == Path(tmp_path / "tmp" / f"lfstudio-{os.getuid()}")
    assert (runtime_dir().stat().st_mode & 0o777) == 0o700
