"""The operator's first session on the simulated studio, through the whole window: the rig and camera
connect at start, home, scan a small grid, and the dataset is complete and shown in the grid."""

from __future__ import annotations

from PySide6.QtCore import Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.views.grid_view import DONE


def test_first_session_on_the_simulated_studio(qtbot, tmp_path):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    rig, camera, scan = (window.panels[n] for n in ("rigDock", "cameraDock", "scanPanel"))
    camera.sim_width.setValue(min(camera.sim_width.value(), 640))
    window.connect_simulated_studio()
    qtbot.waitUntil(lambda: camera.connected and "Connected" in camera.status_label.text(), timeout=60000)
    simulator = window.state.devices["rig_simulator"]
    simulator.time_scale = 0.02                      # homing in a blink
    qtbot.waitUntil(lambda: rig.home_button.isEnabled(), timeout=20000)
    rig.home()
    qtbot.waitUntil(lambda: "homed" in window.statusBar().currentMessage().lower(), timeout=30000)

    scan.columns.setValue(3)
    scan.rows.setValue(2)
    scan.settle.setValue(0.0)
    scan.time_scale.setValue(0.0)
    scan.folder.setText(str(tmp_path / "first"))
    scales_during_scan = []
    window.state.scanEvents.connect(lambda events: scales_during_scan.extend(
        simulator.time_scale for ev in events if ev.kind.value == "view-started"))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=120000)
    ds = Dataset.open(tmp_path / "first")
    assert ds.status_counts()["done"] == 6
    assert scales_during_scan and set(scales_during_scan) == {0.0}   # the scan's time scale reached the simulator
    assert simulator.time_scale == 0.0               # the panel's scale paces the simulated rig outside a scan too
    assert all((ds.root / v["file"]).is_file() and v["sha256"] for v in ds.views)
    qtbot.waitUntil(lambda: (window.central.canvas.status == DONE).sum() == 6, timeout=10000)
    window.close()
