"""The Scan panel's Trigger choice for a continuous-motion scan (#40; `lfstudio scan --trigger
auto|hardware|software`): offered with Continuous motion, remembered, shown in the summary, reaching the
scan session, and a hardware trigger the devices cannot give refused naming the panel's own control."""

from __future__ import annotations

from PySide6.QtCore import Qt

from lfstudio.gui.panels.scan import ScanPanel
from tests.gui.conftest import close_devices, window_devices
from tests.gui.test_scan_gui import scan_panel
from tests.scan.test_fly_refused_line import garble_the_first_row


def _choose(qtbot, panel, key: str) -> None:
    """Pick ``key`` in the Trigger list with the keyboard, as an operator would."""
    combo = panel.trigger
    assert combo.isEnabled()
    for _ in range(combo.count()):
        if combo.currentData() == key:
            return
        qtbot.keyClick(combo, Qt.Key.Key_Down if combo.findData(key) > combo.currentIndex() else Qt.Key.Key_Up)
    assert combo.currentData() == key


def test_the_trigger_is_offered_with_continuous_motion_remembered_and_summarised(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "ds")
    assert [panel.trigger.itemData(i) for i in range(panel.trigger.count())] == ["auto", "hardware", "software"]
    assert panel.trigger.currentData() == "auto" and not panel.trigger.isEnabled()   # a step scan has no trigger
    panel.fly.setChecked(True)
    assert panel.trigger.isEnabled()
    assert "continuous motion, hardware trigger where the rig and the camera can, else software" in panel.summary.text()
    _choose(qtbot, panel, "hardware")
    assert "continuous motion, hardware trigger (the controller's output)" in panel.summary.text()
    again = ScanPanel(state)                         # the window opened again: the choice is remembered
    qtbot.addWidget(again)
    assert again.trigger.currentData() == "hardware"
    again.fly.setChecked(True)
    _choose(qtbot, again, "software")
    third = ScanPanel(state)
    qtbot.addWidget(third)
    assert third.trigger.currentData() == "software"


def test_the_trigger_choice_reaches_the_scan_request(qtbot, tmp_path, instant_devices, scan_requests):

    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "ds")
    panel.time_scale.setValue(0.5)
    panel.fly.setChecked(True)
    _choose(qtbot, panel, "software")
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    qtbot.mouseClick(panel.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: bool(errors), timeout=20000)     # the instant camera has no triggers at all
    assert scan_requests and scan_requests[-1].fly and scan_requests[-1].fly_trigger == "software"


def test_hardware_chosen_but_the_devices_cannot_is_refused_naming_the_trigger_list(qtbot, tmp_path, monkeypatch):
    """The simulated studio with GRBL's laser mode off ($32 = 0): its spindle output cannot fire the camera
    during a move. Hardware chosen: Start is refused before the dataset is made, in the window's words."""
    import lfstudio.studio.simulated as simulated
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.devices import open_studio

    real = simulated.start_simulator

    def without_laser_mode(*args, **kwargs):
        sim = real(*args, **kwargs)
        sim.set_settings({32: 0})
        return sim

    monkeypatch.setattr(simulated, "start_simulator", without_laser_mode)
    rig_config = load_rig()
    plan = ScanPlan.centered(4, 2, (4.0, 6.0), rig_config)
    studio = open_studio("sim", "sim", rig_config, time_scale=0.5, exposure_s=0.001, transfer_s=0.05,
                         view_region_mm=plan.extent_mm(), sim_width_px=64)
    devices = window_devices(studio.rig, studio.camera)
    try:
        state, panel = scan_panel(qtbot, devices, 4, 2, tmp_path / "ds")
        panel.fly.setChecked(True)
        _choose(qtbot, panel, "hardware")
        errors = []
        state.errorOccurred.connect(lambda title, message: errors.append(message))
        qtbot.mouseClick(panel.start_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: bool(errors), timeout=60000)
        message = errors[-1]
        assert message.startswith("Trigger: no hardware trigger: GRBL's laser mode is off ($32 = 0)"), message
        assert "Software or Automatic in the Scan panel's Trigger list" in message
        assert "--trigger" not in message and "--" not in message
        assert not (tmp_path / "ds" / "dataset.json").exists()
    finally:
        close_devices(devices)
        studio.close()


def test_a_line_grbl_refuses_mid_row_pauses_naming_the_line_and_where_the_carriage_stopped(qtbot, tmp_path,
                                                                                          monkeypatch):
    """A hardware-triggered fly row on the simulated studio, one of its lines garbled on the way to GRBL:
    the Scan panel's message (and the box the window raises) says which line GRBL refused, as sent, its
    error and GRBL's meaning, and where the carriage stopped, position kept; not the "Check the axis
    controller's cable, power and alarms" of a rig that stopped answering."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.devices import open_studio

    sent = garble_the_first_row(monkeypatch,        # row 0's 3rd view: its line bringing the output low
                                lambda lines: [line for line in lines if line.endswith(" S0")][2])
    rig_config = load_rig()
    centred = ScanPlan.centered(6, 2, (4.0, 6.0), rig_config).origin_mm
    near_home = (30.0 - centred[0], 30.0 - centred[1])          # the grid 30 mm from home: no 2 m to cross
    plan = ScanPlan.centered(6, 2, (4.0, 6.0), rig_config, offset_mm=near_home)
    studio = open_studio("sim", "sim", rig_config, time_scale=0.5, exposure_s=0.001, transfer_s=0.05,
                         view_region_mm=plan.extent_mm(), sim_width_px=64)
    devices = window_devices(studio.rig, studio.camera)
    try:
        state, panel = scan_panel(qtbot, devices, 6, 2, tmp_path / "ds")
        panel.offset_h.setValue(near_home[0])
        panel.offset_v.setValue(near_home[1])
        panel.fly.setChecked(True)
        _choose(qtbot, panel, "hardware")
        errors = []
        state.errorOccurred.connect(lambda title, message: errors.append((title, message)))
        qtbot.mouseClick(panel.start_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: bool(errors), timeout=120000)
        title, message = errors[-1]
        bad = [line for line in sent[0] if line.endswith(" S0")][2].replace("G1 X", "G1 X#", 1)
        number = [line.replace("G1 X", "G1 X#", 1) for line in sent[0]].index(bad) + 1
        said = (f'Flying row 0: GRBL refused line {number} of {len(sent[0])} of the fly row, "{bad}", with '
                "error:2 (bad number format or missing value); the carriage stopped at x = ")
        assert title == "Scan paused" and message.startswith(said), message
        assert " mm, position kept (GRBL goes on with the lines after a refused one" in message, message
        assert "cable" not in message and "--" not in message
        qtbot.waitUntil(lambda: said in panel.state_label.text(), timeout=10000)
        assert "Paused" in panel.state_label.text()
        panel.abort_button.click()
        qtbot.waitUntil(lambda: not panel.running, timeout=60000)
    finally:
        close_devices(devices)
        studio.close()
