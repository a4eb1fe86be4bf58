"""STOP stays in sight when a big dialog covers the main window (at 1366 x 768 the Process, Depth,
Radiance, Export and calibration dialogs cover its STOP toolbar): each carries a STOP button that
triggers the window's STOP (offscreen Qt, real loop)."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QPushButton

from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.calibration_wizard import CalibrationWizard
from lfstudio.gui.dialogs.export_dialog import ExportDialog
from lfstudio.gui.dialogs.process_dialog import ProcessDialog
from lfstudio.gui.views.depth import DepthDialog
from lfstudio.gui.views.radiance import RadianceDialog


@pytest.mark.parametrize("make", [ProcessDialog, DepthDialog, RadianceDialog, ExportDialog, CalibrationWizard,
                                  lambda state, window: RadianceDialog(state, ProcessDialog(state, window))],
                         ids=["process", "depth", "radiance", "export", "calibration", "radiance-in-process"])
def test_a_dialog_over_the_window_carries_the_windows_stop(qtbot, make_dataset, make):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(make_dataset(rows=1, cols=3, w=96, h=64))
    dialog = make(window.state, window)
    button = dialog.findChild(QPushButton, "dialogStopButton")
    assert button is not None and button.isEnabled() and "STOP" in button.text()
    with qtbot.waitSignal(window.stop_action.triggered, timeout=5000):
        qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    dialog.close()
    window.close()
