"""Render the README's "A day in the studio" screenshots from the real windows, offscreen.

    python docs/make_screenshots.py            # writes docs/screenshot.png, docs/day-*.png, docs/quality-*.png
    python docs/make_screenshots.py quality    # only the quality check's pictures (docs/quality-*.png)

It drives the same steps as ``tests/gui/test_whole_day.py`` on the simulated studio (plan → scan →
calibrate → process → export) in a temporary folder and grabs the window or dialog after each step.
The quality pictures come from a virtual-studio dataset with injected faults (a blurred, a brighter,
a displaced view and a skipped step), calibrated and checked in the window.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ["LFSTUDIO_CONFIG_DIR"] = tempfile.mkdtemp(prefix="lfstudio-shots-config-")

from PySide6.QtCore import Qt  # noqa: E402
from PySide6.QtGui import QImage  # noqa: E402
from PySide6.QtTest import QTest  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

COLUMNS, ROWS = 9, 3
MAX_WIDTH_PX = 1100


def wait_until(condition, timeout_s: float = 120.0, what: str = "") -> None:
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            raise TimeoutError(f"timed out waiting for {what or condition}")
        QTest.qWait(20)


def save(widget, name: str, max_width_px: int = MAX_WIDTH_PX) -> None:
    QTest.qWait(300)                       # let queued repaints land
    image = widget.grab().toImage()
    if image.width() > max_width_px:
        image = image.scaledToWidth(max_width_px, Qt.SmoothTransformation)
    path = HERE / name
    image.save(str(path))
    if path.stat().st_size > 150_000:     # a palette PNG (no dithering: flat UI stays flat) is much smaller
        image.convertToFormat(QImage.Format_Indexed8, Qt.ThresholdDither | Qt.AvoidDither).save(str(path))
    print(f"{path.relative_to(HERE.parent)}: {image.width()} x {image.height()} px, "
          f"{path.stat().st_size // 1024} kB")


def type_into(box, text: str) -> None:
    box.setFocus()
    box.selectAll()
    QTest.keyClicks(box.lineEdit(), text)


def quality_shots() -> None:
    """docs/quality-heatmap.png (the grid coloured by sharpness, flagged views outlined) and
    docs/quality-disparity.png (the disparity map of the centre view)."""
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import save_calibration
    from lfstudio.gui.app import create_window
    from lfstudio.sim.studio import DEMO_ROTATION_DEG, ViewFault
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    work = Path(tempfile.mkdtemp(prefix="lfstudio-shots-quality-"))
    faults = [ViewFault("blur", 1, 2, blur_px=6.0), ViewFault("luminance", 3, 6, gain=1.3),
              ViewFault("displaced", 2, 4, offset_mm=(1.0, 0.0)), ViewFault("skipped", 4, 3)]
    ds = make_virtual_dataset(work / "studio_check", 9, 5, width_px=1000, fmt="png", rotation_deg=DEMO_ROTATION_DEG,
                              faults=faults)
    save_calibration(ds, calibrate_dataset(ds, "array:3x2").document)
    window = create_window(simulated=True)
    window.resize(1500, 900)
    window.show()
    for dock in window.docks.values():
        dock.hide()                        # the grid alone fills the window
    grid = window.central
    grid.open_dataset(str(ds.root))
    bar = grid.quality_bar
    bar.check_button.click()
    wait_until(lambda: not bar.runner.running and grid.canvas.quality, what="the quality check")
    bar.overlay.setCurrentIndex(bar.overlay.findData("sharpness"))
    wait_until(lambda: grid.canvas._mosaic_has.all(), what="the thumbnails")
    save(grid, "quality-heatmap.png")
    grid.show_disparity()
    dialog = grid._disparity_dialog
    dialog.resize(1060, 800)
    save(dialog, "quality-disparity.png")
    window.close()


def main() -> int:
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setStyleSheet((HERE.parent / "resources" / "style.qss").read_text(encoding="utf-8"))
    if sys.argv[1:] == ["quality"]:
        quality_shots()
        return 0
    from lfstudio.gui.app import create_window
    from lfstudio.gui.dialogs.calibration_wizard import CalibrationWizard
    from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS, ExportDialog
    from lfstudio.gui.dialogs.process_dialog import ProcessDialog

    work = Path(tempfile.mkdtemp(prefix="lfstudio-shots-"))
    window = create_window(simulated=True)
    window.resize(1500, 900)
    window.show()
    state = window.state
    planner, rig, camera, scan = (window.panels[n] for n in ("plannerDock", "rigDock", "cameraDock", "scanPanel"))

    # 1. plan
    window.docks["plannerDock"].raise_()
    type_into(planner.rows["grid"].spins[0], str(COLUMNS))
    type_into(planner.rows["grid"].spins[1], str(ROWS))
    type_into(planner.rows["settle_s"].spins[0], "0")
    wait_until(lambda: state.plan is not None and state.plan.grid_columns == COLUMNS
               and state.plan.grid_rows == ROWS, what="the plan")
    save(window, "day-1-plan.png")

    # 2. connect, home, scan
    camera.sim_width.setValue(1000)
    window.connect_simulated_studio()
    wait_until(lambda: camera.connected, what="the camera")
    state.devices["rig_simulator"].time_scale = 0.02
    wait_until(lambda: rig.home_button.isEnabled(), what="the rig")
    rig.home()
    wait_until(lambda: "homed" in window.statusBar().currentMessage().lower(), what="homing")
    window.docks["scanPanel"].raise_()
    scan.time_scale.setValue(0.0)
    scan.folder.setText(str(work / "studio_day"))
    scan.start_button.click()
    wait_until(lambda: "Finished" in scan.state_label.text(), what="the scan")
    QTest.qWait(1500)                      # thumbnails
    save(window, "screenshot.png", 1400)   # the README's first picture: the default layout
    for name in ("planPlotsDock", "liveViewDock"):
        window.docks[name].hide()          # room for the grid
    save(window, "day-2-scan.png")

    # 3. calibrate
    next(a for a in window.menu("Dataset").actions() if a.text().replace("&", "") == "Calibrate…").trigger()
    wizard = window.findChild(CalibrationWizard)
    wizard.resize(1100, 720)
    wizard.next_button.click()
    wait_until(lambda: wizard.result is not None, what="the calibration")
    wait_until(lambda: hasattr(wizard, "inspection"), what="the EPIs")
    wizard.tabs.setCurrentIndex(1)
    save(wizard, "day-3-calibrate.png")
    wizard.accept_button.click()

    # 4. process
    next(a for a in window.menu("Dataset").actions() if a.text().replace("&", "") == "Process…").trigger()
    process = window.findChild(ProcessDialog, "processDialog")
    process.resize(1100, 720)
    process.update_preview()
    wait_until(lambda: not process.preview_runner.running and process.preview_button.isEnabled(), what="preview")
    process.process_button.click()
    wait_until(lambda: "processed" in process.result_label.text() and not process.runner.running,
               what="processing")
    save(process, "day-4-process.png")
    process.close()

    # 5. export: HEVC, then HCI
    next(a for a in window.menu("File").actions() if a.text().replace("&", "") == "Export dataset…").trigger()
    export = window.findChild(ExportDialog, "exportDialog")
    export.resize(880, 760)
    (work / "exports").mkdir()
    export.folder_edit.setText(str(work / "exports"))
    export.format_combo.setCurrentIndex(FORMAT_KEYS.index("hci"))
    export.hci_columns.setValue(3)
    export.hci_rows.setValue(3)
    wait_until(lambda: export.estimate is not None and export.export_button.isEnabled(), what="HCI estimate")
    export.export_button.click()
    wait_until(lambda: export.report is not None and not export.exporting, what="HCI export")
    export.format_combo.setCurrentIndex(FORMAT_KEYS.index("hevc"))
    wait_until(lambda: export.estimate is not None and export.export_button.isEnabled(), what="HEVC estimate")
    export.export_button.click()
    wait_until(lambda: not export.exporting and export.report is not None and export.report.format == "hevc",
               what="HEVC export")
    save(export, "day-5-export.png")
    print(export.report.summary())
    window.close()
    quality_shots()
    return 0


if __name__ == "__main__":
    sys.exit(main())
