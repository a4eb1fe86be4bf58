"""The camera's hardware trigger on GRBL's spindle output (#40): in laser mode ($32=1) GRBL 1.1 switches
its spindle PWM inline with G1 motion, as each block's first step segment loads, without stopping.
``GrblController.fly_pulsing`` streams a row whose output rises exactly where the carriage passes each
view. Checked on the real GRBL 1.1h firmware (its official simulator, built from ../shared/vendor/grbl;
the test shim logs every change of the PWM output with the step counts and the simulated time) and on
our GRBL simulator, whose spindle output is the simulated camera's trigger line.

Times here are the simulators' own clocks between edges (simulated seconds), not this machine's:
without laser mode the firmware stops the carriage at every change, which makes the edges several
times further apart than the spacing at the speed; with it they are one spacing at the speed apart."""

from __future__ import annotations

import dataclasses
import statistics
from typing import cast

import pytest

from lfstudio.errors import DeviceError
from lfstudio.rig.grbl import GrblController
from lfstudio.rig.grbl_protocol import GrblError
from lfstudio.rig.motion import PulsesAtPositions
from lfstudio.rig.profile import load_rig
from lfstudio.sim.grbl_controller import GrblSimulator
from tests.grbl_firmware import read_spindle_log

GANTRY = load_rig()
#: no homing, no repeatability error: the edges' positions are the step counts' own
BENCH = dataclasses.replace(GANTRY, homing=False,
                            horizontal=dataclasses.replace(GANTRY.horizontal, repeatability_um=0.0),
                            vertical=dataclasses.replace(GANTRY.vertical, repeatability_um=0.0))
XS = [40.0, 45.0, 50.0, 55.0, 60.0, 65.0]           # views 5 mm apart, after a 40 mm run-up
SPEED = 50.0                                       # mm/s: 0.1 s between views


def _fly_row(controller: GrblController) -> None:
    controller.fly_pulsing(XS, 80.0, 0.0, SPEED)
    controller.wait_arrival(80.0, 0.0, 60.0)
    controller.pulse_off()


# -- the real firmware ---------------------------------------------------------------------------------
@pytest.fixture
def laser_firmware(grbl_firmware, tmp_path):
    def start(laser: int):
        log = tmp_path / f"spindle-{laser}.log"
        # 2x real time: the driver streams one line at a time and must stay ahead of the firmware's
        # planner even on a busy machine (else GRBL starves and stops, as a real board would)
        fw = grbl_firmware(spindle_log=log, speedup=2.0)
        # the gantry's rates ($110 mm/min, $120 mm/s²) and laser mode as the operator sets them once
        fw.configure({32: laser, 110: 12000.0, 120: 500.0, 130: 4000.0})
        c = GrblController(fw.port, BENCH, timeout_s=5.0)
        c.connect()
        c.set_origin()
        return fw, c, log
    return start


def test_firmware_laser_mode_raises_the_output_at_each_view_without_stopping(laser_firmware):
    fw, c, log = laser_firmware(1)
    try:
        assert isinstance(cast(object, c), PulsesAtPositions) and c.pulse_problem(5.0, SPEED) is None
        assert c.planner_blocks == 15 and "V" in c.options           # [OPT:V,15,128]
        _fly_row(c)
    finally:
        c.disconnect()
    edges = read_spindle_log(log)
    rising = [e for e in edges if e[1]]
    steps = c.settings[100]
    # at each view, to the step: GRBL sets the PWM as the block's first segment loads, just before its
    # first step (the shim sees it after that interrupt, one step on)
    assert [e[2][0] - round(x * steps) for e, x in zip(rising, XS)] == [1] * len(XS)
    assert all(e[3] == 255 for e in rising)                         # S = $30: full PWM
    assert not any(e[1] for e in edges[-1:])                        # off again at the end (S0, M5)
    gaps = [b[0] - a[0] for a, b in zip(rising, rising[1:])]
    nominal = 5.0 / SPEED
    # one spacing at the speed apart: never stopped (the 1 MHz simulated AVR times steps ~1 % coarsely)
    assert max(gaps) < 1.05 * nominal and min(gaps) > 0.95 * nominal, gaps


def test_firmware_without_laser_mode_stops_at_every_change_and_the_driver_refuses(laser_firmware):
    fw, c, log = laser_firmware(0)
    try:
        problem = c.pulse_problem(5.0, SPEED)
        assert problem is not None and "$32 = 0" in problem and "$32=1" in problem
        with pytest.raises(DeviceError, match=r"hardware trigger refused: GRBL's laser mode is off"):
            c.fly_pulsing(XS, 80.0, 0.0, SPEED)
        # what it refuses to do: the same G-code without laser mode makes GRBL stop for each change
        c._command(f"G90 G1 F{SPEED * 60:g} M3 S0")
        for x in XS:
            c._command(f"G1 X{x:.3f} S0", timeout_s=30)
            c._command(f"G1 X{x + 1:.3f} S1000", timeout_s=30)
        c._command("G1 X80 S0", timeout_s=30)
        # GRBL comes to rest (Idle) at each change before it starts the next block (spindle_sync): on a
        # busy machine the firmware simulator stood Idle at the last view over the driver's 0.5 s grace
        # (a stop short of the target to the driver) before its cycle start took the last block
        c.idle_grace_s = 30.0
        c.wait_arrival(80.0, 0.0, 60.0)
        c.pulse_off()
    finally:
        c.disconnect()
    rising = [e for e in read_spindle_log(log) if e[1]]
    # switched standing still at each view (spindle_sync waited for the carriage to stop there)
    assert [e[2][0] - round(x * c.settings[100]) for e, x in zip(rising, XS)] == [0] * len(XS)
    gaps = [b[0] - a[0] for a, b in zip(rising, rising[1:])]
    assert statistics.median(gaps) > 2 * (5.0 / SPEED), gaps


def test_firmware_refuses_a_row_its_planner_cannot_see_far_enough_ahead(laser_firmware):
    fw, c, log = laser_firmware(1)
    try:
        # 15 blocks, two a view: 7 views of 1 mm ahead, but 200 mm/s at 500 mm/s² needs 40 mm to stop
        problem = c.pulse_problem(1.0, 200.0)
        assert problem is not None
        assert "GRBL plans 15 moves ahead, 7 views (7 mm)" in problem and "40 mm it needs to stop" in problem
        assert "at most 83.7 mm/s" in problem
        with pytest.raises(DeviceError, match="hardware trigger refused"):
            c.fly_pulsing([40.0 + k for k in range(10)], 80.0, 0.0, 200.0)
    finally:
        c.disconnect()
    assert not any(e[1] for e in read_spindle_log(log))              # nothing was sent: the output never rose


# -- our simulator -------------------------------------------------------------------------------------
@pytest.fixture
def sim_controller():
    made = []

    def start(laser: int):
        sim = GrblSimulator(BENCH, time_scale=1.0)       # real time: the stream stays ahead of it
        sim.set_settings({32: laser})
        port = sim.start()
        c = GrblController(port, BENCH, timeout_s=5.0)
        c.connect()
        c.set_origin()
        made.append((sim, c))
        return sim, c
    yield start
    for sim, c in made:
        c.disconnect()
        sim.close()


def test_simulator_switches_its_output_where_the_firmware_does(sim_controller):
    sim, c = sim_controller(1)
    assert c.pulse_problem(5.0, SPEED) is None
    _fly_row(c)
    edges = sim.spindle_output.edges()
    rising = [t for t, level in edges if level]
    assert len(rising) == len(XS) and not edges[-1][1]
    # where the carriage was at each rising edge: at the view (the history keeps block ends exactly)
    where = [sim.true_position_at(t) for t in rising]
    assert [round(p[0], 3) for p in where] == XS
    gaps = [(b - a) / sim.time_scale for a, b in zip(rising, rising[1:])]     # simulated seconds
    assert max(gaps) < 1.02 * 5.0 / SPEED and min(gaps) > 0.98 * 5.0 / SPEED, gaps


def test_simulator_without_laser_mode_stops_at_every_change(sim_controller):
    sim, c = sim_controller(0)
    assert "$32 = 0" in (c.pulse_problem(5.0, SPEED) or "")
    c._command(f"G90 G1 F{SPEED * 60:g} M3 S0")
    for x in XS[:3]:
        c._command(f"G1 X{x:.3f} S0", timeout_s=30)
        c._command(f"G1 X{x + 1:.3f} S1000", timeout_s=30)
    c._command("G1 X60 S0", timeout_s=30)
    c.wait_arrival(60.0, 0.0, 60.0)
    rising = [t for t, level in sim.spindle_output.edges() if level]
    assert [round(sim.true_position_at(t)[0], 3) for t in rising] == XS[:3]
    gaps = [(b - a) / sim.time_scale for a, b in zip(rising, rising[1:])]
    assert min(gaps) > 1.5 * 5.0 / SPEED, gaps                            # stopped for each change


def test_a_pulse_near_the_end_of_travel_never_leaves_the_soft_limits(sim_controller):
    """The output stays high ``pulse_mm`` past each view: for a view closer than that to the row's end
    (the run-down cut short by the soft limit, as FlyScanEngine clamps it) the old driver streamed
    ``G1 X80.5 S1000`` on a rig whose travel ends at 80 mm, then came back to 80. Now the pulse ends
    at the row's end: no target beyond it, the carriage never past it, every view still triggered."""
    sim, c = sim_controller(1)
    near = dataclasses.replace(BENCH, horizontal=dataclasses.replace(BENCH.horizontal, soft_max_mm=80.0))
    c.config = near
    xs = [59.5, 64.5, 69.5, 74.5, 79.5]                       # the last view 0.5 mm from the end of travel
    c.fly_pulsing(xs, 80.0, 0.0, SPEED)
    c.wait_arrival(80.0, 0.0, 60.0)
    c.pulse_off()
    targets = [float(word[1:]) for line in sim.lines_received for word in line.split() if word.startswith("X")]
    assert targets and max(targets) <= 80.0, targets
    rising = [t for t, level in sim.spindle_output.edges() if level]
    assert [round(sim.true_position_at(t)[0], 3) for t in rising] == xs


# -- a line GRBL refuses in the middle of a streamed row ----------------------------------------------
#: 20 views 2 mm apart: 41 streamed lines, more than GRBL's 128-byte buffer and 15-block planner hold
LONG_XS = [40.0 + 2.0 * k for k in range(20)]
REFUSED_X = 60.0                                   # the view whose 'G1 X60.000 S0' arrives garbled


def _garble_one_line(controller: GrblController, x: float) -> list[str]:
    """Make the driver's stream send the line that brings the output low before view ``x`` garbled (a
    character lost on the wire: ``G1 X6#.000 S0``, which GRBL refuses with error:1). Returns the lines
    the stream was given."""
    real = controller._stream
    given: list[str] = []

    def garbled(lines: list[str]) -> None:
        target = f"G1 X{x:.3f} S0"
        assert target in lines, lines
        given.extend(lines)
        bad = target.replace(f"X{x:.3f}"[:3], f"X{x:.3f}"[:2] + "#")
        real([bad if line == target else line for line in lines])

    controller._stream = garbled                   # type: ignore[method-assign]
    return given


def _fly_with_a_refused_line(c: GrblController, xs: list[float], end_x: float) -> str:
    """Fly the row with one line garbled; the error's text (raised by fly_pulsing while it streams, or
    by wait_arrival when its answer came after the last line left). It names the line GRBL refused (its
    number among the row's lines, as sent) and GRBL's error with its meaning (the old text said only
    "controller refused 'a line of the fly row': error 1, ...")."""
    given = _garble_one_line(c, REFUSED_X)
    with pytest.raises(GrblError) as caught:
        c.fly_pulsing(xs, end_x, 0.0, SPEED)
        c.wait_arrival(end_x, 0.0, 60.0)
    text = str(caught.value)
    number = given.index(f"G1 X{REFUSED_X:.3f} S0") + 1
    assert text.startswith(f'GRBL refused line {number} of {len(given)} of the fly row, "G1 X6#.000 S0", with '
                           "error:1 (G-code words consist of a letter and a value; the letter was not found)"), text
    return text


def _assert_held_before(c: GrblController, text: str, x_limit: float) -> tuple[float, float]:
    # GRBL's own reports: idle (reset after a complete hold: no ALARM 3, the position kept), standing
    # short of the refused line's view, and no longer moving
    first = c.status()
    assert first.state.name == "IDLE" and first.homed and not c.alarms, (first, c.alarms)
    assert first.position_mm is not None and first.position_mm[0] < x_limit, first
    assert "carriage was held and the rest of the row dropped" in text, text
    x, y = first.position_mm
    assert f"not found); the carriage stopped at x = {x:.3f} mm, y = {y:.3f} mm, position kept (GRBL goes on" in text
    for _ in range(3):
        c._last_t = 0.0                                  # ask the controller each time, not the cache
        again = c.status()
        assert again.state.name == "IDLE" and again.position_mm == first.position_mm
    return first.position_mm


def test_firmware_a_line_refused_mid_row_holds_the_carriage_and_drops_the_rest(laser_firmware):
    """GRBL 1.1h drops a refused line and executes the lines after it (protocol.c): the driver holds the
    carriage, waits for Hold:0 and resets, so nothing after the refused line runs; the position is kept
    (a reset after a complete hold raises no alarm) and the row can be flown again."""
    fw, c, log = laser_firmware(1)
    try:
        text = _fly_with_a_refused_line(c, LONG_XS, 110.0)
        x, _ = _assert_held_before(c, text, REFUSED_X)
        edges = read_spindle_log(log)
        rising = [e for e in edges if e[1]]
        steps = c.settings[100]
        # every edge that came was at its view (to the step, one on as the shim sees it; the hold's
        # deceleration can make it the step itself); none at or after the refused line's view; the
        # output is low (the reset stops the spindle)
        assert all(0 <= e[2][0] - round(v * steps) <= 1 for e, v in zip(rising, LONG_XS)), (rising, x)
        assert all(e[2][0] < round(REFUSED_X * steps) for e in rising) and not edges[-1][1]
        assert edges[-1][2][0] <= round(x * steps) + 1
        # flown again from a run-up: every view's edge, the rig still referenced
        c._stream = GrblController._stream.__get__(c)    # type: ignore[method-assign]
        c.move_to(0.0, 0.0)
        start = len(read_spindle_log(log))
        c.fly_pulsing(LONG_XS, 110.0, 0.0, SPEED)
        c.wait_arrival(110.0, 0.0, 60.0)
        c.pulse_off()
    finally:
        c.disconnect()
    again = [e for e in read_spindle_log(log)[start:] if e[1]]
    assert [e[2][0] - round(v * steps) for e, v in zip(again, LONG_XS)] == [1] * len(LONG_XS)


def test_firmware_a_refused_line_answered_after_the_stream_left_also_holds(laser_firmware):
    """A short row: GRBL's buffer takes every line at once, so the error's answer may come while the
    driver already waits for the arrival; the carriage is held all the same."""
    fw, c, log = laser_firmware(1)
    try:
        text = _fly_with_a_refused_line(c, XS, 80.0)
        _assert_held_before(c, text, REFUSED_X)
    finally:
        c.disconnect()
    edges = read_spindle_log(log)
    assert not edges or not edges[-1][1]


def test_simulator_a_line_refused_mid_row_holds_the_carriage_and_drops_the_rest(sim_controller):
    sim, c = sim_controller(1)
    text = _fly_with_a_refused_line(c, LONG_XS, 110.0)
    x, _ = _assert_held_before(c, text, REFUSED_X)
    assert sim.state == "Idle" and abs(sim.reported_position_mm()[0] - x) < 1e-3
    rising = [t for t, level in sim.spindle_output.edges() if level]
    assert all(sim.true_position_at(t)[0] < REFUSED_X for t in rising) and not sim.spindle_output.level
    assert b"!" in sim.realtime_received and b"\x18" in sim.realtime_received


def _hold_never_completes(c: GrblController) -> None:
    """The driver waits for Hold:0 only so long (its timeout and three stops from full speed); past that it
    resets all the same: GRBL then raises ALARM 3 (a reset while the steppers may run), the position is
    lost, and the error says so (the scan's resume then asks for homing). Forced here by a wait of 0."""
    c._stop_time_s = lambda: -10.0                     # type: ignore[method-assign]  (no time to hold)
    text = _fly_with_a_refused_line(c, LONG_XS, 110.0)
    st = c.status()
    assert st.state.name == "ALARM" and not st.homed and 3 in c.alarms, (st, c.alarms)
    assert "ALARM 3 (reset while moving): its position is lost; home the rig again" in text, text


def test_firmware_a_hold_that_does_not_complete_in_time_is_reset_anyway_and_says_the_position_is_lost(
        laser_firmware):
    fw, c, log = laser_firmware(1)
    try:
        _hold_never_completes(c)
    finally:
        c.disconnect()


def test_simulator_a_hold_that_does_not_complete_in_time_is_reset_anyway_and_says_the_position_is_lost(
        sim_controller):
    sim, c = sim_controller(1)
    _hold_never_completes(c)
    assert sim.state == "Alarm"
