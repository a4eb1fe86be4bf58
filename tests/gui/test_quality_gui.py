"""The grid view's quality tools on a real Qt event loop: the check as a job (progress, Cancel),
verdict outlines and heat maps, a flagged view beside its neighbours, re-capture of the flagged
views, the disparity map, and the scan-time check fed by scan events."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from PySide6.QtCore import Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.state import AppState
from lfstudio.gui.views.grid_view import GridView
from lfstudio.gui.views.quality import DisparityDialog, NeighboursDialog
from lfstudio.sim.studio import ViewFault

FAULTS = [ViewFault("blur", 1, 1, blur_px=6.0), ViewFault("displaced", 2, 3, offset_mm=(1.0, 0.0))]


@pytest.fixture(scope="module")
def _faulty(tmp_path_factory):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    root = tmp_path_factory.mktemp("quality_gui") / "faulty"
    make_virtual_dataset(root, 5, 4, width_px=480, fmt="png", rotation_deg=(1.0, -1.5, 0.7), seed=7, faults=FAULTS)
    return root


@pytest.fixture
def faulty(_faulty, tmp_path):
    dst = tmp_path / "faulty"
    shutil.copytree(_faulty, dst)
    return dst


def grid(qtbot, size=(1000, 640)):
    state = AppState()
    view = GridView(state)
    qtbot.addWidget(view)
    view.resize(*size)
    view.show()
    return state, view


def run_check(qtbot, view):
    bar = view.quality_bar
    with qtbot.waitSignal(bar.runner.finished, timeout=120000):
        qtbot.mouseClick(bar.check_button, Qt.LeftButton)
        assert bar.progress.isVisible() and bar.progress.cancel_button.isEnabled()   # off the GUI thread


def test_check_dataset_flags_the_faulty_views_and_paints_heat_maps(qtbot, faulty):
    state, view = grid(qtbot)
    state.set_dataset(Dataset.open(faulty))
    canvas = view.canvas
    assert canvas.quality == {} and not view.quality_bar.disparity_button.isEnabled()
    run_check(qtbot, view)
    assert canvas.flagged() == [(1, 1), (2, 3)]
    assert (faulty / "quality.json").is_file()
    assert "2 fail" in view.quality_bar.summary.text()
    assert view.quality_bar.disparity_button.isEnabled()
    qtbot.waitUntil(lambda: canvas._mosaic_has.sum() == 20, timeout=20000)
    plain = canvas.viewport().grab().toImage()
    view.quality_bar.overlay.setCurrentIndex(view.quality_bar.overlay.findData("sharpness"))
    assert canvas.overlay_key == "sharpness" and canvas.overlay.heat is not None
    # the blurred view is drawn in another colour than its sharp neighbours
    blurred, sharp = canvas.overlay.heat[1, 1, :3].astype(int), canvas.overlay.heat[1, 2, :3].astype(int)
    assert np.abs(blurred - sharp).sum() > 100
    shaded = canvas.viewport().grab().toImage()
    centre = canvas._cell_rect(1, 2).center()
    assert plain.pixelColor(centre) != shaded.pixelColor(centre)
    shaded.save(str(faulty.parent / "quality-grid.png"))
    # a flagged view is outlined in the fail colour
    rect = canvas._cell_rect(2, 3)
    edge = shaded.pixelColor(rect.left() + 2, rect.center().y())
    assert edge.red() > 180 and edge.green() < 110
    # reopening the dataset shows the saved verdicts again
    state.set_dataset(Dataset.open(faulty))
    assert canvas.flagged() == [(1, 1), (2, 3)]


def test_the_check_can_be_cancelled(qtbot, faulty):
    state, view = grid(qtbot)
    state.set_dataset(Dataset.open(faulty))
    bar = view.quality_bar
    with qtbot.waitSignal(bar.runner.cancelled, timeout=60000):
        qtbot.mouseClick(bar.check_button, Qt.LeftButton)
        qtbot.mouseClick(bar.progress.cancel_button, Qt.LeftButton)
    assert not (faulty / "quality.json").exists()
    assert view.canvas.quality == {}
    qtbot.waitUntil(lambda: bar.check_button.isEnabled(), timeout=5000)


def test_clicking_a_flagged_view_shows_it_beside_its_neighbours(qtbot, faulty):
    state, view = grid(qtbot)
    state.set_dataset(Dataset.open(faulty))
    run_check(qtbot, view)
    canvas = view.canvas
    qtbot.mouseClick(canvas.viewport(), Qt.LeftButton, pos=canvas._cell_rect(2, 2).center())
    assert view._neighbours is None                       # a view that passed: just selected
    qtbot.mouseClick(canvas.viewport(), Qt.LeftButton, pos=canvas._cell_rect(1, 1).center())
    dialog = view._neighbours
    assert isinstance(dialog, NeighboursDialog) and dialog.isVisible() and dialog.cell == (1, 1)
    assert "FAIL" in dialog.reasons.text() and "sharpness" in dialog.reasons.text()
    qtbot.waitUntil(lambda: all(not t.pixmap().isNull() for t in dialog.tiles.values()), timeout=20000)
    dialog.grab().save(str(faulty.parent / "quality-neighbours.png"))
    with qtbot.waitSignal(state.recaptureRequested, timeout=2000) as sig:
        qtbot.mouseClick(dialog.recapture_button, Qt.LeftButton)
    assert sig.args[0] == [(1, 1)]


def test_select_flagged_then_recapture_them(qtbot, faulty):
    state, view = grid(qtbot)
    state.set_dataset(Dataset.open(faulty))
    run_check(qtbot, view)
    qtbot.mouseClick(view.quality_bar.select_button, Qt.LeftButton)
    assert view.canvas.selected == {(1, 1), (2, 3)}
    assert view.recapture_button.text() == "Re-capture 2 selected"
    with qtbot.waitSignal(state.recaptureRequested, timeout=2000) as sig:
        qtbot.mouseClick(view.recapture_button, Qt.LeftButton)
    assert sig.args[0] == [(1, 1), (2, 3)]


def test_the_disparity_map_opens_in_false_colour(qtbot, faulty):
    state, view = grid(qtbot)
    state.set_dataset(Dataset.open(faulty))
    run_check(qtbot, view)
    qtbot.mouseClick(view.quality_bar.disparity_button, Qt.LeftButton)
    dialog = view._disparity_dialog
    assert isinstance(dialog, DisparityDialog) and dialog.isVisible()
    pix = dialog.image.pixmap()
    assert not pix.isNull() and pix.width() == 480
    img = pix.toImage()
    colours = {img.pixelColor(x, y).name() for x in range(0, 480, 24) for y in range(0, 300, 20)}
    assert len(colours) > 20                       # false colour, not a grey picture


def test_views_are_checked_as_scan_events_arrive(qtbot, faulty):
    """The grid view forwards each ``view-done`` event to the scan-time checker; verdicts come back
    on the GUI thread and outline the failing view at once."""
    from lfstudio.scan.events import EventKind, ScanEvent

    state, view = grid(qtbot)
    published = []
    state.liveVerdicts.connect(published.extend)            # for notifications and the status page
    ds = Dataset.open(faulty)
    state.set_dataset(ds)
    assert view.quality_bar.live_box.isChecked()
    order = [(r, c) for r in range(4) for c in (range(5) if r % 2 == 0 else range(4, -1, -1))]
    for r, c in order[:8]:                                  # up to (1, 2): the blurred (1, 1) comes next
        state.scanEvent.emit(ScanEvent(EventKind.VIEW_DONE, row=r, column=c, file=ds.view(r, c)["file"]))
    qtbot.waitUntil(lambda: len(view.canvas.quality) == 8, timeout=60000)
    assert view.canvas.flagged() == []
    state.scanEvent.emit(ScanEvent(EventKind.VIEW_DONE, row=1, column=1, file=ds.view(1, 1)["file"]))
    qtbot.waitUntil(lambda: (1, 1) in view.canvas.quality, timeout=60000)
    assert view.canvas.quality[(1, 1)]["verdict"] == "fail"
    assert view.canvas.flagged() == [(1, 1)]
    assert [e["verdict"] for e in published if (e["row"], e["column"]) == (1, 1)][-1] == "fail"
    assert "checked during the scan" in view.quality_bar.summary.text()
    view.quality_bar.live_box.setChecked(False)             # switched off: no more checks
    state.scanEvent.emit(ScanEvent(EventKind.VIEW_DONE, row=1, column=0, file=ds.view(1, 0)["file"]))
    assert view.live.checker.wait_idle(30)
    assert (1, 0) not in view.canvas.quality
