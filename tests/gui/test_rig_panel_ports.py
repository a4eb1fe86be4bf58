"""The Rig panel's Port list and the rig profile that fits the port (issue 41, items 4 and 12): the
profile follows a chosen port as on the CLI, a remembered port/profile pair that no longer fits is
fallen back from in the panel (never a message box), messages name the window's controls, the state
is not green while not homed, and the Dataset menu's Re-capture needs a selection. Real Qt loop."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt

from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState
from lfstudio.rig.motion import RigState, RigStatus
from lfstudio.rig.profile import DEFAULT_DRIVE_RIG, DEFAULT_RIG

T = 10000  # ms; the waits end as soon as the condition holds


def make_panel(qtbot, simulated=True):
    p = RigPanel(AppState(simulated=simulated))
    p.sim_time_scale = 0.02
    qtbot.addWidget(p)
    p.resize(420, 900)
    p.show()
    return p


def pick_port(panel, word):
    """Choose the list entry of device word ``word`` as an operator does (the list's activation)."""
    index = panel.port_combo.findData(word)
    assert index >= 0, word
    panel.port_combo.setCurrentIndex(index)
    panel.port_combo.activated.emit(index)


def test_the_simulated_ports_are_spelt_alike():
    """The list mixed "Simulated" and "sim-dryve"."""
    from lfstudio.gui.panels.rig import simulated_ports

    texts = [text for text, _, _ in simulated_ports()]
    assert texts[:2] == ["Simulated GRBL", "Simulated drives"]         # the registered simulated rig kinds
    assert all(t.startswith("Simulated ") for t in texts) and len(set(texts)) == len(texts)
    assert not any("-" in t for t in texts)


def test_choosing_the_simulated_drives_picks_their_profile_and_connects(qtbot):
    panel = make_panel(qtbot)
    try:
        assert panel.rig_config.name == DEFAULT_RIG and panel.chosen_port() == "sim"
        pick_port(panel, "sim-dryve")
        assert panel.chosen_port() == "sim-dryve" and panel.port_combo.currentText() == "Simulated drives"
        assert panel.rig_config.name == DEFAULT_DRIVE_RIG == panel.rig_combo.currentText()
        assert panel.profile_note.isVisible() and DEFAULT_DRIVE_RIG in panel.profile_note.text()
        assert settings().value("rig/profile") == DEFAULT_DRIVE_RIG
        with qtbot.assertNotEmitted(panel.state.errorOccurred):
            qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
            qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra,
                            timeout=T)
        assert settings().value("rig/port") == "sim-dryve"
        panel.disconnect_rig()
        pick_port(panel, "sim")                  # back to the GRBL simulator: the gantry's profile again
        assert panel.rig_config.name == DEFAULT_RIG and DEFAULT_RIG in panel.profile_note.text()
        assert "is for CiA 402 drives" in panel.profile_note.text()
    finally:
        panel.shutdown()


def test_typed_sim_dryve_with_the_gantry_profile_connects_without_a_box(qtbot):
    """Disconnect → Port sim-dryve → Connect opened a box in command-line words (--rig-profile ...)."""
    panel = make_panel(qtbot)
    try:
        panel.port_combo.setEditText("sim-dryve")
        assert panel.rig_config.name == DEFAULT_RIG
        with qtbot.assertNotEmitted(panel.state.errorOccurred):
            qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
            qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra,
                            timeout=T)
        assert panel.rig_config.name == DEFAULT_DRIVE_RIG
    finally:
        panel.shutdown()


@pytest.mark.parametrize("remembered_port", ["Simulated", "sim"])
def test_a_remembered_pair_that_no_longer_fits_falls_back_in_the_panel(qtbot, remembered_port):
    """At the next start the port was back to Simulated with the drives' profile remembered: a message
    box at every start ("'sim' is not a drive pair ...")."""
    s = settings()
    s.setValue("rig/profile", DEFAULT_DRIVE_RIG)
    s.setValue("rig/port", remembered_port)
    s.sync()
    panel = make_panel(qtbot)
    try:
        assert panel.chosen_port() == "sim" and panel.rig_config.name == DEFAULT_RIG
        note = panel.profile_note.text()
        assert panel.profile_note.isVisible() and "remembered" in note and DEFAULT_DRIVE_RIG in note, note
        with qtbot.assertNotEmitted(panel.state.errorOccurred):
            panel.connect_rig()                     # as the simulated studio does at start
            qtbot.waitUntil(lambda: panel.last_status is not None
                            and panel.last_status.state is RigState.ALARM, timeout=T)
        assert panel.profile_note.isVisible()       # still said after the connection
    finally:
        panel.shutdown()


def test_the_simulated_drives_remembered_come_back(qtbot):
    settings().setValue("rig/profile", DEFAULT_DRIVE_RIG)
    settings().setValue("rig/port", "sim-dryve")
    panel = make_panel(qtbot)
    try:
        assert panel.chosen_port() == "sim-dryve" and panel.rig_config.name == DEFAULT_DRIVE_RIG
        assert not panel.profile_note.isVisible()
    finally:
        panel.shutdown()


def test_real_drives_with_a_gantry_profile_ask_for_the_profile_in_the_window_s_words(qtbot):
    panel = make_panel(qtbot, simulated=False)
    try:
        panel.port_combo.setEditText("dryve:127.0.0.1:15020,127.0.0.1:15021")
        with qtbot.assertNotEmitted(panel.state.errorOccurred):
            qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
        message = panel.message_label.text()
        assert panel.device is None and panel.connect_button.text() == "Connect"
        assert "Rig list" in message and DEFAULT_DRIVE_RIG in message and "--" not in message, message
        assert panel.rig_config.name == DEFAULT_RIG             # never guessed for real drives
    finally:
        panel.shutdown()


def test_a_profile_that_does_not_fit_says_so_in_the_window_s_words():
    from lfstudio.errors import InputError, window_message
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig

    for port, profile in (("sim", DEFAULT_DRIVE_RIG), ("sim-dryve", DEFAULT_RIG)):
        with pytest.raises(InputError) as info:
            open_rig(port, load_rig(profile), connect=False, lock=False)
        assert "--rig-profile" in str(info.value)                   # the CLI's words on the CLI
        text = window_message(info.value)
        assert "--" not in text and "Rig list" in text, text        # the window's in the window


@pytest.mark.parametrize("size", [(1366, 768), (1920, 1080)])
def test_a_long_error_is_wrapped_whole_in_the_panel(qtbot, size, tmp_path):
    """The red error in the Rig panel was clipped."""
    from lfstudio.gui.app import create_window

    window = create_window(simulated=False)
    qtbot.addWidget(window)
    window.resize(*size)
    window.show()
    panel = window.panels["rigDock"]
    window.docks["rigDock"].raise_()
    panel._show_message("cannot open the rig port '/dev/ttyUSB9': No such file or directory (errno 2). Check "
                        "the cable and choose the controller's port in the Rig panel's Port list (↻ looks for "
                        "ports again), or 'Simulated GRBL'", "error")
    label = panel.message_label
    qtbot.waitUntil(lambda: label.height() >= label.heightForWidth(label.width()) > 0, timeout=T)
    window.grab().save(str(tmp_path / f"rig-error-{size[0]}.png"))
    assert label.height() >= label.heightForWidth(label.width())


def test_idle_but_not_homed_is_not_green(qtbot):
    panel = make_panel(qtbot)
    try:
        panel._on_status(RigStatus(RigState.IDLE, position_mm=(0.0, 0.0), homed=False))
        assert panel.state_label.text() == "idle\nnot homed"
        assert "#2e7d32" not in panel.state_label.styleSheet() and "#b35900" in panel.state_label.styleSheet()
        panel._on_status(RigStatus(RigState.IDLE, position_mm=(0.0, 0.0), homed=True))
        assert panel.state_label.text() == "homed" and "#2e7d32" in panel.state_label.styleSheet()
    finally:
        panel.shutdown()


def test_recapture_in_the_dataset_menu_needs_a_selection(qtbot, tiny_dataset):
    from lfstudio.gui.app import create_window

    window = create_window(simulated=False)
    qtbot.addWidget(window)
    window.show()
    grid = window.central
    window.state.set_dataset(tiny_dataset)
    action = grid.recapture_action
    assert action is not None and action in window.menu("Dataset").actions()
    assert not action.isEnabled() and not grid.recapture_button.isEnabled()
    qtbot.keyClick(grid.canvas, Qt.Key_A, Qt.ControlModifier)             # select every view
    assert action.isEnabled()
    with qtbot.waitSignal(window.state.recaptureRequested, timeout=2000) as sig:
        action.trigger()
    assert len(sig.args[0]) == 15
    assert not action.isEnabled()


def test_homing_the_drives_shows_each_drive_s_progress(qtbot):
    """Homing the simulated drives showed nothing but "homing" for its whole run (issue 41, item 5)."""
    settings().setValue("rig/profile", DEFAULT_DRIVE_RIG)
    settings().setValue("rig/port", "sim-dryve")
    panel = make_panel(qtbot)
    try:
        panel.connect_rig()
        qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra, timeout=T)
        panel.state.devices["rig_simulator"].time_scale = 0.1      # x homes in about 4 s, y in about 1 s
        qtbot.mouseClick(panel.home_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: "x: operation enabled, homing" in panel.drive_label.text()
                        and "y: operation enabled, at reference" in panel.drive_label.text(), timeout=3 * T)
        qtbot.waitUntil(lambda: panel.last_status.homed and panel.last_status.state is RigState.IDLE, timeout=3 * T)
        assert "homing" not in panel.drive_label.text()
    finally:
        panel.shutdown()
