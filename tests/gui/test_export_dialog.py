"""File → Export dataset… on a real dataset: menu entry, estimate, PNG export, cancel, overwrite, settings."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QObject, QPoint, Qt, Slot
from PySide6.QtGui import QDesktopServices
from PySide6.QtWidgets import QMessageBox

from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS, ExportDialog
from lfstudio.gui.settings import settings


def _export_action(window):
    return next(a for a in window.menu("File").actions() if a.text().replace("&", "") == "Export dataset…")


def _open_dialog(qtbot, dataset):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(dataset)
    _export_action(window).trigger()
    dialog = window.findChild(ExportDialog, "exportDialog")
    assert dialog is not None and dialog.isVisible()
    return window, dialog


def _wait_estimate(qtbot, dialog):
    qtbot.waitUntil(lambda: dialog.estimate is not None or dialog.estimate_error is not None, timeout=20000)


class _UrlCatcher(QObject):
    def __init__(self):
        super().__init__()
        self.urls = []

    @Slot("QUrl")
    def open(self, url):
        self.urls.append(url)


def test_menu_entry_is_disabled_and_explains_without_a_dataset(qtbot, tiny_dataset):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    action = _export_action(window)
    assert action.shortcut().toString() == "Ctrl+E"
    assert not action.isEnabled() and "no dataset is open" in action.toolTip()
    window.state.set_dataset(tiny_dataset)
    assert action.isEnabled() and tiny_dataset.root.name in action.toolTip()


def test_export_png_of_a_picked_subset_then_open_folder(qtbot, tiny_dataset, tmp_path):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
    _wait_estimate(qtbot, dialog)
    assert len(dialog.estimate.views) == 15 and "15 views" in dialog.estimate_label.text()
    assert "raw views" in dialog.warnings_label.text()          # the tiny dataset is not processed

    # narrow the export by clicking on the grid: row 0 only, minus one view
    dialog.subset_edit.setText("r0")
    dialog.subset_button.click()
    center = dialog.picker.cell_center(0, 4)
    qtbot.mouseClick(dialog.picker, Qt.LeftButton, pos=QPoint(int(center.x()), int(center.y())))
    assert dialog.picker.selected == {(0, c) for c in range(4)}
    qtbot.waitUntil(lambda: dialog.estimate is not None and len(dialog.estimate.views) == 4, timeout=20000)
    assert dialog.estimate.bytes_estimate > 0 and "4 of 15" in dialog.views_label.text()

    dialog.folder_edit.setText(str(tmp_path / "exports"))
    dialog.name_edit.setText("subset_png")
    (tmp_path / "exports").mkdir()
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.export_button.click()
    out = tmp_path / "exports" / "subset_png"
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == [f"r00_c00{c}.png" for c in range(4)]
    img = cv2.imread(str(out / pngs[0]), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape[1] == 640
    assert (out / "manifest.json").is_file() and json.loads((out / "manifest.json").read_text())
    assert "Exported 4 views" in dialog.result_label.text()
    assert dialog.open_folder_button.isEnabled()
    assert not list((tmp_path / "exports").glob(".*partial*"))

    catcher = _UrlCatcher()                  # the file manager, as Qt sees it
    QDesktopServices.setUrlHandler("file", catcher, "open")
    try:
        dialog.open_folder_button.click()
    finally:
        QDesktopServices.unsetUrlHandler("file")
    assert [u.toLocalFile() for u in catcher.urls] == [str(out)]

    # the format and the destination folder are remembered
    s = settings()
    assert s.value("export/format") == "png" and s.value("export/folder") == str(tmp_path / "exports")
    dialog.close()
    _export_action(window).trigger()
    again = window.export_dialog
    assert again is not dialog and again.folder_edit.text() == str(tmp_path / "exports")


def test_cancel_leaves_nothing_behind(qtbot, tiny_dataset, tmp_path):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
    dest = tmp_path / "exports"
    dest.mkdir()
    dialog.folder_edit.setText(str(dest))
    dialog.name_edit.setText("cancelled_png")
    _wait_estimate(qtbot, dialog)
    with qtbot.waitSignal(dialog.runner.cancelled, timeout=60000):
        dialog.export_button.click()
        assert dialog.progress.cancel_button.isEnabled()
        qtbot.mouseClick(dialog.progress.cancel_button, Qt.LeftButton)
    assert sorted(p.name for p in dest.iterdir()) == []      # no output, no partial folder
    assert "Cancelled" in dialog.result_label.text() and dialog.export_button.isEnabled()


@pytest.mark.parametrize("answer", [QMessageBox.No, QMessageBox.Yes])
def test_overwrite_asks_first(qtbot, tiny_dataset, tmp_path, answer):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
    dialog.folder_edit.setText(str(tmp_path))
    dialog.name_edit.setText("old_png")
    (tmp_path / "old_png").mkdir()                   # an earlier export (only such a folder is ever replaced)
    (tmp_path / "old_png" / "manifest.json").write_text('{"format": "lfstudio-export", "kind": "png"}')
    (tmp_path / "old_png" / "keep.txt").write_text("older export")
    dialog.subset_edit.setText("r1,c0-1")
    dialog.subset_button.click()
    qtbot.waitUntil(lambda: dialog.estimate is not None and len(dialog.estimate.views) == 2, timeout=20000)
    assert "exists" in dialog.path_label.text()
    dialog.export_button.click()
    box = dialog.findChild(QMessageBox, "overwriteBox")
    assert box is not None and box.isVisible() and "old_png" in box.text()
    assert not dialog.runner.running                 # nothing starts before the answer
    if answer == QMessageBox.No:
        box.button(QMessageBox.No).click()
        assert (tmp_path / "old_png" / "keep.txt").is_file() and not dialog.runner.running
        assert "Not exported" in dialog.result_label.text()
    else:
        with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
            box.button(QMessageBox.Yes).click()
        assert not (tmp_path / "old_png" / "keep.txt").exists()
        assert sorted(p.name for p in (tmp_path / "old_png").glob("*.png")) == ["r01_c000.png", "r01_c001.png"]


def test_hci_sub_array_follows_a_click_on_the_grid(qtbot, tiny_dataset, tmp_path):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("hci"))
    dialog.hci_columns.setValue(3)
    dialog.hci_rows.setValue(3)
    center = dialog.picker.cell_center(1, 3)
    qtbot.mouseClick(dialog.picker, Qt.LeftButton, pos=QPoint(int(center.x()), int(center.y())))
    assert (dialog.hci_center_row.value(), dialog.hci_center_column.value()) == (1, 3)
    qtbot.waitUntil(lambda: dialog.estimate is not None and len(dialog.estimate.views) == 9, timeout=20000)
    assert dialog.picker.selected == {(r, c) for r in range(3) for c in range(2, 5)}
    assert "3 × 3 sub-array" in dialog.views_label.text()
    corner = dialog.picker.cell_center(0, 0)        # near the edge: the sub-array stays inside the grid
    qtbot.mouseClick(dialog.picker, Qt.LeftButton, pos=QPoint(int(corner.x()), int(corner.y())))
    assert (dialog.hci_center_row.value(), dialog.hci_center_column.value()) == (1, 1)
    qtbot.waitUntil(lambda: dialog.estimate is not None and (0, 0) in dialog.picker.selected, timeout=20000)
    dialog.hci_center_column.setValue(4)            # typed off the edge: the field and the fix are named
    qtbot.waitUntil(lambda: dialog.estimate_error is not None, timeout=20000)
    assert "hci_center" in dialog.estimate_error and not dialog.export_button.isEnabled()
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("hevc"))   # back: the operator's own selection
    assert dialog.name_edit.text().endswith(".mp4")
    assert len(dialog.picker.selected) == 15


def test_nerfstudio_and_colmap_exports_from_the_dialog(qtbot, tiny_dataset, tmp_path):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.resize(900, 780)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("nerfstudio"))
    assert dialog.name_edit.text() == f"{tiny_dataset.root.name}_nerfstudio"
    dialog.holdout_combo.setCurrentIndex(dialog.holdout_combo.findData("centre"))
    qtbot.waitUntil(lambda: dialog.estimate is not None and "held out" in dialog.warnings_label.text(), timeout=20000)
    assert "no calibration" in dialog.warnings_label.text()     # the tiny dataset is not calibrated
    dialog.folder_edit.setText(str(tmp_path))
    dialog.grab().save("/tmp/export-nerfstudio-dialog.png")
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.export_button.click()
    meta = json.loads((tmp_path / f"{tiny_dataset.root.name}_nerfstudio" / "transforms.json").read_text())
    assert meta["test_filenames"] == ["images/r01_c002.png"] and len(meta["frames"]) == 15
    assert "Exported 15 views" in dialog.result_label.text()

    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("colmap"))
    dialog.image_depth_combos[0].setCurrentIndex(1)             # 16-bit: both pages follow
    assert dialog.image_depth_combos[1].currentData() == 16
    dialog.subset_edit.setText("r1")
    dialog.subset_button.click()
    qtbot.waitUntil(lambda: dialog.estimate is not None and len(dialog.estimate.views) == 5, timeout=20000)
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.export_button.click()
    out = tmp_path / f"{tiny_dataset.root.name}_colmap"
    assert (out / "sparse" / "0" / "images.txt").is_file()
    assert cv2.imread(str(out / "images" / "r01_c000.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    s = settings()
    assert s.value("export/holdout") == "centre" and int(s.value("export/image_bit_depth")) == 16


def test_overwrite_never_deletes_a_folder_of_other_files(qtbot, tiny_dataset, tmp_path):
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
    dialog.folder_edit.setText(str(tmp_path))
    dialog.name_edit.setText("mine")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("years of work")
    dialog.subset_edit.setText("r1,c0-1")
    dialog.subset_button.click()
    qtbot.waitUntil(lambda: dialog.estimate is not None and len(dialog.estimate.views) == 2, timeout=20000)
    dialog.export_button.click()
    box = dialog.findChild(QMessageBox, "overwriteBox")
    if box is not None and box.isVisible():
        box.button(QMessageBox.Yes).click()
    qtbot.waitUntil(lambda: not dialog.runner.running and "earlier export" in dialog.result_label.text(),
                    timeout=60000)
    assert (tmp_path / "mine" / "thesis.tex").read_text() == "years of work"


def test_hdr_radiance_source_turns_the_image_choice_off(qtbot, tiny_dataset):
    """With Source 'HDR radiance, float' the export copies the merge's float files: the dialog still
    offered 'Images: 8-bit sRGB', which does nothing then."""
    window, dialog = _open_dialog(qtbot, tiny_dataset)
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("colmap"))
    dialog.source_combo.setCurrentIndex(dialog.source_combo.findData("hdr"))
    assert not any(c.isEnabled() for c in dialog.image_depth_combos)
    assert "float" in dialog.image_depth_combos[0].toolTip()
    dialog.source_combo.setCurrentIndex(dialog.source_combo.findData("processed"))
    assert all(c.isEnabled() for c in dialog.image_depth_combos)
