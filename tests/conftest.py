"""Shared fixtures. Qt runs offscreen; settings go to a temporary folder per test."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(autouse=True)
def _isolated_config(tmp_path_factory, monkeypatch):
    """Every test gets its own user config folder (QSettings, presets, logs)."""
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path_factory.mktemp("config")))


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data`` (real files from outside the project); skips when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present on this machine")
    return SHARED_DATA


@pytest.fixture
def run_cli():
    """Run ``python -m lfstudio ARGS`` in a subprocess; returns CompletedProcess (text)."""
    import subprocess

    def run(*args: str, timeout: float = 120, **kw):
        env = dict(os.environ)
        env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        return subprocess.run([sys.executable, "-m", "lfstudio", *map(str, args)], capture_output=True,
                              text=True, timeout=timeout, env=env, cwd=kw.pop("cwd", REPO_ROOT), **kw)

    return run
