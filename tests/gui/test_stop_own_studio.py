"""STOP reaches a scan on the Scan panel's own simulated studio (nothing connected in the Rig and
Camera panels): the studio's rig is the window's rig for the scan's duration, so the toolbar's STOP
(and Esc) pause the scan, the rig badge and the Rig panel show it, and once the scan has ended the Rig
panel shows no device any more (simulated studio on a real pty, real Qt loop)."""

from __future__ import annotations

from dataclasses import replace
from typing import cast

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from lfstudio.gui.app import create_window
from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.panels.scan import ScanPanel
from tests.gui.test_messages_day import set_up_scan

T = 60000


def own_studio_window(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    scan, rig = cast(ScanPanel, window.panels["scanPanel"]), cast(RigPanel, window.panels["rigDock"])
    assert window.state.devices.get("rig") is None and rig.device is None     # nothing connected
    return window, scan, rig


@pytest.mark.parametrize("fly", [False, True], ids=["step", "fly"])
def test_stop_pauses_a_scan_on_the_scan_panels_own_studio(qtbot, tmp_path, fly):
    window, scan, rig = own_studio_window(qtbot)
    if fly:       # a short exposure: a fly speed within the blur limit exists
        window.state.set_plan(replace(window.state.plan, exposure_s=0.001))
    set_up_scan(scan, 8, 3, tmp_path / "own")
    scan.time_scale.setValue(0.05)
    scan.fly.setChecked(fly)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.dataset.status_counts()["done"] >= 2,
                    timeout=T)
    device = window.state.devices.get("rig")
    assert device is not None and device.worker is scan.engine.rig            # the scan's rig is the window's
    qtbot.waitUntil(lambda: window.rig_badge.word not in ("", "disconnected"), timeout=T)
    qtbot.waitUntil(lambda: rig.x_label.text() != "—", timeout=T)             # the Rig panel shows where it is
    assert not rig.jog_buttons[(1, 0)].isEnabled() and not rig.connect_button.isEnabled()
    qtbot.mouseClick(window.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine.state.value == "paused", timeout=T)
    assert scan.engine.fault is not None and scan.engine.fault.stop_pressed
    assert scan.engine.dataset.status_counts()["done"] < 24
    assert not rig.connect_button.isEnabled()      # the paused scan keeps its rig: no other rig replaces it
    rig.connect_rig()                               # (a caller that skips the button: refused too)
    assert rig.device is None and window.state.devices["rig"] is device
    scan.abort()
    qtbot.waitUntil(lambda: "Aborted" in scan.state_label.text(), timeout=T)
    assert scan.engine.state.value == "finished"
    assert window.state.devices.get("rig") is None and rig.device is None      # no stale device
    assert window.rig_badge.word == "disconnected"
    assert rig.x_label.text() == "—" and rig.state_label.text() == "disconnected"
    assert rig.connect_button.isEnabled()
    rig.stop()                                      # STOP with nothing connected: nothing to do, no error
    window.close()


def test_the_rig_panels_stop_reaches_the_own_studios_rig(qtbot, tmp_path):
    """Esc's action (the Rig panel's STOP) and the Rig panel's own STOP button stop the scan's rig."""
    window, scan, rig = own_studio_window(qtbot)
    set_up_scan(scan, 8, 3, tmp_path / "own")
    scan.time_scale.setValue(0.05)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.dataset.status_counts()["done"] >= 1,
                    timeout=T)
    qtbot.mouseClick(rig.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine.state.value == "paused", timeout=T)
    assert scan.engine.fault is not None and scan.engine.fault.stop_pressed
    qtbot.waitUntil(lambda: "Paused" in scan.state_label.text(), timeout=T)     # the GUI has the event too
    qtbot.mouseClick(scan.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine.dataset.status_counts()["done"] >= 3, timeout=T)    # under way again
    window.stop_action.trigger()                    # what Esc triggers
    qtbot.waitUntil(lambda: scan.engine.state.value == "paused", timeout=T)
    assert scan.engine.fault is not None and scan.engine.fault.stop_pressed
    scan.abort()
    qtbot.waitUntil(lambda: "Aborted" in scan.state_label.text(), timeout=T)
    assert window.state.devices.get("rig") is None
    window.close()


def test_stop_while_the_own_studio_homes_stops_it_and_the_scan_does_not_start(qtbot, tmp_path):
    """The own studio's simulated rig homes when it starts (about 11 s in real time): STOP then stops
    it (it was out of STOP's reach: no panel held it yet) and the scan does not start."""
    window, scan, rig = own_studio_window(qtbot)
    set_up_scan(scan, 8, 3, tmp_path / "own")
    scan.time_scale.setValue(1.0)
    errors = []
    window.state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    preparing = lambda: getattr(scan, "_preparing", None)     # noqa: E731 - the rig being prepared
    qtbot.waitUntil(lambda: preparing() is not None and preparing().rig is not None, timeout=T)
    homing = preparing().rig
    qtbot.mouseClick(window.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Not started: STOP was pressed" in scan.state_label.text(), timeout=T)
    assert scan.engine is None and not (tmp_path / "own" / "dataset.json").exists()
    assert not errors, errors                     # the operator's own STOP: no alarm box
    assert scan.studio is None                    # the studio that was stopped while homing is closed again
    assert homing.status().state.value == "disconnected"
    assert window.state.devices.get("rig") is None and scan.start_button.isEnabled()
    window.close()


def test_stop_right_after_start_keeps_the_scan_from_starting(qtbot, tmp_path):
    """STOP pressed while the scan is being prepared (devices opening, dataset being made): nothing
    moves afterwards, the scan does not start."""
    window, scan, rig = own_studio_window(qtbot)
    set_up_scan(scan, 8, 3, tmp_path / "own")
    scan.time_scale.setValue(0.05)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    assert scan.opener.running
    window.stop_action.trigger()
    qtbot.waitUntil(lambda: "Not started: STOP was pressed" in scan.state_label.text(), timeout=T)
    assert scan.engine is None
    window.close()


def test_the_move_back_before_a_resume_on_the_own_studio_is_the_windows_rig(qtbot, tmp_path):
    """A resume whose own-studio rig stands elsewhere offers to move it back: the move runs as the
    window's rig (the badge shows it, STOP reaches it); before, it was refused with "The rig is not
    connected: connect it (Rig → Connect rig)" although the Scan panel's own rig was there."""
    window, scan, rig = own_studio_window(qtbot)
    folder = tmp_path / "moved"
    set_up_scan(scan, 6, 2, folder)
    scan.time_scale.setValue(0.05)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.dataset.status_counts()["done"] >= 2,
                    timeout=T)
    qtbot.mouseClick(scan.abort_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: not scan.running and "Aborted" in scan.state_label.text(), timeout=T)
    assert window.state.devices.get("rig") is None
    scan.studio.rig.move_to(100.0, 50.0)                 # moved away since (the studio's rig, directly)
    errors = []
    window.state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(scan.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: getattr(scan, "move_back_box", None) is not None and scan.move_back_box.isVisible(),
                    timeout=T)
    qtbot.mouseClick(scan.move_back_box.button(QMessageBox.StandardButton.Yes), Qt.LeftButton)
    assert not errors, errors
    device = window.state.devices.get("rig")
    assert device is not None and device.driver is scan.studio.rig      # STOP and the badge reach the move
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.state.value == "running", timeout=T)
    qtbot.waitUntil(lambda: window.state.devices.get("rig") is not None
                    and window.state.devices["rig"].worker is scan.engine.rig, timeout=T)   # now the scan's
    scan.abort()
    qtbot.waitUntil(lambda: "Aborted" in scan.state_label.text() and not scan.running, timeout=T)
    assert not errors, errors
    assert window.state.devices.get("rig") is None
    window.close()


def test_a_start_with_nothing_to_capture_leaves_no_worker_polling_the_own_studios_rig(qtbot, tmp_path):
    """Start again on a finished dataset (nothing to capture): the engine made for it never starts,
    and its own rig worker kept polling the own studio's rig for as long as the window lived."""
    import threading

    window, scan, rig = own_studio_window(qtbot)
    set_up_scan(scan, 2, 1, tmp_path / "done")
    before = set(threading.enumerate())                        # other tests' threads are not this test's
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text() and not scan.running, timeout=T)
    workers = lambda: [t for t in threading.enumerate() if t.name == "device-rig" and t not in before]  # noqa: E731
    qtbot.waitUntil(lambda: not workers(), timeout=T)          # the finished scan's worker has ended
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Every view of this dataset is captured" in scan.state_label.text(), timeout=T)
    qtbot.waitUntil(lambda: not workers(), timeout=T)
    window.close()


def test_a_scan_with_only_the_rig_connected_is_refused_naming_the_camera_panel(qtbot, tmp_path):
    """A rig connected in the Rig panel but no camera: Start is refused (it used to scan on the Scan
    panel's own simulated studio beside the connected rig, which might be a real one) and says what to
    connect; no dataset is made and no simulated studio opened."""
    window, scan, rig = own_studio_window(qtbot)
    errors: list[tuple[str, str]] = []
    window.state.errorOccurred.connect(lambda title, text: errors.append((title, text)))
    rig.connect_rig()
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.state.value != "disconnected",
                    timeout=T)
    set_up_scan(scan, 8, 3, tmp_path / "own")
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    assert errors and errors[-1][0] == "Scan"
    text = errors[-1][1]
    assert "rig is connected but the camera is not" in text and "Camera panel" in text
    assert "disconnect the rig in the Rig panel" in text
    assert scan.engine is None and scan.studio is None and not scan.opener.running
    assert not (tmp_path / "own" / "dataset.json").exists()
    window.close()
