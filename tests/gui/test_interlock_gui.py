"""The window while a scan owns the rig and the camera, on a real Qt event loop: motion controls locked
(and nothing from the GUI reaches the simulated controller), the Camera panel's test shot and settings
locked (and nothing reaches the camera), STOP always in sight and working whatever the panel layout,
and quitting during a scan asks first (Cancel keeps scanning; Stop lets the view finish)."""

from __future__ import annotations

import threading

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QDockWidget

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.panels import camera as camera_panel
from lfstudio.gui.panels.scan import ACTIVE_KEY
from lfstudio.gui.settings import settings
from lfstudio.rig.motion import RigState
from lfstudio.rig.profile import load_rig
from lfstudio.resources import user_config_dir
from lfstudio.scan.events import ScanState
from lfstudio.sim.instant import InstantRig
from tests.gui.conftest import close_devices, window_devices
from tests.scan.test_engine_states import HeldCamera

T = 60000  # ms; generous for a loaded machine, the waits end as soon as the condition holds


def motion_controls(rig):
    return {"jog": list(rig.jog_buttons.values()), "go": [rig.goto_button], "home": [rig.home_button, rig.home_action],
            "origin": [rig.origin_button, rig.origin_action], "recover": [rig.recover_action],
            "connect": [rig.connect_button, rig.connect_action]}


#: the simulated rigs a window test can run on: GRBL 1.1h's protocol on a pty, a dryve D1 pair over Modbus TCP
RIGS = {"sim": None, "sim-dryve": "dryve D1 gantry 4 m x 0.5 m"}


def homed_simulated_studio(qtbot, rig_word: str = "sim"):
    """The window with the simulated camera and a homed simulated rig: ``rig_word`` "sim" (the GRBL
    simulator, File's simulated studio) or "sim-dryve" (emulated CiA 402 drives, chosen in the Rig
    panel with their profile, as an operator does)."""
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    rig, camera, scan = (window.panels[n] for n in ("rigDock", "cameraDock", "scanPanel"))
    camera.sim_width.setValue(min(camera.sim_width.value(), 320))
    rig.sim_time_scale = 0.02
    if RIGS[rig_word] is None:
        window.connect_simulated_studio()
    else:
        rig.rig_combo.setCurrentText(RIGS[rig_word])
        rig.port_combo.setCurrentText(rig_word)
        rig.connect_rig()
        qtbot.waitUntil(lambda: rig.home_button.isEnabled(), timeout=T)
        camera.connect_camera()
    qtbot.waitUntil(lambda: camera.connected and "Connected" in camera.status_label.text(), timeout=T)
    qtbot.waitUntil(lambda: rig.home_button.isEnabled(), timeout=T)
    rig.home()
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.homed
                    and rig.last_status.state is RigState.IDLE, timeout=T)
    return window, rig, camera, scan


def test_motion_controls_are_locked_while_a_scan_runs_on_the_simulated_studio(qtbot, tmp_path):
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    simulator = window.state.devices["rig_simulator"]
    controls = motion_controls(rig)
    assert all(w.isEnabled() for ws in controls.values() for w in ws)          # free before the scan
    assert not rig.lock_label.isVisible() and window.scan_lock_label.text() == ""

    scan.columns.setValue(3)
    scan.rows.setValue(2)
    scan.settle.setValue(0.0)
    scan.time_scale.setValue(1.0)       # real time: the first move, from the home corner to the grid, takes seconds
    scan.folder.setText(str(tmp_path / "locked"))
    records_before, lines_before = len(simulator.records), len(simulator.lines_received)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: window.state.scan_owns_rig, timeout=T)
    engine = scan.engine
    assert window.state.devices["rig"].worker.holder == engine.label        # the core interlock is on

    for name, widgets in controls.items():
        for w in widgets:
            assert not w.isEnabled(), name
            assert f"Disabled while {engine.label} runs" in w.toolTip(), name
    assert rig.lock_label.isVisible() and engine.label in rig.lock_label.text()
    assert engine.label[1:] in window.scan_lock_label.text() and "locked" in window.scan_lock_label.text()
    assert window.stop_button.isVisible() and window.stop_button.isEnabled()

    # every way in from the GUI: disabled buttons, keys, menu entries, and a command sent anyway
    qtbot.mouseClick(rig.jog_buttons[(1, 0)], Qt.LeftButton)
    qtbot.mouseClick(rig.goto_button, Qt.LeftButton)
    rig.setFocus()
    qtbot.keyClick(rig, Qt.Key_Right)
    assert "Disabled while" in window.statusBar().currentMessage()
    rig.home_action.trigger()
    rig.origin_action.trigger()
    refused = []
    window.state.devices["rig"].run("jog", 5.0, 0.0, on_error=refused.append)
    qtbot.waitUntil(lambda: len(refused) == 1, timeout=T)
    assert f"in use by {engine.label}" in refused[0] and "STOP is always available" in refused[0]

    simulator.time_scale = 0.0                                  # now let the scan finish quickly
    window.state.devices["camera"].driver.time_scale = 0.0      # (the simulator's knob: the worker is leased)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=T)
    qtbot.waitUntil(lambda: not window.state.scan_owns_rig, timeout=T)
    assert engine.state is ScanState.FINISHED and Dataset.open(tmp_path / "locked").status_counts()["done"] == 6

    # nothing but the scan's own moves reached the controller
    moves = simulator.records[records_before:]
    assert [m.kind for m in moves] != [] and "jog" not in {m.kind for m in moves}
    targets = [c for m in moves for c in m.target_mm]
    assert targets == pytest.approx([c for v in engine.plan.views() for c in v.position_mm], abs=1e-3)
    sent = [line.strip().upper() for line in simulator.lines_received[lines_before:]]
    assert not [line for line in sent if line.startswith(("$J", "$H", "G10", "G92"))]

    # and the controls come back
    qtbot.waitUntil(lambda: rig.goto_button.isEnabled(), timeout=T)
    assert all(w.isEnabled() for ws in controls.values() for w in ws)
    assert not rig.lock_label.isVisible() and window.scan_lock_label.text() == ""
    assert "Disabled while" not in rig.home_button.toolTip()
    window.close()


def camera_controls(camera):
    return {"test shot": [camera.shot_button, camera.shot_action], "apply": [camera.apply_button],
            "connect": [camera.connect_button, camera.connect_action]}


def test_camera_controls_are_locked_while_a_scan_owns_the_camera_and_a_test_shot_is_refused(qtbot, tmp_path):
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    device = window.state.devices["camera"]
    device.worker.call("set_setting", "time_scale", 0.0)
    driver = device.driver
    entered, gate = threading.Semaphore(0), threading.Semaphore(0)
    plain_capture = driver.capture

    def held_capture(stem_path, on_exposed=None):               # each of the scan's captures waits for the test
        entered.release()
        assert gate.acquire(timeout=T / 1000), "the test never released the capture"
        return plain_capture(stem_path, on_exposed=on_exposed)
    driver.capture = held_capture
    controls = camera_controls(camera)
    qtbot.waitUntil(lambda: camera.shot_button.isEnabled(), timeout=T)
    assert all(w.isEnabled() for ws in controls.values() for w in ws)           # free before the scan
    assert not camera.lock_label.isVisible()
    shots = user_config_dir() / "test_shots"
    before = sorted(shots.glob("*")) if shots.is_dir() else []

    scan.columns.setValue(2)
    scan.rows.setValue(1)
    scan.settle.setValue(0.0)
    scan.time_scale.setValue(0.0)
    scan.folder.setText(str(tmp_path / "camera_locked"))
    try:
        qtbot.mouseClick(scan.start_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: entered.acquire(blocking=False), timeout=T)    # the scan's first exposure
        qtbot.waitUntil(lambda: window.state.scan_owns_camera, timeout=T)
        engine = scan.engine
        assert device.worker.holder == engine.label                             # the core interlock is on
        for name, widgets in controls.items():
            for w in widgets:
                assert not w.isEnabled(), name
                assert f"Disabled while {engine.label} runs: the scan owns the camera" in w.toolTip(), name
        assert camera.lock_label.isVisible() and engine.label in camera.lock_label.text()
        live_view = window.panels["liveViewDock"]
        assert not live_view.live_button.isEnabled() and not live_view.live_action.isEnabled()
        assert "owns the camera" in live_view.live_button.toolTip()
        camera.grab().save("/tmp/leftovers-camera-locked.png")

        # every way in from the GUI: the disabled button and its shortcut, the method, a call sent anyway
        qtbot.mouseClick(camera.shot_button, Qt.LeftButton)
        camera.shot_action.trigger()
        camera.take_test_shot()
        assert "Test shot: Disabled while" in window.statusBar().currentMessage()
        camera.apply_settings()
        refused = []
        device.run(camera_panel.test_shot, driver, shots, timeout_s=30, on_error=refused.append)
        device.run("set_setting", "iso", 3200, on_error=refused.append)
        qtbot.waitUntil(lambda: len(refused) == 2, timeout=T)
        assert all(f"in use by {engine.label}" in text for text in refused), refused
        assert refused[0].startswith("camera: test_shot(") and refused[1].startswith("camera: set_setting(")
        assert driver.settings()["iso"] != 3200
        assert (sorted(shots.glob("*")) if shots.is_dir() else []) == before       # no picture was taken
    finally:
        gate.release(100)

    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=T)
    qtbot.waitUntil(lambda: not window.state.scan_owns_camera, timeout=T)
    assert Dataset.open(tmp_path / "camera_locked").status_counts()["done"] == 2
    qtbot.waitUntil(lambda: camera.shot_button.isEnabled(), timeout=T)          # and the controls come back
    assert all(w.isEnabled() for ws in controls.values() for w in ws)
    assert not camera.lock_label.isVisible() and "Disabled while" not in camera.shot_button.toolTip()
    assert live_view.live_button.isEnabled() and "owns the camera" not in live_view.live_button.toolTip()
    qtbot.mouseClick(camera.shot_button, Qt.LeftButton)                         # a test shot works again
    qtbot.waitUntil(lambda: "Last test shot" in camera.shot_label.text(), timeout=T)
    assert len(sorted(shots.glob("*"))) > len(before)
    window.close()


def test_stop_is_in_sight_with_every_panel_layout_and_stops_the_rig(qtbot):
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    simulator = window.state.devices["rig_simulator"]
    docks = window.findChildren(QDockWidget)
    assert window.stop_button.isVisible() and window.stop_button.text() == "STOP (Esc)"
    assert not window.stop_toolbar.isMovable() and not window.stop_toolbar.toggleViewAction().isVisible()

    for dock in docks:                                          # every panel floated
        dock.setFloating(True)
    qtbot.waitUntil(lambda: all(d.isFloating() for d in docks), timeout=T)
    assert window.stop_button.isVisible()
    for dock in docks:                                          # every panel hidden
        dock.setFloating(False)
        dock.hide()
    qtbot.waitUntil(lambda: not any(d.isVisible() for d in docks), timeout=T)
    assert window.stop_button.isVisible() and window.stop_button.isEnabled()

    def move_far_and_stop(press):
        simulator.time_scale = 1.0                              # real time: 3000 mm take 15 s
        rig.goto_x.setValue(3000.0)
        rig.go_to()
        qtbot.waitUntil(lambda: simulator.state == "Run" and simulator.reported_position_mm()[0] > 5.0, timeout=T)
        press()
        # the rig's Idle (its status poll) and the move's end (its result, 'stopped by STOP') come on
        # two paths, in either order
        qtbot.waitUntil(lambda: rig.last_status.state is RigState.IDLE and simulator.state == "Idle"
                        and "stopped by STOP" in rig.message_label.text(), timeout=T)
        x = simulator.reported_position_mm()[0]
        assert 5.0 < x < 3000.0 and rig.last_status.homed       # stopped on its way
        simulator.time_scale = 0.02
        rig.goto_x.setValue(0.0)
        rig.go_to()
        qtbot.waitUntil(lambda: abs(rig.last_status.position_mm[0]) < 0.5 and rig.last_status.state is RigState.IDLE,
                        timeout=T)

    move_far_and_stop(lambda: qtbot.mouseClick(window.stop_button, Qt.LeftButton))   # the toolbar's STOP
    window.activateWindow()
    qtbot.waitUntil(lambda: window.isActiveWindow(), timeout=T)
    move_far_and_stop(lambda: qtbot.keyClick(window, Qt.Key_Escape))                  # its shortcut
    window.close()


@pytest.fixture
def held_studio():
    """A held camera (each capture waits for the test) and the instant rig, as the window's devices."""
    rig = InstantRig(load_rig())
    rig.connect()
    cam = HeldCamera(rig.true_position_mm)
    cam.connect()
    devices = window_devices(rig, cam)
    yield devices, cam
    cam.release(100)
    close_devices(devices)


def test_quitting_during_a_scan_asks_and_cancel_keeps_it_running(qtbot, tmp_path, held_studio):
    devices, cam = held_studio
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.devices.update(devices)
    window.show()
    scan = window.panels["scanPanel"]
    scan.columns.setValue(3)
    scan.rows.setValue(2)
    scan.settle.setValue(0.0)
    folder = tmp_path / "quitting"
    scan.folder.setText(str(folder))
    scan.start()
    qtbot.waitUntil(lambda: window.state.scan_owns_rig, timeout=T)
    assert cam.entered.acquire(timeout=T / 1000)                # the first view is being exposed
    engine = scan.engine

    assert window.close() is False                              # asked, not closed
    box = window._quit_box
    qtbot.waitUntil(lambda: box.isVisible(), timeout=T)
    assert "is running: 0 of 6 views captured" in box.text()
    text = box.informativeText()
    assert "stops after the current view" in text and str(folder) in text and "Scan panel's Folder field" in text
    assert "lfstudio scan" not in text                          # the window's words, not a command line
    cam.release()                                               # a view is captured while the question is open:
    qtbot.waitUntil(lambda: "is running: 1 of 6 views captured" in box.text(), timeout=T)   # the count follows
    assert cam.captures == 1 and cam.entered.acquire(timeout=T / 1000)
    qtbot.mouseClick(box.findChild(type(box.defaultButton()), "keepScanningButton"), Qt.LeftButton)
    qtbot.waitUntil(lambda: not box.isVisible(), timeout=T)
    assert window.isVisible() and engine.state is ScanState.RUNNING   # Cancel: the scan goes on

    assert window.close() is False
    box = window._quit_box
    qtbot.waitUntil(lambda: box.isVisible(), timeout=T)
    qtbot.mouseClick(box.findChild(type(box.defaultButton()), "stopAndQuitButton"), Qt.LeftButton)
    qtbot.waitUntil(lambda: engine.state is ScanState.STOPPING, timeout=T)
    assert window.isVisible()                                   # the current view finishes first
    cam.release()
    qtbot.waitUntil(lambda: not window.isVisible(), timeout=T)
    assert engine.state is ScanState.FINISHED and engine.message.startswith("Aborted: 2 of 6")
    ds = Dataset.open(folder)
    assert ds.status_counts()["done"] == 2 and ds.verify_files() == []
    assert settings().value(ACTIVE_KEY, "") == str(ds.root)     # offered for resume at the next start
