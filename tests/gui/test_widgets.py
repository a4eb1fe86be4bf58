"""Shared widgets on a real event loop: the job progress line (ETA, end states)."""

from __future__ import annotations

import re

from PySide6.QtCore import Qt

from lfstudio.gui.bridge import JobRunner
from lfstudio.gui.widgets import JobProgressWidget
from lfstudio.jobs import Cancelled


def _wait_for_cancel(*, progress, cancel):
    """A job that reports nothing and runs until cancelled (a slow item, as seen from the GUI)."""
    while not cancel.wait(60):
        pass
    raise Cancelled()


def _seconds(eta_text: str) -> int:
    m = re.fullmatch(r"ETA (?:(\d+) min )?(\d+) s", eta_text)
    assert m, eta_text
    return int(m.group(1) or 0) * 60 + int(m.group(2))


def test_eta_counts_down_between_reports_and_gives_way_when_the_job_ends(qtbot):
    runner = JobRunner()
    widget = JobProgressWidget(runner)
    qtbot.addWidget(widget)
    runner.start(_wait_for_cancel)
    runner.progress.emit(3, 10, "view 3 of 10", 120.0)      # the last report: 2 min left
    assert _seconds(widget.eta_label.text()) == 120
    # no further report (the next view is slow): the ETA still moves on
    qtbot.waitUntil(lambda: widget.eta_label.text() != "ETA 2 min 00 s", timeout=5000)
    assert 100 < _seconds(widget.eta_label.text()) < 120
    with qtbot.waitSignal(runner.cancelled, timeout=10000):
        qtbot.mouseClick(widget.cancel_button, Qt.LeftButton)
    assert widget.eta_label.text() == "cancelled"
    assert widget.message_label.text() == "Cancelled"        # not "Cancelling…" forever
    assert not widget.cancel_button.isEnabled()


def test_a_finished_job_shows_how_long_it_took(qtbot):
    runner = JobRunner()
    widget = JobProgressWidget(runner)
    qtbot.addWidget(widget)

    def job(*, progress, cancel):
        progress(1, 2, "half")
        progress(2, 2, "done")
        return 42

    with qtbot.waitSignal(runner.finished, timeout=10000):
        runner.start(job)
    assert re.fullmatch(r"took \d+ s", widget.eta_label.text()), widget.eta_label.text()


def test_an_estimate_that_has_passed_shows_as_unknown_not_0_s(qtbot):
    """Importing a light field counted its fast file checks and its slow shear measurement alike: the ETA
    reached "0 s" and stayed there for the whole measurement."""
    runner = JobRunner()
    widget = JobProgressWidget(runner)
    qtbot.addWidget(widget)
    runner.start(_wait_for_cancel)
    runner.progress.emit(45, 90, "measuring the disparities between views", 0.5)     # half a second left
    qtbot.waitUntil(lambda: widget.eta_label.text() == "ETA –", timeout=10000)       # ... passed, still running
    with qtbot.waitSignal(runner.cancelled, timeout=10000):
        qtbot.mouseClick(widget.cancel_button, Qt.LeftButton)


def test_the_eta_follows_the_rate_of_the_steps_being_done_now():
    from lfstudio.jobs import EtaEstimator

    now = [0.0]
    eta = EtaEstimator(clock=lambda: now[0], window_s=30.0)
    assert eta.update(0, 200) is None
    for done in range(1, 101):                  # 100 file checks in 1 s
        now[0] += 0.01
        eta.update(done, 200)
    for done in range(101, 111):                # then 10 measurement steps of 10 s each
        now[0] += 10.0
        left = eta.update(done, 200)
    assert 0.5 * 900 < left < 1.5 * 900         # 90 steps left at 10 s each (from the start: 101 s)
    assert eta.update(3, 10) is None             # counted from 0 again: a new job, no rate yet
