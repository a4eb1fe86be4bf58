"""The Rig panel on two emulated CiA 402 drives (dryve D1 over Modbus TCP, a real TCP server):
connect, home, the drives' power state, a drive fault named with its code and cleared with Reset
fault, STOP mid-move. Real worker thread, real Qt event loop."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt

from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.state import AppState
from lfstudio.rig.motion import RigState

T = 10000  # ms; the waits end as soon as the condition holds
RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"


def state_is(panel, state):
    return panel.last_status is not None and panel.last_status.state is state


@pytest.fixture
def panel(qtbot):
    p = RigPanel(AppState(simulated=True))
    p.sim_time_scale = 0.02
    qtbot.addWidget(p)
    p.show()
    p.rig_combo.setCurrentText(RIG_NAME)
    p.port_combo.setCurrentText("sim-dryve")
    yield p
    p.shutdown()


def test_drive_state_fault_reset_and_stop(qtbot, panel):
    assert panel.rig_config.name == RIG_NAME and panel.chosen_port() == "sim-dryve"
    qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra, timeout=T)
    emulator = panel.state.devices["rig_simulator"]
    assert panel.drive_label.isVisible() and "switch on disabled" in panel.drive_label.text()
    assert not panel.last_status.homed and not panel.goto_button.isEnabled()

    qtbot.mouseClick(panel.home_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE) and panel.last_status.homed, timeout=T)
    assert panel.drive_label.text() == "Drives — x: operation enabled · y: operation enabled"

    emulator.pair.axes[0].inject("following_error")             # the horizontal axis jams on the next move
    panel.goto_x.setValue(500)
    panel.goto_y.setValue(100)
    qtbot.mouseClick(panel.goto_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.ALARM), timeout=T)
    qtbot.waitUntil(lambda: "8611h" in panel.message_label.text(), timeout=T)
    assert "x: fault 8611h" in panel.drive_label.text()
    assert panel.recover_button.isVisible() and panel.recover_button.text() == "Reset fault"

    emulator.pair.axes[0].clear_faults()                         # the obstruction removed
    qtbot.mouseClick(panel.recover_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.last_status.state is not RigState.ALARM, timeout=T)
    assert not panel.last_status.homed and "fault" not in panel.drive_label.text()
    qtbot.mouseClick(panel.home_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE) and panel.last_status.homed, timeout=T)

    emulator.time_scale = 0.5                                    # slow enough to catch it moving
    panel.goto_x.setValue(3000)
    panel.goto_y.setValue(400)
    qtbot.mouseClick(panel.goto_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: state_is(panel, RigState.MOVING), timeout=T)
    qtbot.mouseClick(panel.stop_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "stopped by STOP" in panel.message_label.text(), timeout=T)
    qtbot.waitUntil(lambda: state_is(panel, RigState.IDLE), timeout=T)
    x, y = panel.last_status.position_mm
    assert x < 3000 and y < 400 and panel.last_status.homed
    assert emulator.true_position_mm() == pytest.approx((x, y), abs=0.011)


def test_keep_drive_reference_is_an_explicit_action_shown_in_the_badge(qtbot, panel, tmp_path):
    """Drives found enabled but never homed by this connection are not homed (issue 38); the operator
    may keep their reference with the panel's own button: logged, and the badge says so."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.simulated import start_drive_emulator

    from lfstudio.gui.rig_badge import RigBadge

    emulator = start_drive_emulator(load_rig(RIG_NAME), "modbus", time_scale=0.0, setup={"enabled_unhomed": True})
    badge = RigBadge(panel.state)
    qtbot.addWidget(badge)
    try:
        panel.port_combo.setEditText(emulator.word)
        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra, timeout=T)
        assert "operation enabled" in panel.drive_label.text() and not panel.last_status.homed
        assert "not homed" in panel.state_label.text() and not panel.goto_button.isEnabled()
        assert panel.keep_button.isVisible() and panel.keep_button.isEnabled() and panel.keep_action.isEnabled()
        qtbot.waitUntil(lambda: badge.text() == "Rig: not homed", timeout=T)
        assert "Keep the drives' reference" in badge.toolTip()
        qtbot.mouseClick(panel.keep_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status.homed, timeout=T)
        qtbot.waitUntil(lambda: badge.text() == "Rig: reference kept from the drive", timeout=T)
        assert "did not home them" in badge.toolTip()
        assert panel.state_label.text() == "reference kept\nfrom the drive"
        assert not panel.keep_button.isVisible() and panel.goto_button.isEnabled()
        panel.resize(420, 700)
        panel.grab().save(str(tmp_path / "keep.png"))
    finally:
        panel.shutdown()
        emulator.close()
