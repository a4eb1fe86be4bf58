"""What the Settings dialog stores (QSettings keys) and the getters the panels use.

- ``paths/datasets``: the folder new scans are created in and "Open dataset" starts in (default: home);
- ``export/folder``: the folder File → Export dataset… writes to (the export dialog also stores its
  last folder there; empty: next to the dataset);
- ``defaults/camera``, ``defaults/lens``, ``defaults/rig``: preset names (resources/presets/*.toml
  plus the user's); the rig one is also the Rig panel's profile (``rig/profile``).

lfstudio shows lengths in millimetres throughout (the rig's GRBL units), so there is no unit setting.
"""

from __future__ import annotations

from pathlib import Path

from lfstudio.gui.settings import settings

DATASETS_KEY = "paths/datasets"
EXPORT_KEY = "export/folder"          # also the export dialog's last folder
PRESET_KEYS = {"cameras": "defaults/camera", "lenses": "defaults/lens", "rigs": "defaults/rig"}


def datasets_folder() -> Path:
    return Path(str(settings().value(DATASETS_KEY, str(Path.home()))))


def export_folder() -> Path | None:
    """The export destination folder, or None: next to the exported dataset."""
    value = str(settings().value(EXPORT_KEY, "") or "")
    return Path(value) if value else None


def default_preset(kind: str) -> str:
    """The chosen default preset name of ``kind`` ("cameras", "lenses", "rigs"), or "" (none chosen)."""
    value = settings().value(PRESET_KEYS[kind], "")
    if kind == "rigs" and not value:
        value = settings().value("rig/profile", "")
    return str(value or "")
