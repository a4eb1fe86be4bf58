"""The window on the screens operators have (a 1366 x 768 laptop, 1600 x 1000, 1920 x 1080), held at the
screen's size as a window manager does: the side panels get the width they need (no sideways scrolling,
"Skip view" in sight), every control can be scrolled into sight, STOP is in sight, no text is cut off
without a sign ("0 failec"), Check leaves the layout alone, View → Reset layout puts every panel back,
and the first window fits the screen it opens on."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QTabBar

from lfstudio.gui.app import create_window
from lfstudio.gui.main_window import PanelScrollArea
from lfstudio.gui.widgets import ElidedLabel, QuietLabel, WholeOrNothingLabel
from tests.conftest import REPO_ROOT
from tests.gui.test_panel_docks import CONTROLS, _in_window, _scroll_areas, _scroll_to

SCREENS = [(1366, 768), (1600, 1000), (1920, 1080)]
SIDE = (Qt.LeftDockWidgetArea, Qt.RightDockWidgetArea)


def _window(qtbot, size, fixed=True):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    if fixed:
        window.setFixedSize(*size)
    else:
        window.resize(*size)
    window.show()
    qtbot.waitExposed(window)
    qtbot.waitUntil(lambda: window.docks_fitted > 0, timeout=5000)
    return window


def _layout(window) -> dict:
    return {"window": window.size().toTuple(),
            **{name: dock.geometry().getRect() for name, dock in window.docks.items()
               if dock.isVisible() and not dock.visibleRegion().isEmpty()}}


def _cut_labels(root) -> list[str]:
    """Visible one-line labels whose text is cut off without a sign ('…' or nothing painted)."""
    cut = []
    for label in root.findChildren(QLabel):
        if not label.isVisible() or label.wordWrap() or not label.text() or label.width() <= 0:
            continue
        if isinstance(label, WholeOrNothingLabel):
            continue                                   # paints all of it or nothing (checked below)
        parent = label.parentWidget()
        if isinstance(parent, QuietLabel):
            if parent.shown_text() != parent.text() and not parent.shown_text().endswith("…"):
                cut.append(parent.text())
            continue
        if isinstance(label, ElidedLabel):
            if label.text() != label.full_text() and not label.text().endswith("…"):
                cut.append(label.full_text())
            continue
        need = label.sizeHint().width()
        if label.width() + 1 < need and "…" not in label.text():
            cut.append(f"{label.objectName()}: {label.text()!r} ({label.width()} of {need} px)")
    return cut


@pytest.mark.parametrize("size", SCREENS)
def test_side_panels_get_their_width_every_control_and_stop_in_sight(qtbot, size):
    window = _window(qtbot, size)
    inside = window.rect()
    for name, dock in window.docks.items():
        if window.dockWidgetArea(dock) not in SIDE:
            continue
        dock.show()
        dock.raise_()
        panel = window.panels[name]
        qtbot.waitUntil(lambda: panel.isVisible(), timeout=5000)
        area: PanelScrollArea = dock.widget()
        qtbot.waitUntil(lambda: panel.width() >= panel.minimumSizeHint().width(), timeout=5000)
        assert area.horizontalScrollBar().maximum() == 0, (name, "scrolls sideways", dock.width())
        assert inside.contains(dock.geometry()), (name, dock.geometry())
        for control in [c for kind in CONTROLS for c in panel.findChildren(kind) if c.isVisibleTo(panel)]:
            for scroll in _scroll_areas(control, dock):
                _scroll_to(scroll, control)
            rect, seen = _in_window(control, window), _in_window(dock, window)
            for scroll in _scroll_areas(control, dock):
                seen = seen.intersected(_in_window(scroll.viewport(), window))
            assert seen.contains(rect), (name, control.objectName() or type(control).__name__, rect, seen)
        assert not _cut_labels(panel), (name, _cut_labels(panel))
    assert window.stop_button.isVisible() and inside.contains(_in_window(window.stop_button, window))
    # every dock's tab (Rig, Camera, Processing, ...) on the screen
    for bar in window.findChildren(QTabBar):
        if bar.isVisible():
            assert inside.contains(_in_window(bar, window)), [bar.tabText(i) for i in range(bar.count())]


@pytest.mark.parametrize("size", [(1366, 768), (1600, 1000)])
def test_check_leaves_the_window_and_the_docks_alone(qtbot, tiny_dataset, size):
    """Pressing Check showed its progress beside the buttons: the grid view asked for ~250 px more, the
    window grew (1500 -> 1521 px) and the side docks shrank to 240 px for good."""
    window = _window(qtbot, size, fixed=False)
    window.state.set_dataset(tiny_dataset)
    view = window.central
    qtbot.waitUntil(lambda: view.quality_bar.check_button.isEnabled(), timeout=5000)
    before = _layout(window)
    bar = view.quality_bar
    with qtbot.waitSignal(bar.runner.started, timeout=10000):
        qtbot.mouseClick(bar.check_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: bar.progress.isVisible(), timeout=5000)
    qtbot.wait(50)       # not a synchronisation: the layout gets turns of the event loop to change
    assert _layout(window) == before
    with qtbot.waitSignal(bar.runner.finished, timeout=120000):
        pass
    qtbot.waitUntil(lambda: not bar.progress.isVisible(), timeout=5000)
    assert _layout(window) == before
    assert not _cut_labels(view), _cut_labels(view)
    assert view.counts.shown_text() == view.counts.text() and "15 done" in view.counts.text()
    legend = bar.legend                                  # a heat map gets its colour scale, whole
    assert not legend.isVisible()
    bar.overlay.setCurrentIndex(bar.overlay.findData("sharpness"))
    qtbot.waitUntil(lambda: legend.isVisible() and legend.width() >= legend.sizeHint().width(), timeout=5000)
    low, high = legend.texts()
    assert low.startswith("Sharpness") and high.endswith("×") and legend.low < legend.high
    assert _layout(window) == before


def test_reset_layout_puts_every_panel_back(qtbot):
    window = _window(qtbot, (1600, 1000))
    default = _layout(window)
    docks = window.docks
    docks["scanPanel"].setFloating(True)
    window.addDockWidget(Qt.LeftDockWidgetArea, docks["calibrationPanel"])
    docks["plannerDock"].close()
    window.resizeDocks([docks["rigDock"]], [250], Qt.Horizontal)
    qtbot.waitUntil(lambda: _layout(window) != default, timeout=5000)
    action = window.reset_layout_action
    assert action in window.menu("View").actions()
    action.trigger()
    qtbot.waitUntil(lambda: window.docks_fitted == 2, timeout=5000)
    qtbot.wait(50)       # not a synchronisation: the layout gets turns of the event loop to settle
    assert _layout(window) == default
    assert not any(d.isFloating() for d in docks.values())


FIRST_START = """
import json, sys
from PySide6.QtCore import QPoint, QRect
from PySide6.QtWidgets import QApplication, QTabBar
app = QApplication([])
from lfstudio.gui.app import create_window
window = create_window(simulated=True)
window.show()
while not window.docks_fitted:
    app.processEvents()
for _ in range(20):
    app.processEvents()
screen = window.screen().availableGeometry()
inside = [b for b in window.findChildren(QTabBar)
          if b.isVisible() and window.rect().contains(QRect(b.mapTo(window, QPoint(0, 0)), b.size()))]
bars = [[[b.tabText(i) for i in range(b.count())], window.tab_bar_in_place(b)]
        for b in window.dock_tab_bars() if b.isVisible()]
print(json.dumps({"screen": screen.getRect(), "frame": window.frameGeometry().getRect(),
                  "tabs_inside": [[b.tabText(i) for i in range(b.count())] for b in inside], "bars": bars}))
window.close()
"""


@pytest.mark.parametrize("screen", [(1366, 768), (1600, 1000), (1920, 1080)])
def test_first_window_fits_the_screen(tmp_path, screen):
    """On a 1366 x 768 screen the first window was 1500 x 950: the tab rows (Rig) were off-screen; on a large
    screen stale copies of two tab rows were painted over the status bar."""
    config = tmp_path / "screen.json"
    config.write_text(json.dumps({"screens": [{"name": "s", "x": 0, "y": 0, "width": screen[0],
                                               "height": screen[1], "logicalDpi": 96, "logicalBaseDpi": 96,
                                               "dpr": 1}]}))
    import os

    env = {**os.environ, "QT_QPA_PLATFORM": f"offscreen:configfile={config}",
           "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", FIRST_START], capture_output=True, text=True, env=env,
                         timeout=120, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    sx, sy, sw, sh = got["screen"]
    assert (sw, sh) == screen
    x, y, w, h = got["frame"]
    assert sx <= x and sy <= y and x + w <= sx + sw and y + h <= sy + sh, got
    assert any("Rig" in tabs for tabs in got["tabs_inside"]) and any("Processing" in tabs for tabs in got["tabs_inside"])
    # no tab bar left behind: Qt painted a second "Planner | Rig" and "Plan plots | Live view" bar where
    # the groups were first laid out (over the status bar on a large screen)
    assert all(in_place for _, in_place in got["bars"]), got["bars"]
    groups = [tuple(tabs) for tabs, _ in got["bars"]]
    assert len(groups) == len(set(groups)) and ("Planner", "Rig", "Camera") in groups, groups
    if screen == (1920, 1080):
        assert (w, h) >= (1500, 950)      # a large screen keeps the default size


DIALOGS = """
import json, sys
from PySide6.QtWidgets import QApplication, QLineEdit
app = QApplication([])
from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.import_dialog import ImportImagesDialog
window = create_window(simulated=True)
window.show()
while not window.docks_fitted:
    app.processEvents()
window.state.set_dataset(Dataset.open(sys.argv[1]))
free = window.screen().availableGeometry()
out = {"free": [free.width(), free.height()], "dialogs": {}}

def look(name, dialog):
    dialog.show()
    for _ in range(30):
        app.processEvents()
    cut = [e.objectName() or e.placeholderText() for e in dialog.findChildren(QLineEdit)
           if e.isVisible() and not e.text() and e.placeholderText()
           and e.fontMetrics().horizontalAdvance(e.placeholderText()) + 12 > e.width()]
    out["dialogs"][name] = {"size": dialog.size().toTuple(), "minimum": dialog.minimumSizeHint().toTuple(),
                            "placeholders_cut": cut}

window.open_export_dialog()
export = window.export_dialog
export.format_combo.setCurrentIndex(export.format_combo.findData("hci"))
look("export (HCI)", export)
window.panels["processingPanel"].open_dialog()
look("process", window.panels["processingPanel"].dialog)
window.panels["calibrationPanel"].open_wizard()
look("calibration wizard", window.panels["calibrationPanel"].wizard)
look("import images", ImportImagesDialog(window.state, window))
look("user guide", window.show_user_guide())
print(json.dumps(out))
"""


@pytest.mark.parametrize("screen", [(1366, 768), (1600, 1000)])
def test_dialogs_fit_the_screen_and_show_their_hints_whole(tmp_path, tiny_dataset, screen):
    """On a 1366 x 768 laptop the process dialog and the calibration wizard opened 800 px high (their
    buttons under the screen's edge) and the export dialog's HCI authors hint was cut off."""
    import os

    config = tmp_path / "screen.json"
    config.write_text(json.dumps({"screens": [{"name": "s", "x": 0, "y": 0, "width": screen[0],
                                               "height": screen[1], "logicalDpi": 96, "logicalBaseDpi": 96,
                                               "dpr": 1}]}))
    env = {**os.environ, "QT_QPA_PLATFORM": f"offscreen:configfile={config}", "HOME": str(tmp_path),
           "XDG_CONFIG_HOME": str(tmp_path / "config"),
           "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", DIALOGS, str(tiny_dataset.root)], capture_output=True, text=True,
                         env=env, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    free_w, free_h = got["free"]
    assert len(got["dialogs"]) == 5
    for name, seen in got["dialogs"].items():
        (w, h), (min_w, min_h) = seen["size"], seen["minimum"]
        assert w + 16 <= free_w and h + 48 <= free_h, (name, seen, got["free"])     # the frame fits too
        assert min_w <= w and min_h <= h, (name, seen)                               # nothing squeezed
        assert not seen["placeholders_cut"], (name, seen)


@pytest.mark.parametrize("saved_on", [(1920, 1080), (1366, 768)])
def test_a_saved_layout_that_squeezes_a_panel_is_fitted_again(qtbot, saved_on):
    """A layout saved with narrow side panels (on a larger screen, or dragged narrow) came back at the
    next start with the Planner and Scan panels scrolling sideways ("Take grid fro", "Resu" cut off):
    a restored layout is kept, except that a side panel too narrow for its controls gets its width."""
    first = _window(qtbot, saved_on, fixed=False)
    docks = first.docks
    first.resizeDocks([docks["plannerDock"], docks["scanPanel"]], [180, 180], Qt.Horizontal)
    qtbot.waitUntil(lambda: docks["scanPanel"].widget().horizontalScrollBar().maximum() > 0, timeout=5000)
    first.close()                                       # saves the layout
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.setFixedSize(1366, 768)
    window.show()
    qtbot.waitExposed(window)
    qtbot.waitUntil(lambda: window.docks_fitted > 0, timeout=5000)
    for name in ("plannerDock", "scanPanel"):
        area: PanelScrollArea = window.docks[name].widget()
        qtbot.waitUntil(lambda: area.horizontalScrollBar().maximum() == 0, timeout=5000)
    assert window.docks["planPlotsDock"].isVisible()     # the rest of the saved layout is kept
