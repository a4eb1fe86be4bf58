"""Exposure brackets in the window on a real Qt event loop: the Scan panel's Bracket field (a bad
bracket named in red, frames in the summary, a scan that stores every frame under its view, the
field disabled while it runs) and the Planner's Bracket row (time and disk count every frame)."""

from __future__ import annotations

import pytest
from PySide6.QtWidgets import QScrollArea

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.panels.scan import ScanPanel
from lfstudio.gui.state import AppState
from lfstudio.planning.presets import reference_plan
from lfstudio.rig.profile import load_rig
from lfstudio.sim.instant import InstantRig

RIG = load_rig()


def test_scan_panel_bracket_field(qtbot, instant_devices, tmp_path):
    devices, _, cam = instant_devices
    state = AppState()
    state.devices.update(devices)
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.columns.setValue(2)
    panel.rows.setValue(1)
    panel.settle.setValue(0.0)
    panel.folder.setText(str(tmp_path / "ds"))
    panel.bracket.setText("-2,0,x")
    assert "Bracket: 'x' is not an EV step" in panel.summary.text() and "e06060" in panel.summary.text()
    panel.bracket.clear()
    qtbot.keyClicks(panel.bracket, "1/500,1/125s")
    assert "2 views × 2 frames (1/500 s, 1/125 s)" in panel.summary.text()
    panel.resize(520, 900)
    panel.show()
    qtbot.waitExposed(panel)
    panel.grab().save(str(tmp_path / "scan_panel.png"))
    panel.start()
    qtbot.waitUntil(lambda: panel.engine is not None, timeout=10000)
    qtbot.waitUntil(lambda: not panel.bracket.isEnabled() or "Finished" in panel.state_label.text(), timeout=10000)
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=20000)
    assert panel.bracket.isEnabled()
    ds = Dataset.open(tmp_path / "ds")
    assert ds.manifest["bracket"]["frame_shutter_s"] == pytest.approx([0.002, 0.008])
    assert all([f["shutter_s"] for f in v["frames"]] == pytest.approx([0.002, 0.008]) for v in ds.views)
    assert cam.captures == 4


def test_planner_bracket_row_counts_every_frame(qtbot, tmp_path):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.resize(1500, 950)
    window.show()
    qtbot.waitExposed(window)
    p = window.panels["plannerDock"]
    qtbot.waitUntil(lambda: window.state.plan is not None)
    assert window.state.plan == reference_plan()
    single = p.result
    p.bracket_edit.setFocus()
    qtbot.keyClicks(p.bracket_edit, "-2,0,+2")
    qtbot.waitUntil(lambda: p.plan is not None and p.plan.bracket == "-2,0,+2", timeout=3000)
    r = p.result
    assert r.frames_per_view == 3 and r.frames == 3 * 2121
    assert r.storage_bytes == 3 * single.storage_bytes
    # 0.125 + 0.5 + 2 s of exposure and two transfers between the frames, at every view
    assert r.capture_time_s - single.capture_time_s == pytest.approx(2121 * (0.125 + 2.0 + 2 * 2.5), rel=1e-6)
    assert p.outputs["images"].text() == "101 × 21 = 2121, 6363 frames"
    assert "3 a view" in p.outputs["disk"].text()
    scroll = p.findChild(QScrollArea, "plannerScroll")
    scroll.ensureWidgetVisible(p.bracket_edit)
    p.grab().save(str(tmp_path / "planner.png"))
    p.bracket_edit.setText("-2,0,-2")
    qtbot.waitUntil(lambda: p.rows["bracket"].message.isVisible(), timeout=3000)
    assert "given twice" in p.rows["bracket"].message.text() and "Bracket" in p.status_label.text()


def test_process_dialog_merges_a_bracketed_dataset(qtbot, tmp_path):
    from dataclasses import replace

    from lfstudio.dataset.bracket import parse_bracket
    from lfstudio.gui.dialogs.process_dialog import ProcessDialog
    from lfstudio.scan.engine import ScanEngine
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.sim.sim_camera import SimulatedCamera
    from lfstudio.sim.studio import VirtualStudio
    from lfstudio.studio.session import create_scan_dataset

    plan = replace(ScanPlan.centered(2, 1, (4.0, 6.0), RIG, settle_s=0.0), bracket=parse_bracket("-2,0,+2"))
    rig = InstantRig(RIG)
    rig.connect()
    camera = SimulatedCamera(VirtualStudio(width_px=96, view_region_mm=plan.extent_mm(), highlight_gain=3.0),
                             rig.true_position_mm, exposure_s=0.5, time_scale=0.0)
    camera.connect()
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    engine = ScanEngine(ds, plan, rig, camera, time_scale=0.0)
    engine.start()
    engine.wait(60)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(Dataset.open(ds.root))
    actions = {a.text().replace("&", ""): a for a in window.menu("Dataset").actions()}
    actions["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    dialog.editors["rectify"].setChecked(False)
    dialog.workers_spin.setValue(0)
    shares = []
    dialog.runner.progress.connect(lambda done, total, _message, _eta: shares.append(done / max(total, 1)))
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.process_button.click()
    # one bar for both passes: it never drops back to 0 when the merge starts
    assert shares and shares == sorted(shares) and shares[-1] == 1.0, shares
    text = dialog.result_label.text()
    dialog.show()
    qtbot.waitUntil(lambda: dialog.result_label.height() >= 2 * dialog.result_label.fontMetrics().height())
    dialog.grab().save(str(tmp_path / "process_dialog.png"))
    assert "2 processed" in text and "HDR: 2 views merged" in text and "after the merge" in text
    again = Dataset.open(ds.root)
    assert all(v["hdr"]["status"] == "done" and (again.root / v["hdr"]["file"]).is_file() for v in again.views)


def test_a_dataset_that_refuses_a_resume_is_named_in_the_windows_words(qtbot, instant_devices, tmp_path):
    """Starting again into a folder whose dataset does not match is refused in the window's words: it
    said '--out: … holds another scan' (another grid) and '--bracket: … resume without --bracket' (a
    bracket typed for a dataset of single pictures)."""
    devices, _, cam = instant_devices
    state = AppState()
    state.devices.update(devices)
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.columns.setValue(30)
    panel.rows.setValue(1)
    panel.settle.setValue(0.0)
    panel.folder.setText(str(tmp_path / "ds"))
    messages: list[str] = []
    state.errorOccurred.connect(lambda _title, message: messages.append(message))
    panel.start()                                     # some views captured, one picture each, then Abort
    qtbot.waitUntil(lambda: panel.engine is not None and panel.engine.dataset.status_counts()["done"] >= 2,
                    timeout=20000)
    panel.abort()
    qtbot.waitUntil(lambda: "Aborted" in panel.state_label.text() and not panel.running, timeout=20000)
    captured = cam.captures

    def refused() -> str:
        messages.clear()
        before = len(panel.log_view.toPlainText())

        def told() -> str:      # a refusal before the scan (a message box) or the engine's (its log, its state)
            return " ".join(messages) + " " + panel.state_label.text() + " " + panel.log_view.toPlainText()[before:]

        panel.start()
        qtbot.waitUntil(lambda: bool(messages) or "one picture each" in told(), timeout=20000)
        return told()

    panel.columns.setValue(31)
    shown = refused()
    assert "holds another scan" in shown and "Folder:" in shown and "--out" not in shown, shown
    panel.columns.setValue(30)
    panel.bracket.setText("-2,0,+2")
    shown = refused()
    assert "one picture each" in shown and "Bracket:" in shown and "empty the Bracket field" in shown, shown
    assert "--bracket" not in shown, shown
    assert cam.captures == captured
