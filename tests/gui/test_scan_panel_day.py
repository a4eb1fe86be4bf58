"""The Scan panel as a new operator meets it (issue 20): typed folders, folders that hold other
files, state restored after a restart, messages that go when their cause goes. Real Qt event loop,
instant simulated devices."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from lfstudio.dataset import Dataset
from tests.gui.test_scan_gui import scan_panel

T = 60000  # ms; generous for a loaded machine, the waits end as soon as the condition holds


def test_folder_field_expands_tilde_and_variables_and_shows_the_absolute_path(qtbot, tmp_path, monkeypatch,
                                                                              instant_devices):
    devices, rig, cam = instant_devices
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("LFS_DAY", "studio_day")
    monkeypatch.chdir(tmp_path)
    state, panel = scan_panel(qtbot, devices, 2, 1, "")
    panel.time_scale.setValue(0.0)
    panel.show()
    panel.folder.setFocus()
    qtbot.waitUntil(panel.folder.hasFocus)
    panel.folder.clear()
    qtbot.keyClicks(panel.folder, "~/datasets/$LFS_DAY")
    qtbot.keyClick(panel.folder, Qt.Key_Return)          # editing finished: the path it means is shown
    assert panel.folder.text() == str(home / "datasets" / "studio_day")
    panel.folder.setText("~/datasets/${LFS_DAY}")         # typed and started without leaving the field
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=20000)
    assert panel.folder.text() == str(home / "datasets" / "studio_day")
    assert Dataset.open(home / "datasets" / "studio_day").status_counts()["done"] == 2
    assert not (tmp_path / "~").exists() and not (tmp_path / "$LFS_DAY").exists()


def test_unset_variable_in_the_folder_is_one_message_and_no_folder(qtbot, tmp_path, monkeypatch, instant_devices):
    devices, rig, cam = instant_devices
    monkeypatch.delenv("LFS_NOT_SET", raising=False)
    monkeypatch.chdir(tmp_path)
    state, panel = scan_panel(qtbot, devices, 2, 1, "$LFS_NOT_SET/scan")
    with qtbot.waitSignal(state.errorOccurred) as blocker:
        qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    assert "Dataset folder" in blocker.args[1] and "$LFS_NOT_SET, which is not set" in blocker.args[1]
    assert list(tmp_path.iterdir()) == [] and panel.engine is None


def test_start_into_a_folder_holding_other_files_asks_and_offers_a_new_sub_folder(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    mine = tmp_path / "Documents"
    mine.mkdir()
    (mine / "thesis.pdf").write_bytes(b"%PDF")
    state, panel = scan_panel(qtbot, devices, 2, 1, mine)
    panel.time_scale.setValue(0.0)
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: getattr(panel, "folder_box", None) is not None and panel.folder_box.isVisible(),
                    timeout=5000)
    box = panel.folder_box
    assert "not empty (thesis.pdf)" in box.text() and str(mine / "lfstudio-scan") in box.text()
    assert panel.engine is None and sorted(p.name for p in mine.iterdir()) == ["thesis.pdf"]
    qtbot.mouseClick(box.button(QMessageBox.Cancel), Qt.LeftButton)          # Cancel: nothing happens
    assert panel.engine is None and sorted(p.name for p in mine.iterdir()) == ["thesis.pdf"]
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.folder_box is not box and panel.folder_box.isVisible(), timeout=5000)
    qtbot.mouseClick(panel.folder_box.button(QMessageBox.Yes), Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=20000)
    assert panel.folder.text() == str(mine / "lfstudio-scan")
    assert Dataset.open(mine / "lfstudio-scan").status_counts()["done"] == 2
    assert sorted(p.name for p in mine.iterdir()) == ["lfstudio-scan", "thesis.pdf"]


# -- state after a restart --------------------------------------------------------------------------
def test_after_a_restart_the_scan_grid_is_the_one_the_planner_shows(qtbot):
    from lfstudio.gui.app import create_window

    window = create_window(simulated=True)
    qtbot.addWidget(window)
    planner, scan = window.panels["plannerDock"], window.panels["scanPanel"]
    planner.set_plan(planner.current_plan().replace(grid_columns=9, grid_rows=3))
    planner.evaluate()
    qtbot.waitUntil(lambda: (scan.columns.value(), scan.rows.value()) == (9, 3), timeout=5000)
    window.close()

    again = create_window(simulated=True)              # the next start, same settings
    qtbot.addWidget(again)
    planner, scan = again.panels["plannerDock"], again.panels["scanPanel"]
    plan = planner.current_plan()
    assert (plan.grid_columns, plan.grid_rows) == (9, 3)
    assert (scan.columns.value(), scan.rows.value()) == (9, 3)
    assert "27 views" in scan.summary.text()
    assert len(scan.current_plan()) == 27           # what Start would capture
    again.close()


def test_resume_offered_on_start_homes_a_rig_that_is_not_homed_first(qtbot, tmp_path):
    """After a restart the simulated GRBL rig is connected but not homed: "Resume scan" asks to home
    first instead of walking into "rig not homed", and then the scan completes."""
    from lfstudio.gui.app import create_window
    from lfstudio.gui.panels.scan import ACTIVE_KEY
    from lfstudio.gui.settings import settings
    from tests.studio.test_scan_processes import partial_dataset

    ds = partial_dataset(tmp_path / "half", "sim", "sim", 2)         # interrupted: 2 of 6 views
    settings().setValue(ACTIVE_KEY, str(ds.root))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    rig, camera, scan = (window.panels[n] for n in ("rigDock", "cameraDock", "scanPanel"))
    camera.sim_width.setValue(320)
    rig.sim_time_scale = 0.0
    scan.time_scale.setValue(0.0)
    errors = []
    window.state.errorOccurred.connect(lambda title, message: errors.append(message))
    window.connect_simulated_studio()
    try:
        qtbot.waitUntil(lambda: camera.connected and rig.home_button.isEnabled(), timeout=T)
        assert not rig.last_status.homed
        qtbot.waitUntil(lambda: getattr(scan, "resume_box", None) is not None and scan.resume_box.isVisible(),
                        timeout=T)
        qtbot.mouseClick(scan.resume_box.button(QMessageBox.Yes), Qt.LeftButton)
        qtbot.waitUntil(lambda: getattr(scan, "home_box", None) is not None and scan.home_box.isVisible()
                        or bool(errors), timeout=T)
        assert not errors
        assert ("ALARM" in scan.home_box.text() or "not homed" in scan.home_box.text()) and scan.engine is None
        assert Dataset.open(ds.root).status_counts()["done"] == 2              # nothing ran yet
        qtbot.mouseClick(scan.home_box.button(QMessageBox.Yes), Qt.LeftButton)
        qtbot.waitUntil(lambda: "Finished" in scan.state_label.text() or bool(errors), timeout=T)
        assert not errors
        assert rig.last_status.homed
        assert Dataset.open(ds.root).status_counts()["done"] == 6
        assert "homing the rig before the scan" in scan.log_view.toPlainText()
    finally:
        window.close()


def test_simulated_session_does_not_take_the_hardware_session_camera(qtbot):
    from lfstudio.gui.panels.camera import CameraPanel
    from lfstudio.gui.settings import settings
    from lfstudio.gui.state import AppState

    hardware = CameraPanel(AppState(simulated=False))
    qtbot.addWidget(hardware)
    hardware.kind.setCurrentIndex(hardware.kind.findData("gphoto2"))          # the studio's real camera
    simulated = CameraPanel(AppState(simulated=True))                          # lfstudio gui --simulated
    qtbot.addWidget(simulated)
    assert simulated.current_kind() == "sim"
    simulated.kind.setCurrentIndex(simulated.kind.findData("folder"))
    again = CameraPanel(AppState(simulated=False))                             # the next hardware day
    qtbot.addWidget(again)
    assert again.current_kind() == "gphoto2"
    assert CameraPanel(AppState(simulated=True)).current_kind() == "folder"   # each remembers its own
    assert settings().value("camera/kind") == "gphoto2"
