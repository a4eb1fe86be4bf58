"""HDR in the window and pictures that fit (issue 41, item 11): the Process dialog says what a bracketed
scan's merge will do and how far it got, the merged radiance is seen under an exposure slider, and the
Depth dialog shows its map whole (Fit) with its colour bar, or 1:1. Real datasets, real Qt loop, at
1366 x 768 and 1920 x 1080."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.process_dialog import ProcessDialog
from lfstudio.gui.imageutil import qimage_to_rgb
from lfstudio.gui.views.radiance import RadianceDialog

SCREENS = [(1366, 768), (1920, 1080)]


def _window(qtbot, size, ds):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.resize(size[0], size[1] - 40)
    window.show()
    window.state.set_dataset(ds)
    return window


def _actions(window):
    return {a.text().replace("&", ""): a for a in window.menu("Dataset").actions()}


def _brightness(view) -> float:
    return float(qimage_to_rgb(view.pixmap().toImage()).mean())


@pytest.mark.parametrize("size", SCREENS)
def test_a_bracketed_scan_s_process_dialog_tells_the_merge_and_shows_the_radiance(qtbot, tmp_path, bracketed, size):
    import shutil

    ds, _studio = bracketed
    root = tmp_path / "ds"
    shutil.copytree(ds.root, root)
    window = _window(qtbot, size, Dataset.open(root))
    assert not _actions(window)["HDR radiance of a view…"].isEnabled()       # nothing merged yet
    _actions(window)["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    assert dialog is not None and dialog.hdr_box is not None and dialog.hdr_box.isVisibleTo(dialog)
    hint = dialog.hdr_label.text()
    assert "3 frames" in hint and "-2, 0, +2 EV" in hint and "hdr/rRR_cCCC.exr" in hint and "No view merged" in hint
    assert not dialog.radiance_button.isEnabled()
    for step in ("color", "deflicker", "shading", "rectify", "resample"):
        dialog.editors[step].setChecked(False)
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.process_button.click()
    assert "Merged so far: 2 of 2 views" in dialog.hdr_label.text() and dialog.radiance_button.isEnabled()
    dialog.grab().save(str(tmp_path / f"process-hdr-{size[0]}.png"))

    dialog.radiance_button.click()
    radiance = dialog.radiance_dialog
    assert isinstance(radiance, RadianceDialog) and radiance.isVisible()
    qtbot.waitUntil(lambda: radiance.pictures_shown >= 1, timeout=30000)
    assert "hdr/r00_c00" in radiance.caption.text() and "linear float" in radiance.caption.text()
    at_zero = _brightness(radiance.image)
    radiance.slider.setValue(radiance.slider.value() + 20)                   # +2 EV
    qtbot.waitUntil(lambda: abs(radiance.ev - 2.0) < 1e-9 and "+2.0 EV" in radiance.caption.text(), timeout=5000)
    brighter = _brightness(radiance.image)
    radiance.slider.setValue(-30)                                            # -3 EV
    qtbot.waitUntil(lambda: "-3.0 EV" in radiance.caption.text(), timeout=5000)
    darker = _brightness(radiance.image)
    assert darker < at_zero < brighter, (darker, at_zero, brighter)
    shown, room = radiance.image.shown_size(), radiance.image.viewport().size()
    assert shown.width() <= room.width() and shown.height() <= room.height()
    radiance.grab().save(str(tmp_path / f"radiance-{size[0]}.png"))
    assert _actions(window)["HDR radiance of a view…"].isEnabled()


def test_no_hdr_section_without_a_bracket(qtbot, make_dataset):
    ds = make_dataset()
    window = _window(qtbot, (1366, 768), Dataset.open(ds.root if hasattr(ds, "root") else ds))
    _actions(window)["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    assert dialog is not None and dialog.hdr_box is None
    assert not _actions(window)["HDR radiance of a view…"].isEnabled()


@pytest.mark.parametrize("size", SCREENS)
def test_the_depth_map_fits_with_its_colour_bar_or_shows_1_to_1(qtbot, tmp_path, tiny_dataset, size):
    """The Depth dialog showed the map 1:1 with scroll bars: the colour bar under it out of sight."""
    from lfstudio.depth.run import estimate_depth
    from lfstudio.gui.views.depth import DepthDialog

    estimate_depth(tiny_dataset, [(1, 2)])
    window = _window(qtbot, size, tiny_dataset)
    next(a for a in window.menu("Dataset").actions() if a.objectName() == "actionDepthMap").trigger()
    dialog = window.findChild(DepthDialog, "depthDialog")
    assert dialog is not None
    dialog.resize(560, 420)                      # smaller than the picture (640 px wide with its bar)
    qtbot.waitUntil(lambda: dialog.pictures_shown >= 1, timeout=30000)
    view = dialog.image
    full = view.pixmap().size()
    caption = dialog.caption.text()             # the disparity's reference and statistic named (item 10)
    assert "between horizontal neighbours, from infinity" in caption and "1st–99th percentile" in caption, caption
    assert dialog.fit_button.isChecked()
    qtbot.waitUntil(lambda: view.shown_size().width() < full.width(), timeout=5000)
    shown, room = view.shown_size(), view.viewport().size()
    assert shown.width() <= room.width() and shown.height() <= room.height()        # the whole map and its bar
    assert abs(shown.width() / shown.height() - full.width() / full.height()) < 0.02
    dialog.grab().save(str(tmp_path / f"depth-fit-{size[0]}.png"))
    dialog.fit_button.click()                                                   # 1:1
    assert view.shown_size() == full and view.verticalScrollBar().maximum() > 0
    bar = dialog.colour_bar                          # the key at screen resolution, under the map in both modes
    assert bar.isVisible() and len(bar.labels()) == 5 and " px" in bar.labels()[0]
    assert bar.mapTo(dialog, bar.rect().bottomLeft()).y() <= dialog.height()
    bar_picture = qimage_to_rgb(bar.grab().toImage())
    assert np.ptp(bar_picture[:, :, 0]) > 100                                   # its colours are drawn
