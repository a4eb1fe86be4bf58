"""A whole day in the simulated studio, through the app's own menus, panels and dialogs:
plan a scene → scan a small grid → calibrate → process → export HEVC and HCI → check the files."""

from __future__ import annotations

import configparser
import json

import av
import cv2
import numpy as np
from PySide6.QtCore import Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.calibration_wizard import PAGE_RESULTS, CalibrationWizard
from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS, ExportDialog
from lfstudio.gui.dialogs.process_dialog import ProcessDialog

COLUMNS, ROWS = 4, 3


def _action(window, menu: str, text: str):
    action = next(a for a in window.menu(menu).actions() if a.text().replace("&", "") == text)
    assert action.isEnabled(), f"{menu} → {text} is disabled"
    return action


def _type_into(qtbot, box, text: str) -> None:
    """Select a spin box's text and type like an operator."""
    box.setFocus()
    box.selectAll()
    qtbot.keyClicks(box.lineEdit(), text)


def test_a_whole_day_in_the_simulated_studio(qtbot, tmp_path):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    state = window.state
    planner, rig, camera, scan = (window.panels[n] for n in ("plannerDock", "rigDock", "cameraDock", "scanPanel"))

    # -- morning: plan the scene (a small grid today), then the rig and camera connect and home ----------
    grid = planner.rows["grid"].spins
    _type_into(qtbot, grid[0], str(COLUMNS))
    _type_into(qtbot, grid[1], str(ROWS))
    _type_into(qtbot, planner.rows["settle_s"].spins[0], "0")
    qtbot.waitUntil(lambda: state.plan is not None and (state.plan.grid_columns, state.plan.grid_rows)
                    == (COLUMNS, ROWS), timeout=10000)
    assert f"{COLUMNS * ROWS}" in planner.outputs["images"].text()
    qtbot.waitUntil(lambda: (scan.columns.value(), scan.rows.value()) == (COLUMNS, ROWS))   # the Scan panel follows

    camera.sim_width.setValue(640)                   # small images: the whole day in seconds
    window.connect_simulated_studio()
    qtbot.waitUntil(lambda: camera.connected and "Connected" in camera.status_label.text(), timeout=60000)
    state.devices["rig_simulator"].time_scale = 0.02
    qtbot.waitUntil(lambda: rig.home_button.isEnabled(), timeout=20000)
    _action(window, "Rig", "Home rig").trigger()
    qtbot.waitUntil(lambda: "homed" in window.statusBar().currentMessage().lower(), timeout=30000)

    # -- scan ------------------------------------------------------------------------------------------
    scan.time_scale.setValue(0.0)
    root = tmp_path / "studio_day"
    scan.folder.setText(str(root))
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=120000)
    assert state.dataset is not None and state.dataset.root == root
    assert Dataset.open(root).status_counts()["done"] == COLUMNS * ROWS
    assert window.central.minimumSizeHint().width() < 600      # the grid's header never widens the window

    # -- calibrate: Dataset → Calibrate…, the default views (3 × 4 of the 4 × 3 grid), accept ------------
    _action(window, "Dataset", "Calibrate…").trigger()
    wizard = window.findChild(CalibrationWizard)
    assert wizard is not None and len(wizard.picker.selected) == 12
    with qtbot.waitSignal(wizard.runner.finished, timeout=60000):
        qtbot.mouseClick(wizard.next_button, Qt.LeftButton)
    assert wizard.stack.currentIndex() == PAGE_RESULTS and "→" in wizard.headline.text()
    qtbot.mouseClick(wizard.accept_button, Qt.LeftButton)
    assert (root / "calibration.json").is_file()
    qtbot.waitUntil(lambda: "Calibrated" in window.panels["calibrationPanel"].summary.text())

    # -- process: Dataset → Process…, default profile (rectified with the calibration) --------------------
    _action(window, "Dataset", "Process…").trigger()
    process = window.findChild(ProcessDialog, "processDialog")
    assert process is not None
    process.workers_spin.setValue(1)
    with qtbot.waitSignal(process.runner.finished, timeout=60000):
        qtbot.mouseClick(process.process_button, Qt.LeftButton)
    assert f"{COLUMNS * ROWS} processed" in process.result_label.text()
    process.close()
    processed = Dataset.open(root)
    assert all((v.get("processed") or {}).get("status") == "done" for v in processed.views)

    # -- export: File → Export dataset…, HEVC then HCI ------------------------------------------------------
    _action(window, "File", "Export dataset…").trigger()
    export = window.findChild(ExportDialog, "exportDialog")
    assert export is not None and export.isVisible()
    exports = tmp_path / "exports"
    exports.mkdir()
    export.folder_edit.setText(str(exports))

    export.format_combo.setCurrentIndex(FORMAT_KEYS.index("hevc"))
    qtbot.waitUntil(lambda: export.estimate is not None and export.export_button.isEnabled(), timeout=20000)
    assert export.estimate.source == "processed" and len(export.estimate.views) == COLUMNS * ROWS
    with qtbot.waitSignal(export.runner.finished, timeout=120000):
        qtbot.mouseClick(export.export_button, Qt.LeftButton)
    video = exports / "studio_day.mp4"
    assert export.report.out == video and export.report.psnr_db > 40 and "PSNR" in export.result_label.text()

    export.format_combo.setCurrentIndex(FORMAT_KEYS.index("hci"))
    export.hci_columns.setValue(3)
    export.hci_rows.setValue(3)
    qtbot.waitUntil(lambda: export.estimate is not None and len(export.estimate.views) == 9
                    and export.export_button.isEnabled(), timeout=20000)
    with qtbot.waitSignal(export.runner.finished, timeout=120000):
        qtbot.mouseClick(export.export_button, Qt.LeftButton)
    hci_folder = exports / "studio_day_hci"
    assert export.report.out == hci_folder and export.open_folder_button.isEnabled()

    # -- evening: the exported files are what the other tools expect ----------------------------------------
    side = json.loads((exports / "studio_day.mp4.json").read_text())
    frames = [tuple(f) for f in side["frames"]]
    meander = [(r, c) for r in range(ROWS) for c in (range(COLUMNS) if r % 2 == 0 else reversed(range(COLUMNS)))]
    assert frames == meander
    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        decoded = [f.to_ndarray(format="rgb48le") for f in container.decode(stream)]
    assert len(decoded) == COLUMNS * ROWS
    w, h = processed.manifest["processing"]["output_size_px"]
    assert decoded[0].shape == (h + h % 2, w + w % 2, 3)          # x265 pads odd sizes by one pixel
    views = {}
    for v in processed.views:
        bgr = cv2.imread(str(root / v["processed"]["file"]), cv2.IMREAD_UNCHANGED)
        views[(v["row"], v["column"])] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float64)
    for k, frame in enumerate(decoded):             # each frame is closest to the view the sidecar names
        f = frame[:h, :w].astype(np.float64)
        errors = {view: np.mean((f - img) ** 2) for view, img in views.items()}
        assert min(errors, key=errors.get) == frames[k]
        assert 10 * np.log10(65535.0 ** 2 / errors[frames[k]]) > 40

    cfg = configparser.ConfigParser()
    cfg.read(hci_folder / "parameters.cfg")
    assert int(cfg["extrinsics"]["num_cams_x"]) == 3 and int(cfg["extrinsics"]["num_cams_y"]) == 3
    assert float(cfg["extrinsics"]["baseline_mm"]) > 0 and float(cfg["intrinsics"]["focal_length_mm"]) > 0
    cams = sorted(hci_folder.glob("input_Cam*.png"))
    assert [p.name for p in cams] == [f"input_Cam{i:03d}.png" for i in range(9)]
    first = cv2.imread(str(cams[0]), cv2.IMREAD_UNCHANGED)
    assert first is not None and first.shape[1] == int(cfg["intrinsics"]["image_resolution_x_px"])
    assert np.std(first) > 1                         # a picture, not an empty frame
    window.close()
