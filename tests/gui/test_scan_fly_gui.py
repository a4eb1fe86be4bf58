"""The Scan panel's 'Continuous motion' choice (#40): it reaches the scan session (a fly scan), and a
refusal names the window's own control, not the command line's --fly."""

from __future__ import annotations

from PySide6.QtCore import Qt

from tests.gui.test_scan_gui import scan_panel


def test_continuous_motion_reaches_the_session_and_its_refusal_names_the_control(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "fly")
    panel.time_scale.setValue(0.5)
    assert not panel.fly.isChecked() and "continuous motion" not in panel.summary.text()
    panel.fly.setChecked(True)
    assert "continuous motion, hardware trigger where" in panel.summary.text()
    assert "the row speed is chosen at Start" in panel.summary.text()
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: bool(errors), timeout=20000)
    message = errors[-1]
    assert "Continuous motion" in message and "no triggered frames" in message
    assert "--fly" not in message
    assert not (tmp_path / "fly" / "dataset.json").exists()
    assert cam.captures == 0


def test_continuous_motion_is_locked_while_a_scan_runs(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 30, 2, tmp_path / "step")
    panel.time_scale.setValue(0.0)
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.running, timeout=10000)
    assert not panel.fly.isEnabled()
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=30000)
    qtbot.waitUntil(panel.fly.isEnabled, timeout=10000)      # the choice is the operator's again


def test_keep_on_card_reaches_the_session_and_its_refusal_names_the_control(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "card")
    panel.time_scale.setValue(0.0)
    panel.keep_on_card.setChecked(True)
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: bool(errors), timeout=20000)
    assert "Keep pictures on the camera's card" in errors[-1] and "--keep-on-card" not in errors[-1]
    assert not (tmp_path / "card" / "dataset.json").exists()


def test_the_planners_fly_speed_reaches_the_scan_request(qtbot, tmp_path, instant_devices, scan_requests):
    """The Planner's Fly speed is the scan's row speed (it was dropped: the scan flew at the fastest)."""
    from dataclasses import replace

    from lfstudio.planning.presets import reference_plan

    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "speed")
    panel.time_scale.setValue(0.5)
    state.set_plan(replace(reference_plan(), grid_columns=4, grid_rows=2, spacing_mm=(4.0, 6.0), fly_speed_mm_s=7.5))
    panel.fly.setChecked(True)
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(panel.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: bool(errors), timeout=20000)
    assert scan_requests and scan_requests[-1].fly and scan_requests[-1].fly_speed_mm_s == 7.5
    assert "Continuous motion" in errors[-1]        # the instant camera has no triggers
