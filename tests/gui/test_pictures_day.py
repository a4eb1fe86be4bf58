"""Pictures that read (issue 20): the calibration wizard's histogram axes in px, residuals binned per
image region at real match counts, the report's warnings wrapped; the grid's title keeps the
dataset's name. Real Qt event loop, real calibration of a virtual-studio dataset."""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QFont, QFontMetrics
from PySide6.QtWidgets import QPlainTextEdit

from lfstudio.gui.dialogs.calibration_wizard import CalibrationWizard, residual_field
from lfstudio.gui.state import AppState


def test_residual_field_bins_matches_per_region():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 1, (20000, 2)) * (1200, 800)
    vertical = rng.uniform(size=20000) < 0.6                    # row pairs measure vertical residuals
    right = pts[:, 0] > 600
    res = np.where(vertical, np.where(right, 0.3, -0.1), 0.2) + rng.normal(0, 0.01, 20000)
    field = residual_field(pts, res, vertical, (1200, 800), cells=(4, 2))
    assert field["rms"].shape == (2, 4) and np.isfinite(field["rms"]).all()
    assert field["count"].sum() == 20000
    assert len(field["centres"]) == 8
    left = field["centres"][:, 0] < 600
    assert np.allclose(field["mean"][left], (0.2, -0.1), atol=0.01)
    assert np.allclose(field["mean"][~left], (0.2, 0.3), atol=0.01)
    sparse = residual_field(pts[:5], res[:5], vertical[:5], (1200, 800), cells=(4, 2), min_count=3)
    assert np.isnan(sparse["rms"]).sum() >= 6                      # too few matches: no value, no arrow


def test_calibration_wizard_pictures_read(qtbot, tiny_dataset):
    state = AppState()
    state.set_dataset(tiny_dataset)
    wizard = CalibrationWizard(state)
    qtbot.addWidget(wizard)
    wizard.resize(900, 760)
    wizard.show()
    with qtbot.waitSignal(wizard.runner.finished, timeout=120_000):
        wizard.next_button.click()
    fit = wizard.result["run"].fit
    matches = int(fit.inlier.sum())
    assert matches > 2000                                            # a real match count

    wizard.tabs.setCurrentIndex(1)                                   # Residuals
    for plot in (wizard.hist_before, wizard.hist_after):            # numbers in px, as they are
        axis = plot.getAxis("bottom")
        qtbot.waitUntil(lambda: -5 < plot.getViewBox().viewRange()[0][0] < -0.05, timeout=10000)
        low, high = axis.range                                       # the axis has the residuals' range now
        assert 0.05 < high < 5 and -5 < low < -0.05
        label = axis.labelString()
        assert "(px)" in label and "(x0.001)" not in label and "[px]" not in label
        assert axis.autoSIPrefixScale == 1.0                         # ticks read -0.4 … 0.4, not -400 … 400

    rows, cols = wizard.field["rms"].shape
    arrows = len(wizard.vector_lines.xData) // 2
    assert 0 < arrows <= rows * cols < matches / 20                 # one arrow per region, not per match
    assert wizard.region_rms.image.shape == (rows, cols)
    # both colour scales drawn as bars beside their plots, spanning what the colours mean
    rms = wizard.field["rms"]
    assert wizard.region_bar.levels() == (0.0, float(np.nanmax(rms)))
    assert tuple(wizard.region_rms.getLevels()) == wizard.region_bar.levels()
    per_view = [v["residual_px"]["after"]["rms"] for v in wizard.result["run"].document["views"]
                if v["residual_px"]["after"]["rms"] is not None]
    assert wizard.heat_bar.levels() == (0.0, max(max(per_view), 1.0))
    for plot, bar in ((wizard.heat, wizard.heat_bar), (wizard.vectors, wizard.region_bar)):
        assert bar.isVisible() and bar.parentItem() is plot and "(px)" in bar.getAxis("left").labelText
        assert bar.sceneBoundingRect().left() >= plot.getViewBox().sceneBoundingRect().right()
    lengths = np.hypot(*(wizard.field["mean"] * wizard.vector_gain.value()).T)
    region = min(wizard.result["preview"].shape[1] / cols, wizard.result["preview"].shape[0] / rows)
    assert 0.5 * region < lengths.max() <= region                    # the longest arrow fills its region
    seen = wizard.res_plots.viewport().width()                      # nothing cut off at the right edge
    for item in (wizard.hist_after, wizard.vectors, wizard.region_bar, wizard.heat_bar):
        assert item.sceneBoundingRect().right() <= seen, (item, item.sceneBoundingRect(), seen)
    wizard.vector_mode.setCurrentIndex(1)                            # before calibration: redrawn, same bins
    assert len(wizard.vector_lines.xData) // 2 <= rows * cols

    report = wizard.report_text
    assert report.lineWrapMode() == QPlainTextEdit.WidgetWidth
    wizard.tabs.setCurrentIndex(0)
    qtbot.waitUntil(report.isVisible, timeout=5000)
    assert report.horizontalScrollBar().maximum() == 0                # no line runs off the right edge
    assert all(w[:40] in report.toPlainText().replace("\n", " ") for w in wizard.result["run"].document["warnings"])
    wizard.close()


def test_grid_title_keeps_the_dataset_name(qtbot, tmp_path):
    from lfstudio.dataset import Dataset
    from lfstudio.gui.views.grid_view import GridView
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    make_virtual_dataset(tmp_path / "studio_day_close_up", columns=5, rows=3, spacing_mm=(4.0, 6.0), width_px=64)
    state = AppState()
    view = GridView(state)
    qtbot.addWidget(view)
    state.set_dataset(Dataset.open(tmp_path / "studio_day_close_up"))
    bold = QFont(view.title.font())
    bold.setBold(True)
    name_px = QFontMetrics(bold).horizontalAdvance("studio_day_close_up")
    for width in (560, 760, 1100):                                   # a central view between two docks
        view.resize(width, 300)
        view.show()
        qtbot.waitUntil(lambda: view.width() == width and view.title.width() >= name_px, timeout=5000)
        assert "<b>studio_day_close_up</b>" in view.title.text() and "5 × 3 views" in view.title.text()
    long_name = "studio_day_close_up_second_session_with_the_new_lens"
    make_virtual_dataset(tmp_path / long_name, columns=5, rows=3, spacing_mm=(4.0, 6.0), width_px=64)
    state.set_dataset(Dataset.open(tmp_path / long_name))              # longer than its share: elided
    view.resize(760, 300)
    qtbot.waitUntil(lambda: view.width() == 760 and "…" in view.title.text(), timeout=5000)
    assert view.title.toolTip().endswith(long_name) and "5 × 3 views" in view.title.text()
    assert view.title.width() > 0.3 * 760        # it keeps its share of the view, the name elided in it
