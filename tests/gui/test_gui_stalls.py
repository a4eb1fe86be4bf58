"""The GUI thread only paints: the watchdog names what stalls it; the work behind the stalls found with
it (planner plots, the scan path, the grid, scan events, opening a dataset) is done in place, once a
frame or off the GUI thread. Behaviour only: timing figures are in benchmarks/ (grid_gui.py,
planner_update.py), not here."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
from PySide6.QtWidgets import QGraphicsItem

from lfstudio.dataset import Dataset
from lfstudio.gui.heartbeat import Heartbeat, keep_out_of_gc
from lfstudio.gui.imageutil import qimage_to_rgb
from lfstudio.gui.panels.planner import STICKY_FILL, PlanPlotsPanel, sticky_range
from lfstudio.gui.views.path_preview import PathPreview
from lfstudio.gui.state import AppState
from lfstudio.gui.views.grid_view import DONE, GridView
from lfstudio.planning.presets import reference_plan
from lfstudio.rig.profile import load_rig
from lfstudio.scan.events import EventKind, ScanEvent
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


# -- the watchdog --------------------------------------------------------------------------------------
def _hold_the_gui_thread(heart: Heartbeat, sampled) -> None:
    """Runs on the GUI thread: busy until the watchdog has seen this function in most of the samples
    of this overdue tick (``sampled()``: samples naming it, samples of others) and the tick is
    overdue by more than its warning threshold (no sleep: the GUI thread computes)."""
    limit = time.perf_counter() + 30.0
    overdue_s = (heart.interval_ms + heart.warn_ms) / 1000.0 + 0.005
    x = 0
    while time.perf_counter() < limit:
        x += 1
        ours, others = sampled()
        if ours >= 3 and ours > others and time.perf_counter() - heart._last > overdue_s:
            return


class _Samples:
    """The watchdog's samples, as an ``on_sample`` hook: how many named the hold, how many did not."""

    def __init__(self) -> None:
        self.ours = self.others = 0

    def __call__(self, where: str) -> None:
        if "_hold_the_gui_thread" in where:
            self.ours += 1
        else:
            self.others += 1


def _compute_until(done: threading.Event) -> None:
    x = 0
    while not done.is_set():
        for _ in range(1000):
            x += 1


def test_watchdog_names_the_code_that_stalled_the_gui_thread(qtbot):
    from PySide6.QtCore import QTimer

    heart = Heartbeat(interval_ms=10, warn_ms=20, watch=True)
    samples = _Samples()
    heart.on_sample = samples
    done = threading.Event()
    helper = threading.Thread(target=_compute_until, args=(done,), name="busy-helper", daemon=True)
    helper.start()                                   # another thread running Python meanwhile
    heart.start()
    try:
        qtbot.waitUntil(lambda: heart.ticks >= 3, timeout=30000)     # past the loop's own start
        samples.others = 0
        QTimer.singleShot(0, lambda: _hold_the_gui_thread(heart, lambda: (samples.ours, samples.others)))
        # (a stall of the loop's own start-up on a loaded machine may come first: look for ours)
        qtbot.waitUntil(lambda: any("_hold_the_gui_thread" in s.where for s in heart.stalls), timeout=30000)
    finally:
        heart.stop()
        done.set()
        helper.join(10)
    stall = next(s for s in heart.stalls if "_hold_the_gui_thread" in s.where)
    assert stall.duration_ms > heart.warn_ms
    assert stall.samples >= 1
    assert "busy-helper: " in stall.others and "_compute_until" in stall.others   # named as a competitor
    assert stall.cpu_ms > 0                      # the GUI thread itself was busy (not waiting)
    assert heart.max_stall_ms >= stall.duration_ms and heart.max_cpu_ms > 0
    assert "_hold_the_gui_thread" in str(stall)


def test_heartbeat_without_watch_records_stalls_but_no_source(qtbot):
    from PySide6.QtCore import QTimer

    heart = Heartbeat(interval_ms=10, warn_ms=20, record=True)
    heart.start()
    QTimer.singleShot(0, lambda: _spin_past(heart))
    qtbot.waitUntil(lambda: bool(heart.stalls), timeout=30000)
    watching_run_delay = heart._run_delay_fd is not None
    heart.stop()
    assert heart.stalls[0].where == "not watched" and heart.stalls[0].samples == 0
    assert all(t.queued_ms >= 0 for t in heart.tick_log)
    if sys.platform.startswith("linux"):       # how long it waited for a core comes from its schedstat
        assert watching_run_delay and heart._run_delay_fd is None      # (closed by stop())
    assert heart.tick_log and all(t.gc_ms == 0 and t.event == "" for t in heart.tick_log)   # not asked for


def test_heartbeat_records_garbage_collections_per_tick(qtbot):
    from PySide6.QtCore import QTimer

    heart = Heartbeat(interval_ms=10, record=True, gc_watch=True)
    heart.start()
    try:
        assert heart.gc in gc.callbacks
        QTimer.singleShot(0, gc.collect)                 # a full collection on the GUI thread
        qtbot.waitUntil(lambda: any(g.generation == 2 and g.on_gui_thread for g in heart.gc.log), timeout=30000)
        qtbot.waitUntil(lambda: any(t.gc_ms > 0 for t in heart.tick_log), timeout=30000)
    finally:
        heart.stop()
    assert heart.gc not in gc.callbacks                  # stop() unhooks it
    assert heart.gc.counts[2] >= 1
    full = next(g for g in heart.gc.log if g.generation == 2 and g.on_gui_thread)
    assert full.duration_ms > 0


def _use_cpu(ms: float) -> None:
    """Compute (no sleep) until this thread has used ``ms`` of CPU time."""
    end = time.thread_time() + ms / 1000.0
    x = 0
    while time.thread_time() < end:
        x += 1


def test_event_tap_names_the_event_that_used_a_ticks_cpu(qtbot):
    from PySide6.QtCore import QObject, QTimer

    owner = QObject()
    owner.setObjectName("busyOwner")
    timer = QTimer(owner)
    timer.setSingleShot(True)
    timer.timeout.connect(lambda: _use_cpu(40))
    heart = Heartbeat(interval_ms=10, warn_ms=1000, watch=True, events=True, record=True)
    heart.start()
    try:
        timer.start(0)
        qtbot.waitUntil(lambda: any("busyOwner" in t.event for t in heart.tick_log), timeout=30000)
    finally:
        heart.stop()
    tick = next(t for t in heart.tick_log if "busyOwner" in t.event)
    assert tick.event == "Qt Timer → QTimer of QObject 'busyOwner'"
    assert tick.event_cpu_ms >= 30 and tick.cpu_ms >= tick.event_cpu_ms     # CPU time: the slot's own work
    counted = dict(heart.delivered)                     # after stop(): the events by kind and receiver
    assert counted.get("Qt Timer → QTimer of QObject 'busyOwner'") == 1
    assert counted.get("Qt Timer → QTimer of Heartbeat", 0) >= 1


def _spin_past(heart: Heartbeat) -> None:
    limit = time.perf_counter() + 30.0
    while time.perf_counter() < limit and time.perf_counter() - heart._last < (heart.interval_ms + heart.warn_ms) / 1000 + 0.01:
        pass


def test_the_application_watchdog_and_its_diagnosis_mode(qtbot, monkeypatch):
    from PySide6.QtCore import QObject

    from lfstudio.gui.heartbeat import install_watchdog

    parent = QObject()
    monkeypatch.delenv("LFSTUDIO_WATCHDOG", raising=False)
    heart = install_watchdog(parent)
    try:
        assert heart.watch and not heart.events and heart.warn_ms == 50.0
        assert heart._sampler is not None and heart._timer.isActive()
    finally:
        heart.stop()
    monkeypatch.setenv("LFSTUDIO_WATCHDOG", "30")
    heart = install_watchdog(parent)
    try:
        assert heart.events and heart.warn_ms == 30.0 and heart._tap is not None
    finally:
        heart.stop()
    assert heart._sampler is None and heart._tap is None


def test_the_always_on_watchdog_loads_no_diagnostics():
    """The watchdog every window runs imports the event tap and the garbage-collection watch
    (gui/diagnostics.py) only when asked: measured in a fresh interpreter, both ways."""
    script = textwrap.dedent("""
        import sys
        from PySide6.QtCore import QObject
        from PySide6.QtWidgets import QApplication
        app = QApplication([])
        from lfstudio.gui.heartbeat import install_watchdog
        parent = QObject()
        heart = install_watchdog(parent)
        print("diagnostics" if "lfstudio.gui.diagnostics" in sys.modules else "none", heart.events)
        heart.stop()
    """)
    env = {k: v for k, v in os.environ.items() if k != "LFSTUDIO_WATCHDOG"}
    for value, expected in ((None, "none False"), ("1", "diagnostics True")):
        run_env = {**env, "QT_QPA_PLATFORM": "offscreen", **({"LFSTUDIO_WATCHDOG": value} if value else {})}
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=run_env)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip().splitlines()[-1] == expected


def test_keep_out_of_gc_freezes_what_is_alive():
    gc.unfreeze()
    records = [{"row": i, "column": i} for i in range(5000)]
    keep_out_of_gc()
    try:
        assert gc.get_freeze_count() >= len(records)
    finally:
        gc.unfreeze()


def test_opening_a_dataset_freezes_its_records(qtbot, tmp_path):
    ds = create_scan_dataset(tmp_path / "ds", ScanPlan.centered(20, 10, (4.0, 6.0), RIG), rig={"name": RIG.name},
                             camera={"name": "instant"}, lens={"name": "t"})
    gc.unfreeze()
    try:
        AppState().set_dataset(Dataset.open(ds.root))
        assert gc.get_freeze_count() >= 200          # at least one object per view record
    finally:
        gc.unfreeze()


# -- planner plots -----------------------------------------------------------------------------------
def test_sticky_range_keeps_a_range_the_data_fills_and_moves_otherwise():
    assert sticky_range(None, 1.0, 5.0) == (1.0, 5.0)
    assert sticky_range((1.0, 5.0), 1.2, 4.9) == (1.0, 5.0)            # inside, fills 92 %
    assert sticky_range((1.0, 5.0), 0.9, 4.9) == (0.9, 4.9)            # leaves it below
    assert sticky_range((1.0, 5.0), 2.0, 3.0) == (2.0, 3.0)            # fills too little of it
    lo, hi = 1.0, 1.0 + 4.0 * STICKY_FILL
    assert sticky_range((1.0, 5.0), lo, hi) == (1.0, 5.0)              # the threshold itself keeps it


def test_plan_plots_update_their_items_in_place(qtbot):
    state = AppState()
    plots = PlanPlotsPanel(state)
    qtbot.addWidget(plots)
    plots.resize(900, 450)
    plots.show()
    plan = reference_plan()
    plots.draw(plan)
    dof_items = list(plots.dof_plot.getPlotItem().items)
    disparity_items = list(plots.disparity_plot.getPlotItem().items)
    curves = dict(plots.disparity_curves)
    blur = plots.blur_curve
    blur_before = blur.getData()[1].copy()
    h_before = curves["h"].getData()[1].copy()
    x_range = plots.view_range("dof", "x")

    plots.draw(plan.replace(near_m=1.8, spacing_mm=(4.1, 6.0)))        # a keystroke's worth of change

    assert plots.dof_plot.getPlotItem().items == dof_items             # no item added or replaced
    assert plots.disparity_plot.getPlotItem().items == disparity_items
    assert plots.blur_curve is blur and plots.disparity_curves == curves
    assert not np.allclose(curves["h"].getData()[1], h_before)         # new data in the same curve
    assert plots.scene_region.getRegion()[0] == pytest.approx(1.8)
    assert plots.view_range("dof", "x") == x_range                     # small change: axes left as they are
    assert not np.array_equal(blur.getData()[1], blur_before)          # focus moved with the near distance
    for plot in (plots.dof_plot, plots.disparity_plot):
        for side in ("left", "bottom"):
            assert plot.getAxis(side).cacheMode() == QGraphicsItem.DeviceCoordinateCache

    plots.draw(plan.replace(near_m=0.4, far_m=30.0))                   # a different scene: ranges follow
    lo, hi = plots.view_range("dof", "x")
    assert lo < 0.4 and hi >= 30.0


def test_plan_plots_keep_the_note_and_title_when_nothing_changed(qtbot):
    state = AppState()
    plots = PlanPlotsPanel(state)
    qtbot.addWidget(plots)
    plan = reference_plan()
    plots.draw(plan)
    texts = []
    plots.note.setText = lambda text, _orig=plots.note.setText: (texts.append(text), _orig(text))
    plots.draw(plan)
    assert texts == []                                                 # same text: not set again
    plots.draw(plan.replace(spacing_mm=(8.0, 6.0)))
    assert len(texts) == 1 and "8 × 6 mm" in texts[0]


# -- the scan path -----------------------------------------------------------------------------------
def _dot_rgb(preview: PathPreview, row: int, column: int) -> tuple[int, int, int]:
    img = qimage_to_rgb(preview.grab().toImage())
    ox, oy, sx, sy, scale, dot = preview._geom
    x, y = int(round(ox + column * sx * scale)), int(round(oy + row * sy * scale))
    return tuple(int(v) for v in img[y, x])


def test_path_preview_draws_the_path_once_and_adds_done_dots(qtbot):
    preview = PathPreview()
    qtbot.addWidget(preview)
    preview.resize(420, 200)
    preview.show()
    qtbot.waitExposed(preview)
    plan = ScanPlan(101, 21, (4.0, 6.0))
    preview.set_plan(plan)
    grey = _dot_rgb(preview, 5, 7)              # grab() paints the widget
    assert preview.rebuilds == 1
    preview.set_done({(0, c) for c in range(101)} | {(5, 7)})        # a scan's progress: only additions
    green = _dot_rgb(preview, 5, 7)
    assert green[1] > green[0] + 60 and green != grey                  # the done dot is green now
    preview.set_done({(0, c) for c in range(101)})                     # (5, 7) no longer done
    assert _dot_rgb(preview, 5, 7) == grey
    preview.set_plan(ScanPlan(101, 21, (4.0, 6.0)))                    # the same grid again
    preview.grab()
    assert preview.rebuilds == 1                                       # the path was never drawn again
    preview.resize(500, 220)
    preview.grab()
    assert preview.rebuilds == 2                                       # a new size needs a new drawing


def test_path_preview_shows_the_order_it_is_given(qtbot):
    """Row-meander: the line joins (0, last) with (1, last); raster draws no such vertical link."""
    shots = {}
    for order in ("row-meander", "raster"):
        preview = PathPreview()
        qtbot.addWidget(preview)
        preview.resize(300, 150)
        preview.set_plan(ScanPlan(6, 3, (10.0, 10.0), order=order))
        img = qimage_to_rgb(preview.grab().toImage())
        ox, oy, sx, sy, scale, dot = preview._geom
        x = int(round(ox + 5 * sx * scale))
        y = int(round(oy + 0.5 * sy * scale))                           # between rows 0 and 1 at the last column
        shots[order] = img[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).max(axis=0)
    assert shots["row-meander"][2] > shots["raster"][2] + 60            # the blue path line is there


# -- scan events -------------------------------------------------------------------------------------
def test_a_burst_of_scan_events_reaches_every_listener_in_order_and_draws_once(qtbot, tmp_path):
    from lfstudio.gui.panels.scan import ScanPanel

    state = AppState()
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.resize(420, 800)
    panel.show()
    plan = ScanPlan(20, 5, (4.0, 6.0))
    panel.preview.set_plan(plan)
    panel.preview.grab()
    rebuilds = panel.preview.rebuilds
    batches: list[list] = []
    state.scanEvents.connect(batches.append)
    views = plan.views()
    events = []
    for v in views:
        events.append(ScanEvent(EventKind.VIEW_STARTED, row=v.row, column=v.column, index=v.index,
                                done=v.index, total=len(views)))
        events.append(ScanEvent(EventKind.VIEW_DONE, row=v.row, column=v.column, index=v.index,
                                done=v.index + 1, total=len(views)))
    for ev in events:                       # as the engine's threads push them
        panel.bridge.post(ev)
    qtbot.waitUntil(lambda: sum(len(b) for b in batches) == len(events), timeout=30000)
    received = [ev for b in batches for ev in b]
    assert received == events                                          # all of them, in order
    assert len(batches) < len(events) / 4                              # in batches, not one call each
    assert panel.preview.done == {v.cell for v in views}
    last = views[-1]
    assert f"row {last.row}, column {last.column}" in panel.current.text()
    assert panel.progress.value() == len(views)
    assert panel.preview.rebuilds == rebuilds                          # done dots added, path kept
    # the log takes a drain's lines at most every LOG_MS, all of them, in order
    qtbot.waitUntil(lambda: f"({len(views)}/{len(views)})" in panel.log_view.toPlainText(), timeout=10000)
    logged = [line for line in panel.log_view.toPlainText().splitlines() if "done (" in line]
    assert [line.split("done (")[1].split("/")[0] for line in logged] == [str(i + 1) for i in range(len(views))]


def test_state_forwards_a_single_event_as_a_list(qtbot):
    state = AppState()
    got = []
    state.scanEvents.connect(got.append)
    ev = ScanEvent(EventKind.VIEW_STARTED, row=0, column=1)
    state.scanEvent.emit(ev)
    assert got == [[ev]]


# -- the grid ----------------------------------------------------------------------------------------
def _grid_of(qtbot, root, columns: int, rows: int, scan: bool = False, size=(900, 500)):
    """A shown GridView on a new ``columns`` x ``rows`` dataset at ``root`` (captured with the instant
    devices when ``scan``); returns (state, view) once the dataset is open."""
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), RIG, settle_s=0.0)
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "instant"}, lens={"name": "t"})
    if scan:
        from lfstudio.scan.engine import ScanEngine

        rig = InstantRig(RIG)
        rig.connect()
        cam = InstantCamera(rig.true_position_mm)
        cam.connect()
        engine = ScanEngine(ds, plan, rig, cam, time_scale=0.0)
        engine.start()
        engine.wait(60)
    state = AppState()
    view = GridView(state)
    qtbot.addWidget(view)
    view.resize(*size)
    view.show()
    qtbot.waitExposed(view)
    return state, view


def test_grid_repaints_changed_cells_once_a_frame(qtbot, tmp_path):
    state, view = _grid_of(qtbot, tmp_path / "ds", 30, 10)
    state.set_dataset(Dataset.open(tmp_path / "ds"))
    canvas = view.canvas
    paints = []
    original = canvas.paintEvent
    canvas.paintEvent = lambda event: (paints.append(event.rect()), original(event))
    canvas.repaint()
    paints.clear()
    state.publish_scan_events([ScanEvent(EventKind.VIEW_FAILED, row=r, column=c, will_retry=False)
                               for r in range(3) for c in range(30)])
    qtbot.waitUntil(lambda: bool(paints), timeout=10000)
    qtbot.waitUntil(lambda: not canvas._frame_timer.isActive(), timeout=10000)
    assert (canvas.status[:3] != 0).all() and (canvas.status[3:] == 0).all()
    assert len(paints) <= 2                         # 90 changed cells: one repaint (two at a frame edge)
    r3 = canvas._cell_rect(3, 0)
    assert all(rect.top() < r3.top() for rect in paints)     # of the changed rows only


def test_scan_time_verdicts_are_painted_from_the_verdict_array(qtbot, tmp_path):
    state, view = _grid_of(qtbot, tmp_path / "ds", 8, 4)
    state.set_dataset(Dataset.open(tmp_path / "ds"))
    canvas = view.canvas
    canvas.set_zoom(80)
    entries = [{"row": 1, "column": 2, "verdict": "fail", "checks": {"sharpness": {"value": 0.2}}},
               {"row": 2, "column": 5, "verdict": "warn", "checks": {"sharpness": {"value": 0.8}}},
               {"row": 0, "column": 0, "verdict": "pass", "checks": {"sharpness": {"value": 1.0}}}]
    canvas.update_quality_many(entries)
    assert canvas.flagged() == [(1, 2), (2, 5)]
    assert canvas.overlay.verdicts[1, 2] == 2 and canvas.overlay.verdicts[2, 5] == 1 and canvas.overlay.verdicts[0, 0] == 0
    img = qimage_to_rgb(canvas.viewport().grab().toImage())

    def edge(row, column):
        rect = canvas._cell_rect(row, column)
        return tuple(int(v) for v in img[rect.center().y(), rect.left() + 1])

    fail, warn, passed = edge(1, 2), edge(2, 5), edge(0, 0)
    assert fail[0] > 200 and fail[1] < 100                             # red outline
    assert warn[0] > 200 and warn[1] > 200 and warn[2] < 100           # yellow outline
    assert passed != fail and passed != warn


def test_decoded_thumbnails_are_taken_by_the_gui_and_fill_the_mosaic(qtbot, tmp_path):
    state, view = _grid_of(qtbot, tmp_path / "ds", 6, 3, scan=True, size=(700, 400))
    taken = []
    original = view.canvas.loader.take
    view.canvas.loader.take = lambda: (lambda got: (taken.append(len(got)), got)[1])(original())
    state.set_dataset(Dataset.open(tmp_path / "ds"))
    qtbot.waitUntil(lambda: view.canvas._mosaic_has.all(), timeout=30000)
    assert sum(taken) >= 18 and (view.canvas.status == DONE).all()     # every tile, through take()

# -- opening a dataset ---------------------------------------------------------------------------------
def test_opening_a_dataset_imports_no_scipy_or_calibration_code_on_the_gui_thread(tmp_path):
    """Opening a dataset (with a calibration.json) reads it without importing the calibration
    pipeline (scipy.optimize, OpenCV features): measured in a fresh interpreter."""
    from lfstudio.dataset.atomic import atomic_write_json

    root = tmp_path / "ds"
    plan = ScanPlan.centered(6, 3, (4.0, 6.0), RIG, settle_s=0.0)
    create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "instant"}, lens={"name": "t"})
    atomic_write_json(root / "calibration.json", {
        "created": "2026-11-20T10:00:00", "rotation_deg": [0.1, -0.2, 0.05], "homography": np.eye(3).tolist(),
        "image_size_px": [640, 426], "residual_px": {"before": {"rms": 2.5}, "after": {"rms": 0.3}},
        "views_used": [[0, 0], [0, 1]], "warnings": []})
    script = textwrap.dedent("""
        import json, sys
        from PySide6.QtWidgets import QApplication
        app = QApplication([])
        from lfstudio.gui.app import create_window
        window = create_window(simulated=False)
        window.show()
        app.processEvents()
        before = set(sys.modules)
        assert window.central.open_dataset(sys.argv[1])
        app.processEvents()
        panel = window.panels["calibrationPanel"]
        print(json.dumps({"new": sorted(set(sys.modules) - before), "summary": panel.summary.text()}))
    """)
    out = subprocess.run([sys.executable, "-c", script, str(root)], capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "QT_QPA_PLATFORM": "offscreen"})
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    heavy = [m for m in result["new"] if m.split(".")[0] in ("scipy", "cv2", "rawpy")
             or m.startswith(("lfstudio.calibration.calibrate", "lfstudio.calibration.fit",
                              "lfstudio.calibration.features"))]
    assert heavy == []
    assert "Calibrated" in result["summary"]


# -- the wheel guard ---------------------------------------------------------------------------------
def test_the_wheel_guard_watches_windows_not_every_event_of_the_application(qtbot):
    """An application-wide Python event filter takes the GIL for every event of the GUI thread; the
    guard sees a window's own events (where wheel turns arrive) and nothing sent to other objects."""
    from PySide6.QtCore import QCoreApplication, QEvent, QObject
    from PySide6.QtWidgets import QApplication, QSpinBox, QVBoxLayout, QWidget

    from lfstudio.gui.widgets import WheelGuard, install_wheel_guard

    app = QApplication.instance()
    earlier = app.findChild(WheelGuard, "wheelGuard")
    if earlier is not None:
        earlier.setObjectName("earlierWheelGuard")       # so that install_wheel_guard makes a new one
    try:
        guard = install_wheel_guard(app)
        assert guard is not earlier and guard is install_wheel_guard(app)      # one guard
        form = QWidget()
        qtbot.addWidget(form)
        QVBoxLayout(form).addWidget(QSpinBox())
        form.show()
        qtbot.waitExposed(form)
        guard.watch_windows()
        form.resize(320, 200)
        qtbot.waitUntil(lambda: guard.looked_at > 0, timeout=10000)          # the window's own events
        before = guard.looked_at
        target = QObject()
        for _ in range(200):
            QCoreApplication.sendEvent(target, QEvent(QEvent.Type.User))
        assert guard.looked_at == before                 # none of them went through Python
    finally:
        if earlier is not None:
            guard.setObjectName("")
            earlier.setObjectName("wheelGuard")


# -- labels that change during a scan ----------------------------------------------------------------
class _LayoutRequests(__import__("PySide6.QtCore", fromlist=["QObject"]).QObject):
    def __init__(self):
        super().__init__()
        self.count = 0

    def eventFilter(self, obj, event):   # noqa: N802
        from PySide6.QtCore import QEvent

        if event.type() == QEvent.Type.LayoutRequest:
            self.count += 1
        return False


@pytest.mark.parametrize("kind", ["QuietLabel", "QLabel"])
def test_a_quiet_label_changes_its_text_without_a_relayout(qtbot, kind):
    """QLabel.setText re-lays out its parent (and from there the whole window); a QuietLabel does not."""
    from PySide6.QtCore import QCoreApplication
    from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

    from lfstudio.gui.widgets import QuietLabel

    panel = QWidget()
    qtbot.addWidget(panel)
    label = QuietLabel("Current view: –", name="currentView") if kind == "QuietLabel" else QLabel("Current view: –")
    QVBoxLayout(panel).addWidget(label)
    panel.show()
    qtbot.waitExposed(panel)
    QCoreApplication.sendPostedEvents()          # the layout requests of showing it are over
    QCoreApplication.processEvents()
    requests = _LayoutRequests()
    panel.installEventFilter(requests)
    for i in range(20):
        label.setText(f"Current view: row {i}, column {i * 7} — moving" + " ." * i)
    QCoreApplication.sendPostedEvents()      # deliver what setText posted (a LayoutRequest, for a QLabel)
    QCoreApplication.processEvents()
    assert label.text().startswith("Current view: row 19")
    if kind == "QuietLabel":
        assert requests.count == 0 and label.label.objectName() == "currentView"
    else:
        assert requests.count >= 1                  # what the QuietLabel avoids


def test_a_quiet_label_with_every_ms_shows_the_latest_text(qtbot):
    from lfstudio.gui.widgets import QuietLabel

    label = QuietLabel("Step times: –", every_ms=300)
    qtbot.addWidget(label)
    label.setText("Step times: move 0.10 s")          # the first is shown at once
    assert label.label.text() == "Step times: move 0.10 s"
    for i in range(2, 6):
        label.setText(f"Step times: move 0.{i}0 s")
    assert label.text() == "Step times: move 0.50 s"   # what it says (the latest) ...
    qtbot.waitUntil(lambda: label.label.text() == "Step times: move 0.50 s", timeout=5000)   # ... and shows


# -- the inbox ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("every_ms", [0, 1000])
def test_a_paced_inbox_hands_over_what_came_meanwhile_in_one_batch(qtbot, every_ms):
    """With every_ms, items posted soon after a batch wait for the next one (one call for them all);
    without, each turn of the event loop hands over what is there."""
    from PySide6.QtCore import QCoreApplication

    from lfstudio.gui.bridge import GuiInbox

    batches: list[list] = []
    inbox = GuiInbox(batches.append, every_ms=every_ms)
    inbox.post(1)
    qtbot.waitUntil(lambda: batches == [[1]], timeout=10000)
    inbox.post(2)
    QCoreApplication.processEvents()            # its wake-up is delivered
    inbox.post(3)
    QCoreApplication.processEvents()
    qtbot.waitUntil(lambda: sum(len(b) for b in batches) == 3, timeout=10000)
    assert batches[1:] == ([[2, 3]] if every_ms else [[2], [3]])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread names from /proc")
def test_the_window_scales_images_without_qts_thread_pool():
    """Qt's image scaling on its own pool makes the GUI thread wait for threads that wait for a core
    on a busy computer: the window keeps that work on the GUI thread (a fresh interpreter: Qt reads
    the setting once)."""
    script = textwrap.dedent("""
        import glob, json, os
        from PySide6.QtCore import QRectF, Qt
        from PySide6.QtGui import QImage, QPainter
        from PySide6.QtWidgets import QApplication
        app = QApplication([])
        from lfstudio.gui.app import create_window
        window = create_window(simulated=False)
        mosaic = QImage(4848, 672, QImage.Format_RGB32)
        mosaic.fill(0)
        target = QImage(1200, 800, QImage.Format_RGB32)
        p = QPainter(target)
        p.setRenderHint(QPainter.SmoothPixmapTransform, True)
        p.drawImage(QRectF(0, 0, 1200, 300), mosaic)
        p.end()
        mosaic.scaled(1200, 300, Qt.IgnoreAspectRatio, Qt.SmoothTransformation).convertToFormat(QImage.Format_RGB888)
        names = [open(f).read().strip() for f in glob.glob("/proc/self/task/*/comm")]
        print(json.dumps({"threads": names, "env": os.environ.get("QT_NO_GUI_THREADPOOL")}))
    """)
    env = {k: v for k, v in __import__("os").environ.items() if k != "QT_NO_GUI_THREADPOOL"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                         env={**env, "QT_QPA_PLATFORM": "offscreen"})
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["env"] == "1"
    assert "Thread (pooled)" not in result["threads"]
