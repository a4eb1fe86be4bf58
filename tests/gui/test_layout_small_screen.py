"""What was cut or overlapping at 1366 x 768 (issue 41, item 8), on both screens operators have: the
scan summary under "Take grid from the plan" and the "Paused" state line whole (or ending in "…",
whole in its tooltip), the scan log more than four lines high, the central grid not squeezed by
the plan plots, the plan plots never scrolled sideways and their labels clear of each other.
Real window, real Qt loop; screenshots are saved in tmp_path."""

from __future__ import annotations

import pytest
from PySide6.QtCore import QRectF

from tests.gui.test_window_layout import _window

SCREENS = [(1366, 768), (1920, 1080)]
PAUSED = ("Paused: the camera failed 3 time(s) at view r02 c004: shutter_s: 256.0 s is out of range (valid: "
          "0.0001 .. 60 s). Fix the Bracket field, then Resume; or Skip view, or Abort (everything captured is "
          "kept). The camera said: the requested shutter speed is not offered in this mode.")


def _scan(window):
    window.docks["scanPanel"].raise_()
    return window.panels["scanPanel"]


@pytest.mark.parametrize("size", SCREENS)
def test_scan_panel_summary_state_and_log_are_whole(qtbot, tmp_path, size):
    window = _window(qtbot, (size[0], size[1] - 40))
    scan = _scan(window)
    scan.bracket.setText("-2,0,+2")
    summary = scan.summary
    qtbot.waitUntil(lambda: "3 frames" in summary.text(), timeout=5000)
    qtbot.waitUntil(lambda: summary.height() >= summary.heightForWidth(summary.width()), timeout=5000)

    state = scan.state_label
    state.setText(PAUSED)
    shown = state.shown_text()
    assert shown == PAUSED or (shown.endswith("…") and state.label.toolTip() == PAUSED), shown
    metrics = state.label.fontMetrics()
    flags = 0x1000 | 0x1   # Qt.TextWordWrap | Qt.AlignLeft
    need = metrics.boundingRect(0, 0, state.label.width() - 2, 10_000, flags, shown).height()
    assert need <= state.label.height(), (need, state.label.height())        # no line cut through

    lines = scan.log_view.height() / scan.log_view.fontMetrics().lineSpacing()
    assert lines >= 7.5, lines
    window.grab().save(str(tmp_path / f"window-{size[0]}.png"))


@pytest.mark.parametrize("size", SCREENS)
def test_the_central_grid_is_not_squeezed_by_the_plan_plots(qtbot, tmp_path, size, tiny_dataset):
    window = _window(qtbot, (size[0], size[1] - 40))
    window.state.set_dataset(tiny_dataset)
    plots = window.docks["planPlotsDock"]
    column = window.central.height() + plots.height()
    assert window.central.height() >= 0.45 * column, (window.central.height(), plots.height())
    panel = window.panels["planPlotsDock"]
    area = plots.widget()
    assert panel.width() <= area.viewport().width() + 1          # never scrolled sideways
    window.grab().save(str(tmp_path / f"central-{size[0]}.png"))


@pytest.mark.parametrize("size", SCREENS)
def test_disparity_plot_labels_stay_clear_of_each_other_and_the_axes(qtbot, size):
    """'0.5 px' was cut by the axis and '1 px' sat on 'Z min 1.77 m'."""
    window = _window(qtbot, (size[0], size[1] - 40))
    panel = window.panels["planPlotsDock"]
    qtbot.waitUntil(lambda: panel.zmin_line.isVisible(), timeout=5000)
    view = panel.disparity_plot.getPlotItem().getViewBox()
    box = view.sceneBoundingRect()

    def rect(line):
        label = line.label
        return label.mapRectToScene(label.boundingRect())

    labelled = [line for line in panel.pixel_lines.values() if getattr(line, "label", None) is not None
                and line.label.isVisible() and line.label.toPlainText()]
    assert labelled and all("0.5 px" in line.label.toPlainText() or "1 px" in line.label.toPlainText()
                            for line in labelled)
    zmin = rect(panel.zmin_line)
    for line in labelled:
        r = rect(line)
        assert box.contains(r), (r, box)                      # not cut by the plot's edge or axis
        assert not r.intersects(zmin), (r, zmin)
    assert isinstance(box, QRectF)
