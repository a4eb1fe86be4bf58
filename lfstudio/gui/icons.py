"""The application's icon (a leaf module of the GUI: the window, the dialogs and the app all use it)."""

from __future__ import annotations

from PySide6.QtGui import QIcon

from lfstudio.resources import RESOURCES_DIR


def app_icon() -> QIcon:
    """The lfstudio icon (all PNG sizes of resources/icons/hicolor, or the SVG)."""
    icon = QIcon()
    hicolor = RESOURCES_DIR / "icons" / "hicolor"
    for png in sorted(hicolor.glob("*/apps/lfstudio.png")):
        icon.addFile(str(png))
    if icon.isNull() and (RESOURCES_DIR / "icons" / "lfstudio.svg").is_file():
        icon.addFile(str(RESOURCES_DIR / "icons" / "lfstudio.svg"))
    return icon
