"""Where the shipped resources (presets, style, icons) live, and the user's own config folder."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def _find_resources() -> Path:
    """The shipped resources: a PyInstaller bundle has them in its folder; a source checkout next to
    the package; ``pip install .``/pipx under ``PREFIX/share/lfstudio/resources`` (pyproject's
    data-files; PREFIX is the venv, ``~/.local`` for ``--user``, or ``sys.prefix``)."""
    if hasattr(sys, "_MEIPASS"):
        return Path(getattr(sys, "_MEIPASS")) / "resources"
    here = Path(__file__).resolve()
    candidates = [here.parent.parent / "resources"]              # checkout (and editable installs)
    if len(here.parents) > 4:                                    # PREFIX/lib/pythonX.Y/site-packages/lfstudio
        candidates.append(here.parents[4] / "share" / "lfstudio" / "resources")
    candidates.append(Path(sys.prefix) / "share" / "lfstudio" / "resources")
    for path in candidates:
        if (path / "presets").is_dir():
            return path
    return candidates[0]


RESOURCES_DIR = _find_resources()
PRESETS_DIR = RESOURCES_DIR / "presets"


def user_config_dir() -> Path:
    """``$LFSTUDIO_CONFIG_DIR``, else the platform's user config folder (platformdirs:
    ``$XDG_CONFIG_HOME/lfstudio``, by default ``~/.config/lfstudio``, on Linux;
    ``~/Library/Application Support/lfstudio`` on macOS): user presets and profiles go here."""
    env = os.environ.get("LFSTUDIO_CONFIG_DIR")
    if env:
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_config_dir("lfstudio", appauthor=False))


PRESET_KINDS = ("cameras", "lenses", "rigs")


def load_presets(kind: str) -> dict[str, dict]:
    """Presets of ``kind`` ("cameras", "lenses", "rigs"): shipped ones, then the user's, which
    override by name. A broken user file raises :class:`lfstudio.errors.InputError` naming it."""
    return {name: data for name, (data, _path) in load_presets_with_files(kind).items()}


def preset_file(kind: str, name: str) -> str:
    """The file the preset ``name`` of ``kind`` comes from (the user's when it overrides a shipped
    one), for messages about its values; "" when there is no such preset."""
    found = load_presets_with_files(kind).get(name)
    return str(found[1]) if found else ""


def load_presets_with_files(kind: str) -> dict[str, tuple[dict, Path]]:
    """:func:`load_presets`, each preset with the file it comes from."""
    import tomllib

    from lfstudio.errors import InputError

    if kind not in PRESET_KINDS:
        raise ValueError(f"unknown preset kind {kind!r}")
    presets: dict[str, tuple[dict, Path]] = {}
    for path in (PRESETS_DIR / f"{kind}.toml", user_config_dir() / "presets" / f"{kind}.toml"):
        if not path.is_file():
            continue
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise InputError(str(path), f"cannot read preset file: {exc}", "a TOML file of [\"Name\"] tables")
        except RecursionError:
            raise InputError(str(path), "cannot read preset file: nested too deeply to be a preset file",
                             "a TOML file of [\"Name\"] tables") from None
        presets.update({name: (value, path) for name, value in data.items()})
    return presets
