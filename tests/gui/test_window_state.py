"""State the operator can see (real Qt loop): the Rig menu's scan items only when they can act;
opening a dataset says what it does to the Scan panel (its grid shown, the operator's own order kept
as their default after a restart) and replaces the previous scan's "Finished…" line; the
Calibration panel tells notes from warnings and shows a readable time; counts in words ("1 view")."""

from __future__ import annotations

from lfstudio.gui.app import create_window
from lfstudio.gui.settings import settings
from lfstudio.gui.widgets import readable_time
from lfstudio.jobs import count


def test_counts_and_times_in_words():
    assert count(1, "view") == "1 view" and count(0, "view") == "0 views" and count(27, "view") == "27 views"
    assert count(2, "match", "matches") == "2 matches"
    shown = readable_time("2026-11-27T12:48:04.123Z")
    assert "2026" in shown and "Nov" in shown and "T" not in shown and ".123" not in shown
    assert readable_time(None) == "" and readable_time("not a time") == "not a time"


def test_rig_menu_scan_items_only_when_they_can_act(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    scan = window.panels["scanPanel"]
    assert scan.action_start in window.menu("Rig").actions()
    assert scan.action_start.isEnabled()
    assert not scan.action_pause.isEnabled() and not scan.action_resume.isEnabled() \
        and not scan.action_abort.isEnabled()


def test_opening_a_dataset_says_what_it_does_to_the_scan_panel(qtbot, tiny_dataset):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    scan = window.panels["scanPanel"]
    assert tiny_dataset.grid.order != "raster"
    index = scan.order.findText("raster")
    scan.order.setCurrentIndex(index)
    scan.order.activated.emit(index)                      # the operator's choice
    scan.state_label.setText("<b>Finished</b> 27 of 27 views captured.")    # the previous scan's line
    window.state.set_dataset(tiny_dataset)
    assert scan.order.currentText() == tiny_dataset.grid.order
    qtbot.waitUntil(lambda: f"shows {tiny_dataset.root.name}'s grid" in scan.log_view.toPlainText(), timeout=5000)
    assert "raster" in scan.log_view.toPlainText()         # what it was
    assert "Finished" not in scan.state_label.text() and "15 of 15 views captured" in scan.state_label.text()
    scan._save_settings()                                  # what Start (resuming this dataset) saves
    window.close()
    assert settings().value("scan/order") == "raster"
    again = create_window(simulated=True)
    qtbot.addWidget(again)
    assert again.panels["scanPanel"].order.currentText() == "raster"
    again.close()


def test_calibration_panel_notes_are_not_warnings(qtbot, tiny_dataset):
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import save_calibration

    doc = calibrate_dataset(tiny_dataset, "array:3x1").document    # one row: tilt held (a note)
    save_calibration(tiny_dataset, doc)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(tiny_dataset)
    text = window.panels["calibrationPanel"].summary.text()
    held = [h["reason"] for h in (doc.get("observability") or {}).get("held") or []]
    assert held and set(held) <= set(doc["warnings"])
    others = [w for w in doc["warnings"] if w not in held]
    assert "warning(s)" not in text and "1 views" not in text
    assert count(len(held), "note") in text
    assert (count(len(others), "warning") in text) == bool(others)
    assert doc["created"] not in text and readable_time(doc["created"]) in text
    window.close()


def test_calibration_panel_says_whether_the_views_are_rotated(qtbot, tiny_dataset):
    """Issue 37: the window says what processing will do with the fitted rotation (applied, or not
    significant and the views left unrotated), as the CLI report does."""
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import rectification_decision, save_calibration

    doc = calibrate_dataset(tiny_dataset, "array:3x2").document
    save_calibration(tiny_dataset, doc)
    decided = rectification_decision(doc)
    assert decided and ("views left unrotated" in decided or "views rectified by it" in decided)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(tiny_dataset)
    summary = window.panels["calibrationPanel"].summary
    text = summary.text()
    if "views left unrotated" in decided:
        assert "Views left unrotated: the rotation is not significant" in text
    else:
        assert "Views rectified: the rotation is significant" in text
    assert f"Rectification: {decided}" in summary.toolTip()
    window.close()
