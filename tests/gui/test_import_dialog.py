"""File → Import images… and Import HEVC… on a real Qt event loop: live count, import, the destination
folder rule (new sub-folder offered for a folder of other files, replace-dataset question), open the dataset."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PySide6.QtWidgets import QApplication, QMessageBox

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.import_dialog import ImportHevcDialog, ImportImagesDialog


def _images(folder: Path, n: int, size=(48, 32)) -> Path:
    folder.mkdir()
    for i in range(n):
        img = np.full((size[1], size[0], 3), 10 * i, np.uint8)   # view i has grey level 10·i
        cv2.imwrite(str(folder / f"frame{i + 1}.png"), img)
    return folder


def _menu_action(window, text):
    actions = {a.text().replace("&", ""): a for a in window.menu("File").actions()}
    assert text in actions, sorted(actions)
    return actions[text]


def test_import_images_dialog_imports_and_opens_the_dataset(qtbot, tmp_path):
    folder = _images(tmp_path / "rig", 6)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    _menu_action(window, "Import images…").trigger()
    dialog = window.findChild(ImportImagesDialog, "importImagesDialog")
    assert dialog is not None and dialog.isVisible()

    dialog.folder_edit.setText(str(folder))
    dialog.columns_spin.setValue(3)
    dialog.rows_spin.setValue(3)
    qtbot.waitUntil(lambda: "Found 6 images" in dialog.count_label.text())   # the debounced live count
    assert "grid needs 9" in dialog.count_label.text()
    dialog.rows_spin.setValue(2)
    dialog.order_combo.setCurrentText("meander")
    dialog.intrinsics_combo.setCurrentIndex(2)
    dialog.focal_px.setValue(800.0)
    dialog.spacing_h.setValue(5.0)
    assert dialog.recount() == 6 and "✓" in dialog.count_label.text()

    # an empty destination that exists takes the dataset without a question
    out = tmp_path / "ds"
    out.mkdir()
    dialog.out_edit.setText(str(out))
    with qtbot.waitSignal(dialog.runner.finished, timeout=30000):
        dialog.import_button.click()
    assert dialog.findChild(QMessageBox, "confirmOverwrite") is None
    assert "Imported 6 views (3 × 2, 48 × 32 px)" in dialog.message.text()
    ds = Dataset.open(out)
    # meander: frame4 is the first of the reversed second row -> row 1, column 2
    assert ds.view(1, 2)["source_file"] == "frame4.png" and ds.view(1, 0)["source_file"] == "frame6.png"
    assert ds.view(0, 1)["commanded_mm"] == [5.0, 0.0]
    assert ds.focal_length_px(48) == 800.0

    assert dialog.open_button.isEnabled()
    with qtbot.waitSignal(window.state.datasetChanged, timeout=5000):
        dialog.open_button.click()
    assert window.state.dataset is not None and window.state.dataset.root == out.resolve()

    # a wrong grid is reported in the dialog, never raised
    dialog.show()
    dialog.columns_spin.setValue(4)
    dialog.out_edit.setText(str(tmp_path / "other"))
    with qtbot.waitSignal(dialog.runner.failed, timeout=30000):
        dialog.import_button.click()
    assert "grid needs 8" in dialog.message.text() and not (tmp_path / "other").exists()
    # the fields persist
    again = ImportImagesDialog(window.state)
    qtbot.addWidget(again)
    assert again.folder_edit.text() == str(folder) and again.order_combo.currentText() == "meander"


def test_import_hevc_dialog_restores_an_export(qtbot, tmp_path):
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    src = make_virtual_dataset(tmp_path / "src", 3, 2, width_px=64, fmt="png")
    video = tmp_path / "lf.mp4"
    export_dataset(src, ExportOptions("hevc", video))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    _menu_action(window, "Import HEVC…").trigger()
    dialog = window.findChild(ImportHevcDialog, "importHevcDialog")
    assert dialog is not None and dialog.isVisible()
    dialog.file_edit.setText(str(tmp_path / "missing.mp4"))
    dialog.out_edit.setText(str(tmp_path / "ds"))
    dialog.import_button.click()
    assert "HEVC file" in dialog.message.text() and "is not a file" in dialog.message.text()
    assert not dialog.runner.running and not (tmp_path / "ds").exists()

    dialog.file_edit.setText(str(video))
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.import_button.click()
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds.done_views()) == 6 and "Imported 6 views into" in dialog.message.text()
    with qtbot.waitSignal(window.state.datasetChanged, timeout=5000):
        dialog.open_button.click()
    assert window.state.dataset.root == (tmp_path / "ds").resolve()


def _shown_box(qtbot, dialog, name: str) -> QMessageBox:
    """The question ``name`` the dialog shows now (earlier ones stay as hidden children)."""
    def shown():
        return [b for b in dialog.findChildren(QMessageBox, name) if b.isVisible()]
    qtbot.waitUntil(lambda: len(shown()) == 1, timeout=5000)
    return shown()[0]


def test_import_dialogs_offer_a_sub_folder_for_a_folder_of_other_files_and_ask_before_replacing_a_dataset(
        qtbot, tmp_path):
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    folder = _images(tmp_path / "rig", 6)
    mine = tmp_path / "Documents"
    mine.mkdir()
    (mine / "thesis.pdf").write_bytes(b"%PDF")
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    _menu_action(window, "Import images…").trigger()
    dialog = window.findChild(ImportImagesDialog, "importImagesDialog")
    dialog.folder_edit.setText(str(folder))
    dialog.columns_spin.setValue(3)
    dialog.rows_spin.setValue(2)
    dialog.out_edit.setText(str(mine))
    dialog.import_button.click()
    box = _shown_box(qtbot, dialog, "folderNotEmptyBox")           # the Scan panel's offer
    assert "not empty (thesis.pdf)" in box.text() and str(mine / "lfstudio-import") in box.text()
    assert box.button(QMessageBox.Yes).text() == "Import into lfstudio-import"
    assert "not empty (thesis.pdf)" in dialog.message.text() and not dialog.runner.running
    box.button(QMessageBox.Cancel).click()                          # Cancel: nothing is written
    assert not dialog.runner.running and sorted(p.name for p in mine.iterdir()) == ["thesis.pdf"]
    dialog.import_button.click()
    box = _shown_box(qtbot, dialog, "folderNotEmptyBox")
    with qtbot.waitSignal(dialog.runner.finished, timeout=30000):
        box.button(QMessageBox.Yes).click()
    assert dialog.out_edit.text() == str(mine / "lfstudio-import")
    assert len(Dataset.open(mine / "lfstudio-import").done_views()) == 6
    assert sorted(p.name for p in mine.iterdir()) == ["lfstudio-import", "thesis.pdf"]

    # a dataset there: replaced only when the operator says so
    dialog.import_button.click()
    box = _shown_box(qtbot, dialog, "confirmOverwrite")
    assert "already holds a dataset" in box.text() and not dialog.runner.running
    box.button(QMessageBox.Cancel).click()
    assert "holds a dataset" in dialog.message.text() and not dialog.runner.running
    (mine / "lfstudio-import" / "raw" / "r00_c000.png").unlink()
    dialog.import_button.click()
    box = _shown_box(qtbot, dialog, "confirmOverwrite")
    with qtbot.waitSignal(dialog.runner.finished, timeout=30000):
        box.button(QMessageBox.Yes).click()
    assert (mine / "lfstudio-import" / "raw" / "r00_c000.png").is_file()
    (tmp_path / "a_file").write_text("x")
    dialog.out_edit.setText(str(tmp_path / "a_file"))
    dialog.import_button.click()
    assert "is a file" in dialog.message.text() and not dialog.runner.running

    # the HEVC dialog: the same offer
    src = make_virtual_dataset(tmp_path / "src", 3, 2, width_px=64, fmt="png")
    video = tmp_path / "lf.mkv"
    export_dataset(src, ExportOptions("hevc", video))
    _menu_action(window, "Import HEVC…").trigger()
    hevc = window.findChild(ImportHevcDialog, "importHevcDialog")
    hevc.file_edit.setText(str(video))
    hevc.out_edit.setText(str(mine))
    hevc.import_button.click()
    box = _shown_box(qtbot, hevc, "folderNotEmptyBox")
    assert str(mine / "lfstudio-import-2") in box.text()              # the first sub-folder holds a dataset now
    with qtbot.waitSignal(hevc.runner.finished, timeout=60000):
        box.button(QMessageBox.Yes).click()
    assert len(Dataset.open(mine / "lfstudio-import-2").done_views()) == 6
    assert (mine / "thesis.pdf").read_bytes() == b"%PDF"


def test_import_dialog_never_replaces_a_dataset_a_running_scan_holds(qtbot, tmp_path):
    """A dataset whose dataset.lock another process holds: refused at once in the dialog, naming that
    process, with no "Replace dataset?" question; a scan that starts there while the question is open
    is named when the import ends (failed, nothing replaced); once that process is gone (killed) its
    stale lock blocks nothing."""
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from tests.support.test_locks import hold_in_child

    src = make_virtual_dataset(tmp_path / "src", 3, 2, width_px=64, fmt="png")
    video = tmp_path / "lf.mkv"
    export_dataset(src, ExportOptions("hevc", video))
    ds = make_virtual_dataset(tmp_path / "ds", 2, 1, width_px=64, fmt="png").root
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    _menu_action(window, "Import HEVC…").trigger()
    dialog = window.findChild(ImportHevcDialog, "importHevcDialog")
    dialog.file_edit.setText(str(video))
    dialog.out_edit.setText(str(ds))
    children = []
    try:
        children.append(hold_in_child("dataset_lock", ds))
        dialog.import_button.click()
        text = dialog.message.text()
        assert f"dataset {ds} is in use by" in text and f"pid {children[0].pid}" in text and "stop that scan" in text
        assert not [b for b in dialog.findChildren(QMessageBox, "confirmOverwrite") if b.isVisible()]
        assert not dialog.runner.running
        children[0].kill()                         # the scan is gone: its stale lock stays behind
        children[0].wait(10)

        dialog.import_button.click()
        box = _shown_box(qtbot, dialog, "confirmOverwrite")
        children.append(hold_in_child("dataset_lock", ds))         # a scan starts there meanwhile
        with qtbot.waitSignal(dialog.runner.failed, timeout=60000):
            box.button(QMessageBox.Yes).click()
        assert f"pid {children[1].pid}" in dialog.message.text() and "in use by" in dialog.message.text()
        assert len(Dataset.open(ds).views) == 2                     # still the scan's dataset
        children[1].kill()
        children[1].wait(10)

        dialog.import_button.click()
        box = _shown_box(qtbot, dialog, "confirmOverwrite")
        with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
            box.button(QMessageBox.Yes).click()
        assert len(Dataset.open(ds).done_views()) == 6
    finally:
        for child in children:
            child.kill()
            child.wait(10)
            child.stdin.close()
            child.stdout.close()


def test_import_images_dialog_states_the_zero_plane_and_shows_it_with_the_measurement(qtbot, tmp_path):
    """Sheared views (a virtual capture shifted by shear · position) imported with their zero plane
    stated in the dialog: the summary says where zero disparity lies and what was measured."""
    from tests.export.test_sheared_import import GRID, shear_views

    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    make_virtual_dataset(tmp_path / "virtual", **GRID)
    f_px, _ = shear_views(tmp_path / "virtual", tmp_path / "sheared", 3.0)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    _menu_action(window, "Import images…").trigger()
    dialog = window.findChild(ImportImagesDialog, "importImagesDialog")
    dialog.folder_edit.setText(str(tmp_path / "sheared"))
    dialog.columns_spin.setValue(5)
    dialog.rows_spin.setValue(5)
    dialog.spacing_h.setValue(4.0)
    dialog.spacing_v.setValue(6.0)
    dialog.intrinsics_combo.setCurrentIndex(2)
    dialog.focal_px.setValue(f_px)
    dialog.positions_combo.setCurrentIndex(0)
    assert not dialog.positions_csv_row.isEnabled() and not dialog.zero_depth.isEnabled() or \
        dialog.zero_combo.currentIndex() == 2
    dialog.zero_combo.setCurrentIndex(2)
    assert dialog.zero_depth.isEnabled()
    dialog.zero_depth.setValue(3.0)
    # a CSV of positions that was not chosen: one line naming the field, nothing started
    assert dialog.isVisible()
    QApplication.processEvents()
    below = dialog.copy_check.pos()
    dialog.positions_combo.setCurrentIndex(2)
    assert dialog.positions_csv_row.isEnabled() and not dialog.spacing_h.isEnabled()
    QApplication.processEvents()
    assert dialog.copy_check.pos() == below        # the fields below do not move while one chooses
    dialog.positions_csv.setText("")
    dialog.out_edit.setText(str(tmp_path / "ds"))
    dialog.import_button.click()
    assert "Positions" in dialog.message.text() and not (tmp_path / "ds").exists()
    dialog.positions_combo.setCurrentIndex(0)
    shown: list[str] = []        # what the progress line said while the views were measured (6-11 s)

    def seen(done, total, message, eta_s):
        if message.startswith("disparities: ") and " of 25 views (" in message:
            shown.append(dialog.progress.message_label.toolTip() or dialog.progress.message_label.text())
            if len(shown) == 1:
                dialog.grab().save(str(tmp_path / "import_dialog_measuring.png"))
    dialog.runner.progress.connect(seen)
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.import_button.click()
    assert shown and all(s.startswith("disparities: ") and " of 25 views (" in s for s in shown)
    text = dialog.message.text()
    assert "zero disparity: sheared views, zero-disparity plane at 3.000 m" in text, text
    assert "between horizontal neighbours" in text
    assert Dataset.open(tmp_path / "ds").manifest["zero_disparity"]["source"] == "--zero-disparity-depth-m"
    QApplication.processEvents()
    assert dialog.message.height() > 3 * dialog.message.fontMetrics().height()   # every line shown
    dialog.grab().save(str(tmp_path / "import_dialog.png"))


@pytest.mark.parametrize("screen", [(1366, 768), (1920, 1080)])
def test_the_fields_stay_put_while_the_file_count_changes(qtbot, tmp_path, screen):
    """The count's message grew from one line to three as the operator typed and pushed the fields
    under it about 28 px down: a click meant for Focal length opened File order (issue 41, item 9)."""
    folder = _images(tmp_path / "rig", 6)
    for i in range(3):                                           # two kinds: the longest message, with a hint
        cv2.imwrite(str(folder / f"extra{i}.jpg"), np.zeros((8, 8, 3), np.uint8))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.resize(*screen)
    window.show()
    dialog = ImportImagesDialog(window.state, window)
    qtbot.addWidget(dialog)
    dialog.show()
    qtbot.waitExposed(dialog)
    watched = (dialog.order_combo, dialog.intrinsics_combo, dialog.out_edit)

    def places():
        return [w.mapTo(dialog, w.rect().topLeft()).y() for w in watched]

    start, size = places(), dialog.size()
    texts = []
    for typed in ("/", str(tmp_path / "nowhere" / ("deep" * 12)), str(folder), str(folder)[:-1]):
        dialog.folder_edit.setText(typed)
        dialog.recount()
        QApplication.processEvents()        # a relayout, if the text asks for one, happens here
        texts.append(dialog.count_label.text())
        assert places() == start and dialog.size() == size, (typed, dialog.count_label.text())
    assert any("Found 9 images" in t for t in texts) and len(set(texts)) >= 3, texts
    dialog.grab().save(str(tmp_path / f"import-{screen[0]}.png"))
