"""No dead ends (simulated studio on a real pty, real Qt loop): resuming a scan whose rig was moved
away offers to drive it back to the last view (the move shown by the rig badge, STOP available) and
then continues; re-capturing views of a finished dataset after homing goes ahead (before, both were
refused with "home the rig", and refused again after homing, since home is not where the last view
was taken)."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from lfstudio.dataset import Dataset
from tests.gui.test_interlock_gui import RIGS, homed_simulated_studio
from tests.gui.test_messages_day import set_up_scan

T = 60000


def _move_rig(qtbot, rig, x, y):
    rig.goto_x.setValue(x)
    rig.goto_y.setValue(y)
    rig.go_to()
    qtbot.waitUntil(lambda: rig.last_status is not None and rig.last_status.state.value == "idle"
                    and abs(rig.last_status.position_mm[0] - x) < 0.01
                    and abs(rig.last_status.position_mm[1] - y) < 0.01, timeout=T)


@pytest.mark.parametrize("rig_word", list(RIGS))
def test_resume_offers_to_move_the_rig_back_and_recapture_goes_ahead(qtbot, tmp_path, rig_word):
    window, rig, camera, scan = homed_simulated_studio(qtbot, rig_word)
    folder = tmp_path / "moved"
    set_up_scan(scan, 6, 2, folder)
    scan.time_scale.setValue(0.05)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.dataset.status_counts()["done"] >= 2,
                    timeout=T)
    qtbot.mouseClick(scan.abort_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: not scan.running and "Aborted" in scan.state_label.text(), timeout=T)
    assert "Aborted</b>" in scan.state_label.text() and "Aborted:" not in scan.state_label.text()  # one state word
    done = Dataset.open(folder).status_counts()["done"]
    assert 2 <= done < 12
    scan.time_scale.setValue(0.0)
    _move_rig(qtbot, rig, 100.0, 50.0)                     # someone jogged the rig away
    words = []
    window.rig_badge.wordChanged.connect(words.append)
    qtbot.mouseClick(scan.resume_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: getattr(scan, "move_back_box", None) is not None and scan.move_back_box.isVisible(),
                    timeout=T)
    box = scan.move_back_box
    assert "Rig → Home" in box.text() and "lfstudio" not in box.text()   # the window's words, no CLI
    qtbot.mouseClick(box.button(QMessageBox.Yes), Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text(), timeout=T)
    assert "moving" in words
    assert "Finished</b> 12 of 12" in scan.state_label.text()              # not "Finished Finished: 12 of 12"
    assert "finished: Finished" not in scan.log_view.toPlainText()            # nor in the log
    assert Dataset.open(folder).status_counts()["done"] == 12

    rig.home()                                               # home is not where the last view was taken
    qtbot.waitUntil(lambda: rig.last_status.homed and rig.last_status.state.value == "idle"
                    and window.rig_badge.word == "homed", timeout=T)
    boxes_before = {id(b) for b in window.findChildren(QMessageBox) if b.isVisible()}
    states = []
    window.state.scanStateChanged.connect(lambda st: states.append(st.value))
    scan.recapture([(0, 1), (1, 3)])
    qtbot.waitUntil(lambda: states[-2:] == ["running", "finished"] and not scan.running, timeout=T)
    assert "re-capturing 2 view" in scan.log_view.toPlainText()
    refused = [b.text() for b in window.findChildren(QMessageBox) if b.isVisible() and id(b) not in boxes_before]
    assert not refused, refused
    ds = Dataset.open(folder)
    assert ds.status_counts()["done"] == 12
    window.close()


def test_a_resume_where_another_datasets_scan_left_the_rig_asks_the_operator(qtbot, tmp_path):
    """The rig standing where this dataset's last view was taken let the resume continue silently even
    when another dataset had been scanned since (it might have been homed again or given another origin
    in between): the window now asks, and continues only when the operator says so."""
    window, rig, camera, scan = homed_simulated_studio(qtbot)
    mine = tmp_path / "mine"
    set_up_scan(scan, 4, 2, mine)
    scan.time_scale.setValue(0.05)
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: scan.engine is not None and scan.engine.dataset.status_counts()["done"] >= 2,
                    timeout=T)
    qtbot.mouseClick(scan.abort_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: not scan.running and "Aborted" in scan.state_label.text(), timeout=T)
    ds = Dataset.open(mine)
    done = ds.status_counts()["done"]
    last = max(ds.done_views(), key=lambda v: v["captured_at"])["reported_mm"]
    ds.close()
    scan.time_scale.setValue(0.0)
    set_up_scan(scan, 2, 1, tmp_path / "other")                 # another dataset, scanned to its end
    qtbot.mouseClick(scan.start_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text() and not scan.running, timeout=T)
    _move_rig(qtbot, rig, *last)                                # and the rig back where mine stopped
    set_up_scan(scan, 4, 2, mine)
    scan.start()
    qtbot.waitUntil(lambda: getattr(scan, "used_since_box", None) is not None and scan.used_since_box.isVisible(),
                    timeout=T)
    box = scan.used_since_box
    assert "other" in box.text() and "lfstudio" not in box.text() and "--" not in box.text()   # the window's words
    assert Dataset.open(mine).status_counts()["done"] == done    # nothing ran before the answer
    qtbot.mouseClick(box.button(QMessageBox.Yes), Qt.LeftButton)
    qtbot.waitUntil(lambda: "Finished" in scan.state_label.text() and not scan.running, timeout=T)
    assert Dataset.open(mine).status_counts()["done"] == 8
    assert "kept its reference" in scan.log_view.toPlainText()
    window.close()
