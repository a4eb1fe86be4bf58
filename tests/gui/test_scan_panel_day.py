"""The Scan panel as a new operator meets it (issue 20): typed folders, folders that hold other
files, state restored after a restart, messages that go when their cause goes. Real Qt event loop,
instant simulated devices."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from lfstudio.dataset import Dataset
from tests.gui.test_scan_gui import instant_devices, scan_panel  # noqa: F401  (fixture)


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
