"""Where the shipped resources (presets, style, icons) live, and the user's own config folder."""

from __future__ import annotations

import os
import sys
from pathlib import Path

# In a PyInstaller bundle the resources sit in the bundle folder; otherwise next to the package.
RESOURCES_DIR = (Path(getattr(sys, "_MEIPASS")) if hasattr(sys, "_MEIPASS")
                 else Path(__file__).resolve().parent.parent) / "resources"
PRESETS_DIR = RESOURCES_DIR / "presets"


def user_config_dir() -> Path:
    """``$LFSTUDIO_CONFIG_DIR`` or ``~/.config/lfstudio``: user presets and profiles go here."""
    env = os.environ.get("LFSTUDIO_CONFIG_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "lfstudio"


PRESET_KINDS = ("cameras", "lenses", "rigs")


def load_presets(kind: str) -> dict[str, dict]:
    """Presets of ``kind`` ("cameras", "lenses", "rigs"): shipped ones, then the user's, which
    override by name. A broken user file raises :class:`lfstudio.errors.InputError` naming it."""
    import tomllib

    from lfstudio.errors import InputError

    if kind not in PRESET_KINDS:
        raise ValueError(f"unknown preset kind {kind!r}")
    presets: dict[str, dict] = {}
    for path in (PRESETS_DIR / f"{kind}.toml", user_config_dir() / "presets" / f"{kind}.toml"):
        if not path.is_file():
            continue
        try:
            presets.update(tomllib.loads(path.read_text(encoding="utf-8")))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise InputError(str(path), f"cannot read preset file: {exc}", "a TOML file of [\"Name\"] tables")
    return presets
