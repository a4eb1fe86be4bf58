"""Every panel in its dock on a small screen (the window held at the screen's size, as a window manager
does): the panel is laid out at least at its minimum size (no rows squeezed over each other or under
the dock's tab bar), its dock lies inside the window, and each of its controls can be brought into
sight (the dock scrolls the panel; a control wider than the dock: as much of it as the dock shows).
STOP stays in sight. Before the panels were put in scroll areas, docks ran past the window's edges."""

from __future__ import annotations

import pytest
from PySide6.QtCore import QPoint, QRect
from PySide6.QtWidgets import QAbstractButton, QAbstractSpinBox, QComboBox, QLineEdit, QScrollArea

from lfstudio.gui.app import create_window

CONTROLS = (QAbstractButton, QAbstractSpinBox, QComboBox, QLineEdit)


def _in_window(widget, window) -> QRect:
    return QRect(widget.mapTo(window, QPoint(0, 0)), widget.size())


def _scroll_areas(widget, dock) -> list[QScrollArea]:
    """The scroll areas between ``widget`` and its dock, innermost first."""
    areas, parent = [], widget.parentWidget()
    while parent is not None and parent is not dock:
        if isinstance(parent, QScrollArea):
            areas.append(parent)
        parent = parent.parentWidget()
    return areas


def _scroll_to(area: QScrollArea, control) -> None:
    """Scroll ``area`` so that the whole of ``control`` is in its viewport, as far as its scroll bars go
    (QScrollArea.ensureWidgetVisible shows only the text cursor of an input)."""
    at = control.mapTo(area.widget(), QPoint(0, 0))
    for bar, start, length, room in ((area.verticalScrollBar(), at.y(), control.height(), area.viewport().height()),
                                     (area.horizontalScrollBar(), at.x(), control.width(), area.viewport().width())):
        if start + length > bar.value() + room:
            bar.setValue(start + length - room)
        if start < bar.value():
            bar.setValue(start)


@pytest.mark.parametrize("size", [(1280, 800), (1280, 1000), (1024, 600)])
def test_every_panel_fits_its_dock_or_scrolls_in_a_small_window(qtbot, size):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.setFixedSize(*size)
    window.show()
    qtbot.waitExposed(window)
    inside = window.rect()
    for name, dock in window.docks.items():
        dock.show()
        dock.raise_()
        panel = window.panels[name]
        need = panel.minimumSizeHint()
        qtbot.waitUntil(lambda: panel.isVisible() and panel.height() >= need.height()
                        and panel.width() >= need.width(), timeout=5000)
        assert inside.contains(dock.geometry()), (name, dock.geometry(), inside)
        controls = [c for kind in CONTROLS for c in panel.findChildren(kind) if c.isVisibleTo(panel)]
        for control in controls:
            for area in _scroll_areas(control, dock):
                _scroll_to(area, control)
            rect = _in_window(control, window)
            seen = _in_window(dock, window)
            for area in _scroll_areas(control, dock):
                seen = seen.intersected(_in_window(area.viewport(), window))
            shown = seen.intersected(rect)      # all of it, or as much as the dock's width can show
            assert shown.height() == rect.height() and shown.width() == min(rect.width(), seen.width()), (name, control.objectName() or type(control).__name__,
                                         control.text() if hasattr(control, "text") else "", rect, seen)
        assert window.stop_button.isVisible() and inside.contains(_in_window(window.stop_button, window))
