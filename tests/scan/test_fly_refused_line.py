"""A line GRBL refuses in the middle of a hardware-triggered fly row (#40). GRBL 1.1h drops the refused
line and executes the ones after it; the driver holds the carriage, waits for the hold to complete and
resets (the rest of the row dropped, the position kept), and the scan pauses saying so, with the
carriage standing. On resume the row's views not taken are flown again from a run-up (never taken
standing still for this), and every view ends done at its position.

On the simulated studio (the GRBL simulator on a pty through the real driver); the same reaction on the
real GRBL 1.1h firmware is tests/rig/test_grbl_laser_trigger.py::test_firmware_a_line_refused_mid_row_*."""

from __future__ import annotations

import json
from typing import Any

from lfstudio.dataset import Dataset
from lfstudio.rig.grbl import GrblController
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.fly import FlyScanEngine
from lfstudio.scan.scan_plan import ScanPlan
from tests.scan.conftest import RIG
from tests.scan.test_fly_scan import SCALE, check_views, fly_studio


def garble_the_first_row(monkeypatch, pick) -> list[list[str]]:
    """Every fly row's lines as the driver streams them (before garbling); in the first, the line ``pick(lines)``
    is sent as one GRBL refuses ("G1 X#…": error:1 on the firmware, error:2 on our simulator)."""
    real = GrblController._stream
    sent: list[list[str]] = []

    def garbled_once(self: GrblController, lines: list[str]) -> None:
        sent.append(lines)
        if len(sent) == 1:
            target = pick(lines)
            lines = [line.replace("G1 X", "G1 X#", 1) if line == target else line for line in lines]
        real(self, lines)

    monkeypatch.setattr(GrblController, "_stream", garbled_once)
    return sent


def test_a_line_refused_mid_row_pauses_with_the_carriage_stopped_and_resume_flies_the_row_again(tmp_path, monkeypatch):
    session, plan, ds = fly_studio(tmp_path / "ds", columns=12, rows=2)
    try:
        driver = session.rig
        sim = session.simulator
        assert isinstance(driver, GrblController)
        # row 0 goes left to right: garble the line that brings the output low before its 9th view
        refused_x = plan.views()[8].x_mm
        target = f"G1 X{refused_x:.3f} S0"
        streams = garble_the_first_row(monkeypatch, lambda lines: target)
        engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                               speed_mm_s=40.0, trigger="hardware")
        events = []
        engine.subscribe(events.append)
        engine.start()
        assert engine.wait_for_state(ScanState.PAUSED, timeout_s=120), engine.message
        # the scan says paused: the carriage stands (idle, not held nor moving), short of the refused
        # line's view, and the message says what happened and where the rig is
        status = engine.rig.call("status", timeout_s=10)
        assert status.state.name == "IDLE" and status.homed, status
        assert sim.state == "Idle" and sim.reported_position_mm()[0] < refused_x
        x, y = status.position_mm
        # in the operator's words (the Scan panel shows this message, the CLI prints it): the line GRBL
        # refused, its error and meaning, where the carriage stopped and that its position is kept; not
        # the generic "Check the axis controller's cable, power and alarms" of a failing rig
        assert target in streams[0]
        number = streams[0].index(target) + 1
        assert engine.message == (
            f'Flying row 0: GRBL refused line {number} of {len(streams[0])} of the fly row, '
            f'"{target.replace("G1 X", "G1 X#")}", with error:2 (bad number format or missing value); the carriage '
            f"stopped at x = {x:.3f} mm, y = {y:.3f} mm, position kept (GRBL goes on with the lines after a "
            "refused one, so the carriage was held and the rest of the row dropped: feed hold, then reset). The "
            "row's views not taken are flown again from its run-up when the scan goes on."), engine.message
        assert not sim.spindle_output.level                     # the trigger line is low
        late = [t for t in sim.spindle_output.rising() if sim.true_position_at(t)[0] >= refused_x]
        assert late == [], "the row went on after the refused line"
        kept = {(v["row"], v["column"]) for v in Dataset.open(ds.root).done_views()}
        assert all(row == 0 and column < 8 for row, column in kept), kept

        engine.resume()
        assert engine.wait(180) is ScanState.FINISHED, engine.message
        flown, retaken = check_views(ds.root, engine)
        assert flown + retaken == 24
        logs = [e.message for e in events if e.kind is EventKind.LOG]
        assert sum(m.startswith("row 0: flying") for m in logs) == 2, logs
        d = Dataset.open(ds.root)
        for v in d.views:
            record: dict[str, Any] = dict(v)
            fly = record.get("fly") or {}
            # a view the refused line cut off was flown again, not taken standing still for it
            assert "missed trigger" not in fly.get("retaken", ""), record
            truth = json.loads((d.root / record["sidecars"][1]).read_text())
            assert abs(truth["true_position_mm"][0] - record["commanded_mm"][0]) < 0.5 * plan.spacing_mm[0]
    finally:
        session.close()


def test_a_row_refused_before_the_carriage_moves_pauses_without_waiting_out_the_cameras_time_limit(tmp_path,
                                                                                                monkeypatch):
    """The row's first line bringing the output low refused (streamed before the carriage moves): the
    frames the row never triggers end at once, and the scan pauses then, not when the camera's time
    limit (an hour here) runs out: the engine waited on its own condition for futures that never woke
    it (the CLI took ~20 s to say a line was refused)."""
    session, plan, ds = fly_studio(tmp_path / "ds", columns=6, rows=1)
    try:
        garble_the_first_row(monkeypatch, lambda lines: [line for line in lines if line.endswith(" S0")][1])
        engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                               speed_mm_s=40.0, trigger="hardware")
        engine._capture_timeout = 3600.0               # a frame may take an hour: only its end settles it
        engine.start()
        assert engine.wait_for_state(ScanState.PAUSED, timeout_s=120), engine.message
        assert "GRBL refused line" in engine.message
        assert Dataset.open(ds.root).status_counts()["done"] <= 1
        engine.abort()
        assert engine.wait(60) is ScanState.FINISHED
    finally:
        session.close()


def test_a_refused_line_whose_hold_does_not_complete_pauses_saying_the_position_is_lost_and_resume_asks_for_homing(
        tmp_path, monkeypatch):
    """When the hold does not complete in time the driver resets all the same: GRBL raises ALARM 3 and
    its position is lost. The pause says so, Resume refuses to go on until the rig is homed, and after
    homing the scan finishes with every view at its position."""
    session, plan, ds = fly_studio(tmp_path / "ds", columns=12, rows=2)
    try:
        driver = session.rig
        refused_x = plan.views()[8].x_mm
        target = f"G1 X{refused_x:.3f} S0"
        garble_the_first_row(monkeypatch, lambda lines: target)
        real_stop_time = driver._stop_time_s
        driver._stop_time_s = lambda: -10.0               # type: ignore[method-assign]  (no time to hold)
        engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                               speed_mm_s=40.0, trigger="hardware")
        engine.start()
        assert engine.wait_for_state(ScanState.PAUSED, timeout_s=120), engine.message
        assert "ALARM 3 (reset while moving): its position is lost; home the rig again" in engine.message, \
            engine.message
        assert "with error:2 (bad number format or missing value)" in engine.message and "cable" not in engine.message
        assert session.simulator.state == "Alarm"
        driver._stop_time_s = real_stop_time              # type: ignore[method-assign]
        engine.resume().result(timeout=60)               # resumed: the rig is checked first
        assert engine.wait_for_state(ScanState.PAUSED, timeout_s=60) and "Home the rig" in engine.message, \
            engine.message
        session.simulator.time_scale = SCALE / 10           # homing is not what this test measures
        engine.rig.call("home", timeout_s=120)
        session.simulator.time_scale = SCALE
        engine.resume()
        assert engine.wait(180) is ScanState.FINISHED, engine.message
        flown, retaken = check_views(ds.root, engine)
        assert flown + retaken == 24
        d = Dataset.open(ds.root)
        for view in d.views:
            record: dict[str, Any] = dict(view)
            truth = json.loads((d.root / record["sidecars"][1]).read_text())
            assert abs(truth["true_position_mm"][0] - record["commanded_mm"][0]) < 0.5 * plan.spacing_mm[0]
    finally:
        session.close()


def test_the_cli_says_which_line_grbl_refused_and_where_the_carriage_stopped(tmp_path, monkeypatch, capsys):
    """``lfstudio scan --fly --trigger hardware`` (in this process, the driver's stream garbling one line):
    the run stops saying which line GRBL refused, with its error and meaning, and where the carriage
    stands, then how to resume; never the cable advice of a rig that stopped answering."""
    from lfstudio.cli import main

    sent = garble_the_first_row(monkeypatch,        # row 0's 4th view: its line bringing the output low
                                lambda lines: [line for line in lines if line.endswith(" S0")][3])
    centred = ScanPlan.centered(8, 2, (4.0, 6.0), RIG).origin_mm     # the grid 30 mm from home, as fly_studio's
    code = main(["scan", "--out", str(tmp_path / "ds"), "--grid", "8x2", "--spacing-mm", "4x6",
                 f"--offset-mm={30 - centred[0]:g}x{30 - centred[1]:g}", "--sim-width-px", "64", "--time-scale",
                 str(SCALE), "--fly", "--exposure-s", "0.001", "--transfer-s", "0.05", "--trigger", "hardware"])
    err = capsys.readouterr().err
    assert code != 0, err
    stopped = [line for line in err.splitlines() if line.startswith("lfstudio scan: stopped: ")]
    assert len(stopped) == 1, err
    bad = [line for line in sent[0] if line.startswith("G1 X") and line.endswith(" S0")][3].replace("G1 X", "G1 X#")
    number = [line.replace("G1 X", "G1 X#", 1) for line in sent[0]].index(bad) + 1
    text = stopped[0]
    assert (f'stopped: Flying row 0: GRBL refused line {number} of {len(sent[0])} of the fly row, "{bad}", with '
            "error:2 (bad number format or missing value); the carriage stopped at x = ") in text, text
    assert " mm, position kept (GRBL goes on with the lines after a refused one" in text, text
    assert "cable" not in text and "Traceback" not in err
    assert "--resume" in err.split(text, 1)[1]
