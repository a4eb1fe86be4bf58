"""The window's scan on emulated CiA 402 drives (dryve D1 over Modbus TCP, the emulator's Modbus TCP server): the Rig
panel connects 'sim-dryve' with the dryve D1 profile, the simulated camera follows the drives'
true position, Home, a small scan; then STOP in the window during a scan's long move ends it at a
known position."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.views.grid_view import DONE
from lfstudio.rig.motion import RigState

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"


def test_window_scans_on_emulated_drives_and_stop_ends_a_move(qtbot, tmp_path):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    rig, camera, scan = (window.panels[n] for n in ("rigDock", "cameraDock", "scanPanel"))
    camera.sim_width.setValue(min(camera.sim_width.value(), 320))
    rig.rig_combo.setCurrentText(RIG_NAME)
    rig.port_combo.setCurrentText("sim-dryve")
    rig.sim_time_scale = 0.02
    rig.connect_rig()
    qtbot.waitUntil(lambda: rig.home_button.isEnabled(), timeout=30000)
    emulator = window.state.devices["rig_simulator"]
    camera.connect_camera()
    qtbot.waitUntil(lambda: camera.connected and "Connected" in camera.status_label.text(), timeout=60000)
    rig.home()
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.homed, timeout=30000)
    assert rig.drive_label.text() == "Drives — x: operation enabled · y: operation enabled"

    scan.columns.setValue(3)
    scan.rows.setValue(2)
    scan.settle.setValue(0.0)
    scan.time_scale.setValue(0.0)
    scan.folder.setText(str(tmp_path / "drives"))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=120000)
    ds = Dataset.open(tmp_path / "drives")
    assert ds.status_counts()["done"] == 6
    assert ds.manifest["devices"]["rig"]["kind"] == "sim-dryve" and ds.manifest["devices"]["rig"]["profile"] == RIG_NAME
    for v in ds.views:
        assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.011)
    assert emulator.time_scale == scan.time_scale.value()   # the Scan panel's time scale paces the rig
    qtbot.waitUntil(lambda: (window.central.canvas.status == DONE).sum() == 6, timeout=10000)
    ds.close()

    # a scan far from where the rig stands (a long first move), STOPped from the window's STOP
    scan.columns.setValue(2)
    scan.rows.setValue(1)
    scan.offset_h.setValue(-1500.0)
    scan.time_scale.setValue(0.5)
    scan.folder.setText(str(tmp_path / "stopped"))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.state is RigState.MOVING, timeout=60000)
    window.stop_action.trigger()
    qtbot.waitUntil(lambda: "paused" in scan.state_label.text().lower(), timeout=60000)
    qtbot.waitUntil(lambda: rig.last_status.state is RigState.IDLE, timeout=30000)
    x, y = rig.last_status.position_mm
    assert 400 < x < 2000                              # stopped on its way to the grid near 500 mm
    assert emulator.true_position_mm() == pytest.approx((x, y), abs=0.011)
    assert rig.last_status.homed
    scan.abort()
    qtbot.waitUntil(lambda: not window.state.scan_active, timeout=60000)
    window.close()
