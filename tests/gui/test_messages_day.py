"""Messages that go when their cause goes (issue 20), on a real Qt event loop: the Rig panel's
"stopped by STOP", a scan paused by a rig alarm after homing, "Resume the scan" with a working
Resume, a scan log that follows like a terminal, the live view's placeholder, the Export dialog's
result line and layout."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Qt

from lfstudio.dataset import Dataset
from lfstudio.rig.motion import RigState
from tests.gui.test_interlock_gui import homed_simulated_studio
from tests.gui.test_scan_gui import scan_panel, start_then_pause

T = 60000  # ms; generous for a loaded machine, the waits end as soon as the condition holds


def set_up_scan(scan, columns: int, rows: int, folder) -> None:
    """The window's Scan panel set to a small grid, no settling, simulated time 0."""
    scan.columns.setValue(columns)
    scan.rows.setValue(rows)
    scan.settle.setValue(0.0)
    scan.time_scale.setValue(0.0)
    scan.folder.setText(str(folder))


def test_stopped_by_stop_goes_when_the_next_scan_starts(qtbot, tmp_path):
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    simulator = window.state.devices["rig_simulator"]
    simulator.time_scale = 1.0                              # real time: 3000 mm take 15 s
    rig.goto_x.setValue(3000.0)
    rig.go_to()
    qtbot.waitUntil(lambda: simulator.state == "Run" and simulator.reported_position_mm()[0] > 5.0, timeout=T)
    qtbot.mouseClick(window.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "stopped by STOP" in rig.message_label.text(), timeout=T)
    simulator.time_scale = 0.0
    set_up_scan(scan, 2, 1, tmp_path / "later")
    seen = []
    window.state.scanStateChanged.connect(lambda st: seen.append((st, rig.message_label.text())))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=T)
    running = [text for st, text in seen if st.value == "running"]
    assert running and all("stopped by STOP" not in text for text in running)
    assert "stopped by STOP" not in rig.message_label.text()
    window.close()


def test_a_scan_paused_by_a_rig_alarm_says_so_only_until_the_rig_is_homed(qtbot, tmp_path):
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    simulator = window.state.devices["rig_simulator"]
    simulator.time_scale = 0.0
    set_up_scan(scan, 3, 2, tmp_path / "alarm")
    simulator.inject("alarm_mid_move")
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.state.value == "paused", timeout=T)
    qtbot.waitUntil(lambda: "alarm" in scan.state_label.text().lower(), timeout=T)
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.state is RigState.ALARM, timeout=T)
    assert "e06060" in scan.state_label.text()                  # red while the alarm lasts
    simulator.clear_faults()
    rig.home()
    qtbot.waitUntil(lambda: rig.last_status.homed and rig.last_status.state is RigState.IDLE, timeout=T)
    qtbot.waitUntil(lambda: "alarm" not in scan.state_label.text().lower(), timeout=T)
    assert "press Resume" in scan.state_label.text() and "e06060" not in scan.state_label.text()
    assert scan.resume_button.isEnabled()
    qtbot.mouseClick(scan.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=T)
    assert Dataset.open(tmp_path / "alarm").status_counts()["done"] == 6
    window.close()


def test_resume_the_scan_is_said_only_with_a_resume_button_that_works(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 6, 2, tmp_path / "aborted")
    start_then_pause(qtbot, panel)
    qtbot.mouseClick(panel.abort_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Aborted" in panel.state_label.text() and not panel.running, timeout=20000)
    assert "Resume the scan" in panel.state_label.text()
    assert panel.resume_button.isEnabled()
    qtbot.mouseClick(panel.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished</b>" in panel.state_label.text(), timeout=20000)
    assert Dataset.open(tmp_path / "aborted").status_counts()["done"] == 12
    assert not panel.resume_button.isEnabled()                  # nothing left to resume


def test_scan_log_follows_new_lines_when_at_its_end_like_a_terminal(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 2, 1, tmp_path / "log")
    panel.resize(420, 700)
    for i in range(200):                    # lines arriving while the panel is a tab behind another one
        panel._log(f"line {i}")
    panel.show()
    qtbot.waitExposed(panel)
    bar = panel.log_view.verticalScrollBar()
    qtbot.waitUntil(lambda: bar.maximum() > 0, timeout=5000)
    assert bar.value() == bar.maximum()     # shown at its newest line
    # a click in the text moves the text cursor: the log must still follow from its end
    qtbot.mouseClick(panel.log_view.viewport(), Qt.LeftButton, pos=QPoint(20, 10))
    bar.setValue(bar.maximum())
    for i in range(30):
        panel._log(f"more {i}")
    assert bar.value() == bar.maximum()
    assert panel.log_view.toPlainText().endswith("more 29")
    bar.setValue(0)                                             # scrolled back to read: stays there
    for i in range(30):
        panel._log(f"later {i}")
    assert bar.value() == 0
    bar.setValue(bar.maximum())
    panel._log("last")
    assert bar.value() == bar.maximum()


def test_live_view_placeholder_fits_and_follows_the_camera(qtbot):
    from lfstudio.gui.devices import QtDevice
    from lfstudio.gui.state import AppState
    from lfstudio.gui.views.live_view import LiveView
    from lfstudio.rig.worker import DeviceWorker
    from lfstudio.sim.instant import InstantCamera

    state = AppState()
    live = LiveView(state)
    qtbot.addWidget(live)
    live.resize(360, 420)
    live.show()
    qtbot.waitExposed(live)
    message = live.message
    assert message.isVisible() and "No camera connected" in message.text()
    area = live.graphics.rect()
    qtbot.waitUntil(lambda: area.contains(message.geometry()), timeout=5000)
    assert message.height() >= message.heightForWidth(message.width())     # every wrapped line shown

    cam = InstantCamera(lambda: (0.0, 0.0))
    cam.connect()
    device = QtDevice(DeviceWorker(cam, name="camera", status_method=None))
    try:
        state.set_device("camera", device)
        assert "No camera" not in message.text() and "connect one" not in message.text()
        assert "press Live" in message.text()
        live.resize(900, 420)
        qtbot.waitUntil(lambda: live.graphics.rect().contains(message.geometry())
                        and abs(message.geometry().center().x() - live.graphics.rect().center().x()) <= 2,
                        timeout=5000)
        state.set_device("camera", None)
        assert "No camera connected" in message.text()
    finally:
        device.close(disconnect=False)


def test_export_dialog_result_line_goes_with_its_options_and_the_layout_stays(qtbot, tiny_dataset, tmp_path):
    from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS
    from tests.gui.test_export_dialog import _open_dialog, _wait_estimate

    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.folder_edit.setText(str(tmp_path))
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
    _wait_estimate(qtbot, dialog)
    qtbot.waitExposed(dialog)

    def layout():
        return (dialog.picker.geometry(), dialog.export_button.mapTo(dialog, QPoint(0, 0)),
                dialog.format_combo.mapTo(dialog, QPoint(0, 0)))

    before = layout()
    qtbot.mouseClick(dialog.export_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: dialog.report is not None, timeout=60000)
    assert "Exported 15 views" in dialog.result_label.text()
    assert layout() == before                           # a result line takes the room kept for it
    for fmt in ("hevc", "hci", "colmap", "nerfstudio", "png"):
        dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index(fmt))
        assert dialog.result_label.text() == ""         # the line was about the other format's export
        _wait_estimate(qtbot, dialog)
        qtbot.waitUntil(lambda: layout() == before, timeout=5000)
    window.close()
