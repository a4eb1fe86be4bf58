"""Each front end names its own controls (issue #41 item 3): a message the core raises carries the
command line's and the window's words for the options it names (lfstudio.errors.words); the window
shows its controls (Process dialog, Import dialog), the command line its options. And a sheared
archive imported without its zero plane is no dead end (item 2): the summary says what works, and
calibration runs. Real Qt event loop (pytest-qt), real datasets, real subprocesses for the CLI."""

from __future__ import annotations

import re

import pytest
from PySide6.QtWidgets import QApplication

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.import_dialog import ImportImagesDialog
from lfstudio.gui.dialogs.process_dialog import ProcessDialog

#: a command-line option or command in a message: what the window must not show
CLI_WORDS = re.compile(r"(?<![\w-])--[a-z][a-z-]+|lfstudio (calibrate|process|import)|processing\.toml|calibration\.json")


def _process_dialog(qtbot, ds):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(ds)
    actions = {a.text().replace("&", ""): a for a in window.menu("Dataset").actions()}
    actions["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    assert dialog is not None
    return window, dialog


def test_the_process_dialog_on_an_uncalibrated_dataset_names_its_own_controls(qtbot, make_dataset):
    """It said "processing.toml: [rectify]: …/calibration.json not found; calibrate the dataset first
    ('lfstudio calibrate') or switch rectification off (enabled = false)" in the window."""
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _process_dialog(qtbot, ds)
    dialog.workers_spin.setValue(0)
    with qtbot.waitSignal(dialog.runner.failed, timeout=30000):
        dialog.process_button.click()
    text = dialog.result_label.text()
    assert "Dataset → Calibrate…" in text and "untick 6 Rectification (calibration)" in text, text
    assert not CLI_WORDS.search(text), text
    for w, h in ((1366, 768), (1920, 1080)):
        window.resize(w, h)
        QApplication.processEvents()
        dialog.grab().save(f"/tmp/inputs42_process_uncalibrated_{w}.png")


def test_the_command_line_names_its_flag_for_the_same_refusal(make_dataset, run_cli):
    ds = make_dataset(rows=1, cols=2)
    proc = run_cli("process", ds.root)
    assert proc.returncode == 2, proc.stderr
    assert "--no-rectify" in proc.stderr and f"lfstudio calibrate {ds.root}" in proc.stderr, proc.stderr
    assert "Dataset → Calibrate" not in proc.stderr and "\x1f" not in proc.stderr


@pytest.fixture(scope="module")
def sheared_folder(tmp_path_factory):
    """A virtual capture sheared to zero disparity at 3 m, as archives publish theirs; (folder, f_px)."""
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from tests.export.test_sheared_import import GRID, shear_views

    base = tmp_path_factory.mktemp("sheared")
    make_virtual_dataset(base / "virtual", **GRID)
    f_px, _ = shear_views(base / "virtual", base / "sheared", 3.0)
    return base / "sheared", f_px


def test_the_import_dialog_summary_of_unstated_sheared_views_says_what_works_in_its_own_words(
        qtbot, tmp_path, sheared_folder):
    """The summary said "import again with --zero-disparity-depth-m for depths" (and the CLI's "next:
    lfstudio calibrate", which calibrate then refused): a dead end, in command-line words."""
    folder, f_px = sheared_folder
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    actions = {a.text().replace("&", ""): a for a in window.menu("File").actions()}
    actions["Import images…"].trigger()
    dialog = window.findChild(ImportImagesDialog, "importImagesDialog")
    dialog.folder_edit.setText(str(folder))
    dialog.columns_spin.setValue(5)
    dialog.rows_spin.setValue(5)
    dialog.spacing_h.setValue(4.0)
    dialog.spacing_v.setValue(6.0)
    dialog.intrinsics_combo.setCurrentIndex(2)
    dialog.focal_px.setValue(f_px)
    dialog.positions_combo.setCurrentIndex(0)
    dialog.zero_combo.setCurrentIndex(0)          # measure: the plane is not stated
    dialog.out_edit.setText(str(tmp_path / "ds"))
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.import_button.click()
    text = dialog.message.text()
    assert "zero-disparity plane not stated" in text and "calibration" in text and "work without it" in text, text
    assert "Zero disparity: Sheared, zero-disparity plane at" in text and "Focal length (px) field" in text, text
    assert not CLI_WORDS.search(text), text
    for w, h in ((1366, 768), (1920, 1080)):
        window.resize(w, h)
        QApplication.processEvents()
        dialog.grab().save(f"/tmp/inputs42_import_sheared_{w}.png")


def test_unstated_sheared_views_calibrate_and_the_command_line_names_its_options(tmp_path, sheared_folder, run_cli):
    folder, f_px = sheared_folder
    proc = run_cli("import-images", folder, "--grid", "5x5", "--spacing-mm", "4x6", "--focal-length-px", f"{f_px:.6f}",
                   "--out", tmp_path / "ds", timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "--zero-disparity-depth-m" in proc.stdout and "work without it" in proc.stdout, proc.stdout
    assert "\x1f" not in proc.stdout + proc.stderr
    assert f"next: lfstudio calibrate {tmp_path / 'ds'}" in proc.stdout
    proc = run_cli("calibrate", tmp_path / "ds", timeout=300)           # was refused: a dead end
    assert proc.returncode == 0, proc.stderr
    doc = Dataset.open(tmp_path / "ds").manifest
    assert doc["zero_disparity"]["shear_px_per_mm"] is None        # still not stated: nothing invented
    import json

    cal = json.loads((tmp_path / "ds" / "calibration.json").read_text())
    assert cal["settings"]["zero_plane"]["assumed_shear_px_per_mm"] > 0


def test_a_missing_focal_length_is_named_in_each_front_ends_words(tmp_path):
    """Dataset.focal_length_px's refusal (met by the Calibrate dialog) named 'lfstudio calibrate
    --focal-length-px F' in the window too."""
    import cv2
    import numpy as np

    from lfstudio.errors import DatasetError, window_message
    from lfstudio.export.import_images import ImportOptions, import_images

    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(2):
        assert cv2.imwrite(str(folder / f"v{i}.png"), np.full((32, 48, 3), 40 * i, np.uint8))
    ds = Dataset.open(import_images(ImportOptions(folder, tmp_path / "ds", (2, 1), (5.0, 5.0))))
    with pytest.raises(DatasetError) as err:
        ds.focal_length_px(48)
    assert "lfstudio calibrate --focal-length-px F" in str(err.value)
    shown = window_message(err.value)
    assert "the Calibrate dialog's Focal length" in shown and not CLI_WORDS.search(shown), shown


def test_the_export_dialog_refuses_a_posed_export_of_unstated_sheared_views_in_its_own_words(
        qtbot, tmp_path, sheared_folder):
    """The estimate's refusal said "import them again with --zero-disparity-depth-m (or
    --parallel-views …)" in the window."""
    from lfstudio.export.import_images import ImportOptions, import_images
    from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS, ExportDialog
    from lfstudio.quality.shear import measure_shear

    folder, f_px = sheared_folder
    ds = Dataset.open(import_images(ImportOptions(folder, tmp_path / "ds", (5, 5), (4.0, 6.0), focal_length_px=f_px,
                                                  measure=measure_shear)))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(ds)
    next(a for a in window.menu("File").actions() if a.text().replace("&", "") == "Export dataset…").trigger()
    dialog = window.findChild(ExportDialog, "exportDialog")
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("colmap"))
    qtbot.waitUntil(lambda: dialog.estimate_error is not None, timeout=30000)
    text = dialog.estimate_error
    assert "sheared by an amount nobody stated" in text and "Zero disparity set to a depth" in text, text
    assert "PNG and HEVC exports need no plane" in text and not CLI_WORDS.search(text), text


def test_the_import_dialog_names_a_file_whose_name_is_not_utf8_by_its_bytes_and_its_own_field(qtbot, tmp_path):
    """#42 item 10 in the window: the live count names the file escaped and the Files (pattern) field."""
    import os

    import cv2
    import numpy as np

    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(2):
        assert cv2.imwrite(str(folder / f"v{i}.png"), np.full((32, 48, 3), 40 * i, np.uint8))
    os.rename(folder / "v1.png", folder / os.fsdecode(b"v_\xe9.png"))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    actions = {a.text().replace("&", ""): a for a in window.menu("File").actions()}
    actions["Import images…"].trigger()
    dialog = window.findChild(ImportImagesDialog, "importImagesDialog")
    dialog.folder_edit.setText(str(folder))
    assert dialog.recount() is None
    shown = dialog.count_label.toolTip() or dialog.count_label.text()
    assert "v_\\xe9.png" in shown and "not valid UTF-8" in shown and "Files (pattern) field" in shown, shown
    assert not CLI_WORDS.search(shown), shown
