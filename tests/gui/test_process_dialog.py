"""The Process… dialog on a real dataset: menu entry, preview, picking, run with progress, refresh."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.process_dialog import ProcessDialog
from lfstudio.gui.imageutil import qimage_to_rgb
from tests.processing.conftest import make_dataset  # noqa: F401  (fixture)


def _dialog(qtbot, ds):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(ds)
    actions = {a.text().replace("&", ""): a for a in window.menu("Dataset").actions()}
    assert "Process…" in actions and actions["Process…"].isEnabled()
    actions["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    assert dialog is not None
    return window, dialog


def test_preview_pick_and_process(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=3, gains={(0, 0): 1.1}, w=96, h=64)
    window, dialog = _dialog(qtbot, ds)
    dialog.editors["rectify"].setChecked(False)  # no calibration in this dataset
    dialog.workers_spin.setValue(2)                # a real process pool under the GUI
    with qtbot.waitSignal(dialog.preview_runner.finished, timeout=30000):
        dialog.update_preview()
    assert "gain" in dialog.preview_info.text()
    pixels = qimage_to_rgb(dialog.split_view.grab().toImage())
    assert pixels.std() > 5  # an image, not an empty frame

    # pick the white point by clicking the preview
    dialog.pick_white.click()
    assert dialog.split_view.pick_mode == "white"
    r = dialog.split_view.image_rect()
    qtbot.mouseClick(dialog.split_view, Qt.LeftButton, pos=QPoint(int(r.center().x()), int(r.center().y())))
    values = dialog.editors["color"].values()
    assert values["mode"] == "points" and values["white_point_px"] != [0.0, 0.0]
    assert dialog.split_view.pick_mode is None
    dialog.editors["color"].setChecked(False)

    changed = []
    window.state.datasetChanged.connect(changed.append)
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.process_button.click()
    assert "3 processed" in dialog.result_label.text()
    assert "process pool (2 workers)" in dialog.result_label.text()
    assert changed and changed[-1].view(0, 0)["processed"]["status"] == "done"
    assert "3</b> of 3" in window.panels["processingPanel"].summary.text()
    assert Dataset.open(ds.root).manifest["processing"]["profile"]["rectify"]["enabled"] is False


def test_bad_field_is_reported_not_raised(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    dialog.editors["lens"].fields["dist_coeffs"].setText("0.1 abc")
    dialog.update_preview()
    assert "dist coeffs" in dialog.preview_info.text() and not dialog.preview_runner.running


def test_processing_without_calibration_says_how_to_fix(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    dialog.workers_spin.setValue(0)
    with qtbot.waitSignal(dialog.runner.failed, timeout=30000):
        dialog.process_button.click()
    assert "calibrate" in dialog.result_label.text()


def test_broken_profile_file_is_reported_and_defaults_are_used(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    (ds.root / "processing.toml").write_text("[resample]\nscale = 7\n")
    window, dialog = _dialog(qtbot, ds)
    qtbot.waitUntil(lambda: "scale" in window.statusBar().currentMessage())
    assert dialog.profile() == dialog.profile().__class__()
