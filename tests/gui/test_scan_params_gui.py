"""The Scan panel's editors are made from the scan options' descriptions
(lfstudio.studio.scan_options): they accept exactly what 'lfstudio scan' accepts. The window once
took 10 000 columns where the core takes 20 000, a spacing of 0 the core refuses, at most 5 000 mm
of spacing or offset, 30 s of settle and a time scale up to 10."""

from __future__ import annotations

from lfstudio.gui.panels.scan import ScanPanel
from lfstudio.gui.state import AppState
from lfstudio.studio.scan_options import PARAMS


def test_every_scan_editor_accepts_exactly_what_the_command_line_does(qtbot):
    panel = ScanPanel(AppState(simulated=True))
    qtbot.addWidget(panel)
    spins = {"grid_columns": [panel.columns], "grid_rows": [panel.rows], "spacing_mm": [panel.spacing_h, panel.spacing_v],
             "offset_mm": [panel.offset_h, panel.offset_v], "settle_s": [panel.settle], "time_scale": [panel.time_scale]}
    for name, boxes in spins.items():
        number = PARAMS[name].number
        for box in boxes:
            assert number.problem(box.minimum()) is None and number.problem(box.maximum()) is None, name
            assert box.maximum() == number.high, name
            assert box.minimum() == number.low or number.low_open, name
            assert number.problem(box.value()) is None, name
            assert f"valid: {number.valid()}" in box.toolTip(), name
    assert [panel.order.itemText(i) for i in range(panel.order.count())] == list(PARAMS["order"].choices)
    assert panel.columns.maximum() == 20_000 and panel.spacing_h.minimum() == 0.001
    assert PARAMS["bracket"].tip[1:] in panel.bracket.toolTip()


def test_the_unattended_settings_take_their_ranges_from_the_scan_options(qtbot):
    from lfstudio.gui.unattended import UnattendedBox

    box = UnattendedBox()
    qtbot.addWidget(box)
    for spin, name in ((box.auto_resume, "auto_resume"), (box.timeout, "on_finish_timeout_s")):
        number = PARAMS[name].number
        assert (spin.minimum(), spin.maximum()) == (number.low, number.high), name
