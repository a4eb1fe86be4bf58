"""Crash dialog, Help menu (About, user guide, log folder) and the Settings dialog on the real window."""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

import pytest
from PySide6.QtCore import QTimer
from PySide6.QtGui import QGuiApplication

from lfstudio.gui.app import create_window


@pytest.fixture
def window(qtbot):
    w = create_window(simulated=True)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()


@pytest.fixture
def hooks(window, monkeypatch):
    """The app's exception hooks and log file for one test (restored afterwards)."""
    from lfstudio.gui.crash import install_exception_hooks
    from lfstudio.support.logs import setup_logging

    monkeypatch.setattr(sys, "excepthook", sys.excepthook)
    monkeypatch.setattr(threading, "excepthook", threading.excepthook)
    root = logging.getLogger()
    before, level = list(root.handlers), root.level
    path = setup_logging()
    yield install_exception_hooks(window), path
    for h in list(root.handlers):
        if h not in before:
            root.removeHandler(h)
            h.close()
    root.setLevel(level)


def _crash_dialogs(window):
    from lfstudio.gui.crash import CrashDialog

    return [d for d in window.findChildren(CrashDialog) if d.isVisible()]


@pytest.mark.qt_no_exception_capture
def test_exception_in_a_slot_shows_dialog_and_app_keeps_running(qtbot, window, hooks):
    reporter, log_path = hooks

    def broken_slot():
        raise RuntimeError("injected failure in a slot")

    QTimer.singleShot(0, broken_slot)
    qtbot.waitUntil(lambda: len(_crash_dialogs(window)) == 1, timeout=5000)
    dialog = _crash_dialogs(window)[0]
    assert "injected failure in a slot" in dialog.message.text()
    assert str(log_path) in dialog.message.text()            # where the log is
    assert "Traceback" in dialog.details and "broken_slot" in dialog.details
    assert "LibRaw" in dialog.details                         # versions for the bug report
    dialog.copy_button.click()
    assert "injected failure in a slot" in QGuiApplication.clipboard().text()
    assert "broken_slot" in Path(log_path).read_text(encoding="utf-8")   # traceback in the log file

    # the window still works: its event loop runs and its actions respond
    window.state.show_status("still alive", 0)
    qtbot.waitUntil(lambda: window.statusBar().currentMessage() == "still alive")
    assert window.isVisible()
    dialog.close()


@pytest.mark.qt_no_exception_capture
def test_exception_in_a_thread_shows_dialog(qtbot, window, hooks):
    def worker():
        raise ValueError("injected failure in a thread")

    t = threading.Thread(target=worker, name="injected-worker")
    t.start()
    t.join()
    qtbot.waitUntil(lambda: len(_crash_dialogs(window)) == 1, timeout=5000)
    dialog = _crash_dialogs(window)[0]
    assert "injected failure in a thread" in dialog.message.text() and "injected-worker" in dialog.message.text()
    assert window.isVisible()


def test_the_hooks_it_replaced_come_back_in_order(window, monkeypatch):
    """Nested installs unwind to the hooks each one found (an embedding program keeps its own)."""
    from lfstudio.gui.crash import install_exception_hooks, restore_exception_hooks

    def mine(*args):
        pass

    def mine_for_threads(args):
        pass

    monkeypatch.setattr(sys, "excepthook", mine)
    monkeypatch.setattr(threading, "excepthook", mine_for_threads)
    outer = install_exception_hooks(window)
    first = sys.excepthook
    inner = install_exception_hooks(window)
    assert sys.excepthook is not first and sys.excepthook is not mine
    restore_exception_hooks(inner)
    assert sys.excepthook is first and threading.excepthook is not mine_for_threads
    restore_exception_hooks(outer)
    restore_exception_hooks(outer)                   # twice is harmless
    assert sys.excepthook is mine and threading.excepthook is mine_for_threads


def test_help_menu_has_guide_log_folder_and_about(qtbot, window, tmp_path, monkeypatch):
    names = {a.objectName() for a in window.menu("Help").actions()}
    assert {"actionUserGuide", "actionShowLogFolder", "actionAbout"} <= names
    about = window.show_about()
    qtbot.waitUntil(lambda: about.table.rowCount() > 5, timeout=20000)
    text = about.text()
    for name in ("lfstudio", "Python", "Qt", "OpenCV", "LibRaw", "FFmpeg", "numpy", "libgphoto2"):
        assert f"\n{name}: " in "\n" + text, name
    assert "PySide6" in text
    monkeypatch.chdir(tmp_path)          # pictures must load from the README's folder, not the cwd
    guide = window.show_user_guide()
    assert "Planning a scene" in guide.browser.toPlainText()
    from PySide6.QtCore import QUrl
    from PySide6.QtGui import QImage, QTextDocument

    picture = guide.browser.loadResource(QTextDocument.ImageResource, QUrl("docs/screenshot.png"))
    assert picture is not None and not QImage.fromData(picture).isNull()     # the guide's pictures load
    assert guide.fit_images(300) >= 5 and guide.fit_images(300) == 0        # ... fitted, and only once
    # the guide on a 1366 x 768 laptop (860 px wide): commands wrap, pictures fit, no sideways scrolling
    guide.resize(860, 600)
    guide.show()
    qtbot.waitUntil(lambda: guide.browser.document().idealWidth() <= guide.browser.viewport().width(), timeout=5000)
    assert guide.browser.horizontalScrollBar().maximum() == 0
    assert "lfstudio scan --port sim" in guide.browser.toPlainText()
    guide.close()
    about.close()


def test_settings_round_trip_and_apply(qtbot, window, tmp_path, tiny_dataset):
    from lfstudio.gui import preferences
    from lfstudio.gui.dialogs.settings_dialog import SettingsDialog

    dialog = window.open_settings()
    dialog.datasets_edit.setText(str(tmp_path / "datasets"))
    dialog.export_edit.setText(str(tmp_path / "exports"))
    rigs = dialog.preset_combos["rigs"]
    rigs.setCurrentIndex(rigs.count() - 1)
    rig_name = rigs.currentData()
    dialog.accept()
    assert preferences.datasets_folder() == tmp_path / "datasets"
    assert preferences.export_folder() == tmp_path / "exports"
    assert preferences.default_preset("rigs") == rig_name
    scan = window.panels["scanPanel"]
    assert Path(scan.folder.text()).parent == tmp_path / "datasets"       # applied to the Scan panel
    assert window.panels["rigDock"].rig_config.name == rig_name          # and to the Rig panel
    again = SettingsDialog(window)                                        # a new dialog shows the stored values
    assert again.values() == dialog.values()
    window.state.set_dataset(tiny_dataset)                                # the export dialog starts there
    window.open_export_dialog()
    assert window.export_dialog.folder_edit.text() == str(tmp_path / "exports")
    window.export_dialog.close()
