"""Scan panel and grid view on a real Qt event loop, with the instant simulated devices."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.panels.scan import ACTIVE_KEY, ScanPanel
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState
from lfstudio.gui.views.grid_view import CAPTURING, DONE, PENDING, GridView, recent_datasets
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.studio.session import create_scan_dataset
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig

RIG = load_rig()


def scanned(root, cols=4, rows=3, stop_after=None):
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "instant"}, lens={"name": "t"})
    rig = InstantRig(RIG)
    rig.connect()
    cam = InstantCamera(rig.true_position_mm)
    cam.connect()
    if stop_after is not None:
        plan = plan.with_subset([v.cell for v in plan.views()[:stop_after]])
    engine = ScanEngine(ds, plan, rig, cam, time_scale=0.0)
    engine.start()
    engine.wait(30)
    return Dataset.open(root)


def grid_view(qtbot, size=None):
    """A GridView on a fresh AppState; shown at ``size`` (w, h) when given."""
    state = AppState()
    view = GridView(state)
    qtbot.addWidget(view)
    if size is not None:
        view.resize(*size)
        view.show()
    return state, view


def scan_panel(qtbot, devices, columns, rows, folder):
    """A Scan panel on the instant devices, set to a ``columns`` x ``rows`` grid without settling."""
    state = AppState()
    state.devices.update(devices)
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.columns.setValue(columns)
    panel.rows.setValue(rows)
    panel.settle.setValue(0.0)
    panel.folder.setText(str(folder))
    return state, panel


def start_then_pause(qtbot, panel):
    """Start the panel's scan and wait until it says it is paused."""
    panel.start()
    qtbot.waitUntil(lambda: panel.engine is not None, timeout=10000)
    panel.pause()
    qtbot.waitUntil(lambda: "Paused" in panel.state_label.text(), timeout=20000)


def test_grid_view_empty_state_then_dataset_painted(qtbot, tmp_path):
    state, view = grid_view(qtbot, (800, 500))
    assert view.stack.currentWidget() is view.empty
    ds = scanned(tmp_path / "ds", stop_after=7)
    state.set_dataset(ds)
    assert view.stack.currentIndex() == 1
    canvas = view.canvas
    assert (canvas.status == DONE).sum() == 7 and (canvas.status == PENDING).sum() == 5
    assert "7 done" in view.counts.text() and "5 to capture" in view.counts.text()
    qtbot.waitUntil(lambda: canvas._mosaic_has.sum() == 7, timeout=5000)
    img = canvas.viewport().grab().toImage()
    # the first cell shows a thumbnail (not the background, not the pending colour)
    r = canvas._cell_rect(0, 0)
    c = img.pixelColor(r.center())
    assert c.name() not in ("#18191c", "#464a52")
    assert str(tmp_path / "ds") in recent_datasets()[0]


def test_grid_zoom_selection_and_recapture_request(qtbot, tmp_path):
    state, view = grid_view(qtbot, (900, 600))
    state.set_dataset(scanned(tmp_path / "ds"))
    canvas = view.canvas
    qtbot.waitExposed(view)
    canvas.fit()
    fit_px = canvas.cell_px
    canvas.set_zoom(400)
    assert canvas.cell_px == 400 and canvas.horizontalScrollBar().maximum() > 0
    qtbot.waitUntil(lambda: len(canvas._cache) > 0, timeout=5000)   # full thumbnails for visible cells
    canvas.fit()
    # fit: the whole grid is visible again, no scrolling
    qtbot.waitUntil(lambda: canvas.horizontalScrollBar().maximum() == 0
                    and canvas.verticalScrollBar().maximum() == 0, timeout=2000)
    assert canvas.cell_px < 400 and canvas.cell_px == pytest.approx(fit_px, rel=0.1)
    a = canvas._cell_rect(0, 1).center()
    b = canvas._cell_rect(1, 2).center()
    qtbot.mousePress(canvas.viewport(), Qt.LeftButton, pos=a)
    qtbot.mouseMove(canvas.viewport(), pos=b)
    qtbot.mouseRelease(canvas.viewport(), Qt.LeftButton, pos=b)
    assert canvas.selected == {(0, 1), (0, 2), (1, 1), (1, 2)}
    assert view.recapture_button.isEnabled()
    with qtbot.waitSignal(state.recaptureRequested) as sig:
        qtbot.mouseClick(view.recapture_button, Qt.LeftButton)
    assert sig.args[0] == [(0, 1), (0, 2), (1, 1), (1, 2)]
    assert not canvas.selected


def test_double_click_opens_the_view_full_size(qtbot, tmp_path):
    state, view = grid_view(qtbot, (800, 500))
    state.set_dataset(scanned(tmp_path / "ds"))
    pos = view.canvas._cell_rect(1, 1).center()
    qtbot.mouseDClick(view.canvas.viewport(), Qt.LeftButton, pos=pos)
    dlg = view._last_dialog
    qtbot.waitUntil(lambda: dlg.label.pixmap() is not None and not dlg.label.pixmap().isNull(), timeout=5000)
    assert "64 x 48 px" in dlg.info.text()
    dlg.close()


def test_scan_panel_runs_a_scan_and_the_grid_follows(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 5, 2, tmp_path / "scan1")
    grid = GridView(state)
    qtbot.addWidget(grid)
    panel.time_scale.setValue(0.0)
    assert "10 views" in panel.summary.text()
    qtbot.mouseClick(panel.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: panel.engine is not None, timeout=10000)
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=20000)   # events delivered
    assert not panel.running
    assert panel.progress.value() == 10 and panel.progress.maximum() == 10
    assert "Step times:" in panel.timings.text() and "move" in panel.timings.text()
    assert "done (10/10)" in panel.log_view.toPlainText()
    assert (grid.canvas.status == DONE).sum() == 10
    assert settings().value(ACTIVE_KEY, "") in ("", None)      # a complete scan is not offered for resume
    assert Dataset.open(tmp_path / "scan1").status_counts()["done"] == 10
    assert cam.captures == 10


def test_scan_panel_pause_resume_and_recapture(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    state, panel = scan_panel(qtbot, devices, 6, 2, tmp_path / "scan2")
    start_then_pause(qtbot, panel)
    assert panel.engine.state.value == "paused"
    assert panel.resume_button.isEnabled() and not panel.pause_button.isEnabled()
    qtbot.mouseClick(panel.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=20000)
    before = cam.captures
    state.recaptureRequested.emit([(1, 3), (0, 0)])
    qtbot.waitUntil(lambda: cam.captures == before + 2 and "Finished" in panel.state_label.text()
                    and not panel.running, timeout=20000)
    assert "re-capturing 2 views" in panel.log_view.toPlainText()


def test_interrupted_scan_is_offered_for_resume_on_start(qtbot, tmp_path):
    ds = scanned(tmp_path / "half", stop_after=5)
    settings().setValue(ACTIVE_KEY, str(ds.root))
    state = AppState()
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    qtbot.waitUntil(lambda: getattr(panel, "resume_box", None) is not None and panel.resume_box.isVisible(),
                    timeout=5000)
    text = panel.resume_box.text()
    assert "5 of 12 views" in text and "7 are missing" in text
    panel.resume_box.close()


def test_grid_follows_scan_events(qtbot, tmp_path):
    from lfstudio.scan.events import EventKind, ScanEvent

    state, view = grid_view(qtbot)
    state.set_dataset(scanned(tmp_path / "ds", stop_after=0))
    state.scanEvent.emit(ScanEvent(EventKind.VIEW_STARTED, row=0, column=2))
    assert view.canvas.status[0, 2] == CAPTURING
    state.scanEvent.emit(ScanEvent(EventKind.VIEW_FAILED, "camera timeout", row=0, column=2, will_retry=False))
    assert view.canvas.status[0, 2] == 3


def test_scan_panel_starts_the_simulated_studio_when_no_devices_are_connected(qtbot, tmp_path):
    state = AppState(simulated=True)
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.columns.setValue(2)
    panel.rows.setValue(1)
    panel.settle.setValue(0.0)
    panel.time_scale.setValue(0.0)
    panel.folder.setText(str(tmp_path / "simscan"))
    panel.start()
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=60000)
    try:
        assert panel.studio is not None and panel.studio.port.startswith("/dev/")   # a real pty
        ds = Dataset.open(tmp_path / "simscan")
        assert ds.status_counts()["done"] == 2
        assert ds.view(0, 1)["file"] == "raw/r00_c001.dng"
        assert ds.camera["name"] == "Simulated camera" and ds.camera.get("sensor_px")
    finally:
        panel.shutdown()


@pytest.mark.parametrize("fmt", ["png", "dng"])
def test_grid_shows_views_without_stored_thumbnails(qtbot, make_tiny_dataset, fmt):
    """A dataset without stored thumbnails (imported by hand, rendered by an older lfstudio): the
    grid decodes the view files themselves."""
    ds = make_tiny_dataset(fmt)
    for v in ds.views:                   # virtual-dataset stores thumbnails now: take them away
        (ds.root / v.pop("thumb")).unlink()
    ds.save()
    state, view = grid_view(qtbot, (900, 500))
    state.set_dataset(Dataset.open(ds.root))
    qtbot.waitUntil(lambda: bool(view.canvas._mosaic_has.all()), timeout=20000)
    tile = view.canvas.mosaic.copy(0, 0, 40, 30)
    from lfstudio.gui.imageutil import qimage_to_rgb
    assert qimage_to_rgb(tile).std() > 5   # image content, not a flat status colour
