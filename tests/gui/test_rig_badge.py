"""The rig's state in the window's toolbar, seen from every layout: the simulated rig on a real pty,
homed from the Rig menu while the Rig panel is a hidden tab behind the Planner (before, nothing in
sight changed while it homed, and the Rig panel said "idle" afterwards, never "homed"). The Scan
panel's Simulation time scale paces the simulated rig outside a scan too (at 0, homing took 9 s)."""

from __future__ import annotations

from PySide6.QtCore import QPoint, QRect, Qt

from lfstudio.gui.app import create_window
from lfstudio.gui.rig_badge import badge_word
from lfstudio.rig.motion import RigState, RigStatus
from lfstudio.rig.worker import DeviceFault

T = 20000


def test_badge_words():
    assert badge_word(None) == "disconnected"
    assert badge_word(RigStatus(RigState.DISCONNECTED)) == "disconnected"
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=False)) == "not homed"
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=True)) == "homed"
    # CiA 402 drives whose own reference the operator kept (issue 38)
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=True, extra={"reference": "kept"})) == \
        "reference kept from the drive"
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=True, extra={"reference": "homed"})) == "homed"
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=False), homing=True) == "homing"
    assert badge_word(RigStatus(RigState.HOMING, (0, 0))) == "homing"
    assert badge_word(RigStatus(RigState.MOVING, (0, 0), homed=True)) == "moving"
    assert badge_word(RigStatus(RigState.JOGGING, (0, 0), homed=True)) == "moving"
    assert badge_word(RigStatus(RigState.IDLE, (0, 0), homed=True), moving=True) == "moving"
    assert badge_word(RigStatus(RigState.ALARM, (0, 0), extra={"locked": True, "alarm_code": 2})) == "alarm"
    assert badge_word(RigStatus(RigState.ALARM, (0, 0), extra={"locked": True, "alarm_code": None})) == "not homed"
    assert badge_word(DeviceFault("rig", "serial port vanished")) == "fault"


def test_home_from_the_menu_with_the_rig_panel_hidden(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.setFixedSize(1366, 768)
    window.show()
    qtbot.waitExposed(window)
    badge, rig_dock = window.rig_badge, window.docks["rigDock"]
    assert badge.word == "disconnected" and badge.isVisible()
    window.panels["scanPanel"].time_scale.setValue(0.0)
    window.connect_simulated_studio()
    qtbot.waitUntil(lambda: badge.word == "not homed", timeout=T)
    simulator = window.state.devices["rig_simulator"]
    assert simulator.time_scale == 0.0                  # the Scan panel's time scale paces the rig too
    assert rig_dock.visibleRegion().isEmpty()           # the Rig panel is a tab behind the Planner
    words, messages = [], []
    badge.wordChanged.connect(words.append)
    window.state.statusMessage.connect(lambda text, _ms: messages.append(text))
    home = window.panels["rigDock"].home_action
    assert home in window.menu("Rig").actions()
    qtbot.waitUntil(home.isEnabled, timeout=T)         # once the connect call has returned
    home.trigger()
    qtbot.waitUntil(lambda: badge.word == "homed", timeout=T)
    assert words[0] == "homing" and words[-1] == "homed", words
    label = window.panels["rigDock"].state_label
    try:
        qtbot.waitUntil(lambda: label.text() == "homed", timeout=T)      # not "idle"
    except Exception:
        raise AssertionError(label.text())
    assert any("homing" in m for m in messages) and messages[-1] == "Rig homed", messages
    assert badge.isVisible() and window.rect().contains(QRect(badge.mapTo(window, QPoint(0, 0)), badge.size()))
    window.panels["scanPanel"].time_scale.setValue(0.5)
    assert simulator.time_scale == 0.5
    window.panels["scanPanel"].time_scale.setValue(2.0)
    assert simulator.time_scale == 1.0                  # never slower than the rig was started
    qtbot.mouseClick(badge, Qt.LeftButton)              # shows the Rig panel
    qtbot.waitUntil(lambda: not rig_dock.visibleRegion().isEmpty(), timeout=T)
    window.panels["rigDock"].disconnect_rig()
    qtbot.waitUntil(lambda: badge.word == "disconnected", timeout=T)
