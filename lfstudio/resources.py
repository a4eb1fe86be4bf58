"""Where the shipped resources (presets, style, icons) live, and the user's own config folder."""

from __future__ import annotations

import os
from pathlib import Path

RESOURCES_DIR = Path(__file__).resolve().parent.parent / "resources"
PRESETS_DIR = RESOURCES_DIR / "presets"


def user_config_dir() -> Path:
    """``$LFSTUDIO_CONFIG_DIR`` or ``~/.config/lfstudio``: user presets and profiles go here."""
    env = os.environ.get("LFSTUDIO_CONFIG_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "lfstudio"
