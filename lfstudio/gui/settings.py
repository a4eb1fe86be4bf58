"""Persistent user settings (QSettings in an INI file under the user config folder), and typed readers
of its values.

``QSettings.value`` gives back whatever the file holds (the INI format: text), so a value is read
through :func:`read_int`, :func:`read_float`, :func:`read_bool` or :func:`read_text`: a value the
file does not hold as that type (edited by hand, or written by another version) gives the default
and a warning in the log, never an exception while the window is being built."""

from __future__ import annotations

import logging
import math

from PySide6.QtCore import QSettings

from lfstudio.resources import user_config_dir

log = logging.getLogger(__name__)


def settings() -> QSettings:
    """The app's settings file; ``$LFSTUDIO_CONFIG_DIR`` moves it (tests point it into tmp_path)."""
    path = user_config_dir() / "lfstudio.ini"
    path.parent.mkdir(parents=True, exist_ok=True)
    return QSettings(str(path), QSettings.Format.IniFormat)


def _unreadable(s: QSettings, key: str, value: object, what: str, default: object) -> None:
    log.warning("%s in %s: %r is not %s; using %r", key, s.fileName(), value, what, default)


def read_text(key: str, default: str = "", s: QSettings | None = None) -> str:
    """The text stored under ``key`` (``default`` when there is none)."""
    s = settings() if s is None else s
    value = s.value(key, default)
    return default if value is None else str(value)


def read_int(key: str, default: int, s: QSettings | None = None) -> int:
    """The whole number stored under ``key`` (``default`` when there is none or it is not one)."""
    s = settings() if s is None else s
    value = s.value(key, default)
    if isinstance(value, (str, int, float)):
        try:
            return int(value)
        except (ValueError, OverflowError):
            pass
    _unreadable(s, key, value, "a whole number", default)
    return default


def read_float(key: str, default: float, s: QSettings | None = None) -> float:
    """The finite number stored under ``key`` (``default`` when there is none or it is not one)."""
    s = settings() if s is None else s
    value = s.value(key, default)
    if isinstance(value, (str, int, float)):
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if math.isfinite(number):
            return number
    _unreadable(s, key, value, "a finite number", default)
    return default


_TRUE, _FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")


def read_bool(key: str, default: bool, s: QSettings | None = None) -> bool:
    """The yes/no stored under ``key`` (QSettings writes ``true``/``false``; ``default`` when there is
    none or it is neither)."""
    s = settings() if s is None else s
    value = s.value(key, default)
    if isinstance(value, bool):
        return value
    word = str(value).strip().lower()
    if word in _TRUE or word in _FALSE:
        return word in _TRUE
    _unreadable(s, key, value, "true or false", default)
    return default
