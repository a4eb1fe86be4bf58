"""Persistent user settings (QSettings in an INI file under the user config folder)."""

from __future__ import annotations

from PySide6.QtCore import QSettings

from lfstudio.resources import user_config_dir


def settings() -> QSettings:
    """The app's settings file; ``$LFSTUDIO_CONFIG_DIR`` moves it (tests point it into tmp_path)."""
    path = user_config_dir() / "lfstudio.ini"
    path.parent.mkdir(parents=True, exist_ok=True)
    return QSettings(str(path), QSettings.Format.IniFormat)
