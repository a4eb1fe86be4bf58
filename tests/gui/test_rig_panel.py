"""The Rig panel on the simulated rig: connect, home, jog (click, keys, hold), go-to, STOP mid-move,
a dropped connection and its recovery. Real pty, real worker thread, real Qt event loop."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt

from lfstudio.gui.devices import QtDevice
from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.state import AppState
from lfstudio.rig.motion import RigState

T = 10000  # ms; generous for a loaded machine, the waits end as soon as the condition holds


def pos(panel):
    return panel.last_status.position_mm


def state_is(panel, state):
    return panel.last_status is not None and panel.last_status.state is state


@pytest.fixture
def panel(qtbot):
    state = AppState(simulated=True)
    p = RigPanel(state)
    p.sim_time_scale = 0.02
    qtbot.addWidget(p)
    p.show()
    yield p
    p.shutdown()


def test_jog_and_stop_mid_move(qtbot, panel):
    assert panel.port_combo.currentText() == "Simulated GRBL"
    assert panel.stop_button.objectName() == "stopButton" and panel.stop_button.isVisible()
    qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.ALARM), timeout=T)   # a homing rig boots locked
    assert isinstance(panel.state.devices["rig"], QtDevice)
    sim = panel.state.devices["rig_simulator"]
    assert "home the rig" in panel.message_label.text()
    panel._connected("sim")     # the connect's result arriving after that first status (under load) keeps it
    assert "home the rig" in panel.message_label.text()
    assert not panel.goto_button.isEnabled()           # no motion before homing

    qtbot.mouseClick(panel.home_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE) and panel.last_status.homed, timeout=T)
    assert pos(panel) == (1.0, 1.0) and panel.x_label.text() == "1.000"   # home: 1 mm pull-off ($27)

    ten = next(b for b in panel.step_group.buttons() if b.property("step_mm") == 10.0)
    ten.setChecked(True)
    qtbot.mouseClick(panel.jog_buttons[(1, 0)], Qt.LeftButton)           # one 10 mm step right
    qtbot.waitUntil(lambda: pos(panel) == (11.0, 1.0) and state_is(panel, RigState.IDLE), timeout=T)
    panel.setFocus()
    qtbot.keyClick(panel, Qt.Key_Down, Qt.ShiftModifier)                 # fine step down
    qtbot.waitUntil(lambda: pos(panel) == (11.0, 1.1), timeout=T)

    sim.time_scale = 0.5                                                 # slow enough to catch it moving
    qtbot.mousePress(panel.jog_buttons[(1, 0)], Qt.LeftButton)           # hold: continuous jog
    qtbot.waitUntil(lambda: state_is(panel, RigState.JOGGING), timeout=T)
    qtbot.mouseRelease(panel.jog_buttons[(1, 0)], Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE), timeout=T)
    assert 11.0 < pos(panel)[0] < 4000.0

    panel.goto_x.setValue(3000)
    panel.goto_y.setValue(400)
    qtbot.mouseClick(panel.goto_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.MOVING), timeout=T)
    qtbot.mouseClick(panel.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "stopped by STOP" in panel.message_label.text(), timeout=T)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE), timeout=T)
    x, y = pos(panel)
    assert x < 3000 and y < 400 and panel.last_status.homed
    assert sim.reported_position_mm() == pytest.approx((x, y), abs=1e-3)


def test_dropped_connection_shows_message_and_recovers(qtbot, panel):
    panel.connect_rig()
    qtbot.waitUntil(lambda: state_is(panel, RigState.ALARM), timeout=T)
    old_sim = panel.state.devices["rig_simulator"]
    old_sim.inject("drop")
    qtbot.waitUntil(lambda: state_is(panel, RigState.DISCONNECTED), timeout=T)
    assert "connect again" in panel.message_label.text()
    assert panel.recover_button.isVisible() and panel.recover_button.text() == "Reconnect"
    qtbot.mouseClick(panel.recover_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.ALARM), timeout=T)
    assert panel.state.devices["rig_simulator"] is not old_sim
    assert not panel.recover_button.isVisible()
    panel.disconnect_rig()
    assert "rig" not in panel.state.devices and "rig_simulator" not in panel.state.devices


def test_rig_without_switches_sets_an_origin(qtbot, panel):
    panel.rig_combo.setCurrentText("Desktop slider 1 m")
    assert panel.goto_x.maximum() == 1000 and panel.goto_y.maximum() == 300
    panel.connect_rig()
    assert not panel.rig_combo.isEnabled()
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE), timeout=T)
    assert not panel.home_button.isEnabled() and not panel.goto_button.isEnabled()
    assert "set the origin" in panel.message_label.text()
    qtbot.mouseClick(panel.origin_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.last_status is not None and panel.last_status.homed, timeout=T)
    panel.goto_x.setValue(500)
    panel.goto_y.setValue(100)
    qtbot.mouseClick(panel.goto_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: pos(panel) == (500.0, 100.0) and state_is(panel, RigState.IDLE), timeout=T)
    assert panel.message_label.text() == ""


def test_controller_and_profile_disagreeing_is_a_wrapping_warning_line_that_goes_with_its_cause(qtbot, panel):
    """The reference gantry's controller (GRBL simulator on a pty) connected under the desktop slider's
    profile: the driver's warnings (speeds, homing) show in the panel, wrapped; disconnected they go,
    and reconnected under the matching profile none comes back."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.simulated import start_simulator

    controller = start_simulator(load_rig("Reference gantry"), time_scale=0.02)
    try:
        panel.resize(360, 1000)
        assert not panel.warning_label.isVisible()
        panel.rig_combo.setCurrentText("Desktop slider 1 m")
        panel.port_combo.setEditText(controller.port)
        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.warning_label.isVisible(), timeout=T)
        text = panel.warning_label.text()
        warnings = panel.last_status.extra["warnings"]
        assert text.startswith("⚠ Controller and rig profile disagree:") and len(warnings) == 6
        assert f"• {warnings[0]}" in text and f"• {warnings[1]}" in text and "the rig profile says 50 mm/s" in text
        assert text.endswith("… and 4 more (point here to read them all)") and f"• {warnings[2]}" not in text
        assert all(f"• {w}" in panel.warning_label.toolTip() for w in warnings)
        assert "homing is on in the controller" in panel.warning_label.toolTip()
        assert panel.warning_label.wordWrap() and panel.warning_label.width() <= panel.width()
        assert panel.warning_label.height() >= 5 * panel.warning_label.fontMetrics().height()   # wrapped lines
        panel.grab().save("/tmp/leftovers-rig-warnings.png")

        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)                   # disconnect: no controller
        qtbot.waitUntil(lambda: not panel.connected, timeout=T)
        assert not panel.warning_label.isVisible() and panel.warning_label.text() == ""
        assert "•" not in panel.warning_label.toolTip()
        panel.rig_combo.setCurrentText("Reference gantry")                      # the cause fixed
        panel.port_combo.setEditText(controller.port)
        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status is not None and panel.last_status.state is not RigState.DISCONNECTED,
                        timeout=T)
        assert panel.last_status.extra["warnings"] == [] and not panel.warning_label.isVisible()
    finally:
        panel.shutdown()
        controller.close()


def test_a_port_that_cannot_be_opened_is_told_in_the_window_s_words(qtbot, panel, tmp_path):
    """The message named the command line ('lfstudio rig --port ...') in the window."""
    port = str(tmp_path / "ttyUSB9")
    panel.port_combo.setEditText(port)
    with qtbot.waitSignal(panel.state.errorOccurred, timeout=T) as shown:
        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
    title, message = shown.args
    assert title == "Rig" and f"cannot open the rig port {port!r}" in message, message
    assert "No such file or directory" in message and "Port list" in message and "Simulated" in message
    assert "--port" not in message and "lfstudio rig" not in message, message
    qtbot.waitUntil(lambda: panel.connect_button.text() == "Connect", timeout=T)   # nothing left half-connected


def test_the_panel_shows_the_profile_with_its_descriptions(panel):
    """One description per parameter: the Rig panel tells the profile's settings with the labels and
    units of their descriptions, and its Go-to fields hold exactly the profile's soft limits."""
    from lfstudio.rig.profile import AXIS_PARAMS, RIG_PARAMS

    tip = panel.rig_combo.toolTip()
    cfg = panel.rig_config
    for key, param in AXIS_PARAMS.items():
        if param.group == "motion" and key != "letter":
            h, v = getattr(cfg.horizontal, key), getattr(cfg.vertical, key)
            assert f"{param.label}: {h:g} {param.number.unit} × {v:g} {param.number.unit}" in tip, key
    assert f"{RIG_PARAMS['driver'].label}: {cfg.driver}" in tip and "rigs.toml" in tip
    for spin, axis in ((panel.goto_x, cfg.horizontal), (panel.goto_y, cfg.vertical)):
        assert (spin.minimum(), spin.maximum()) == (axis.soft_min_mm, axis.soft_max_mm)
        assert spin.suffix() == f" {AXIS_PARAMS['soft_min_mm'].number.unit}"
    panel.rig_combo.setCurrentText("Desktop slider 1 m")
    assert panel.rig_config.name == "Desktop slider 1 m" and "Limit switches: no" in panel.rig_combo.toolTip()
    assert panel.goto_x.maximum() == panel.rig_config.horizontal.soft_max_mm
