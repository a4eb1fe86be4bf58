"""Fly scanning on CiA 402 drives (#40): the driver's FlyingController (profile position at a set
profile velocity 6081h, time-stamped 6064h reads, arrival, STOP, limits) and its touch probe latching
(60B8h-60BBh) against the drive emulator, over Modbus TCP (dryve D1 gateway telegrams) and CANopen.
The emulator's own history of where the carriage was is the truth; nothing here is timed by the
test's clock: every figure compares a report with the truth at the report's own timestamp."""

from __future__ import annotations

import threading
import time

import pytest

from lfstudio.errors import DeviceError
from lfstudio.rig.cia402 import MotionStopped
from lfstudio.rig.motion import FlyingController, LatchesPositions, RigState, SoftLimitError
from lfstudio.rig.profile import load_rig
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
TRANSPORTS = ["modbus", "canopen"]
SCALE = 0.2


@pytest.fixture
def drives():
    rig = load_rig(RIG_NAME)
    opened = []

    def start(transport: str, time_scale: float = SCALE, **setup):
        emulator = start_drive_emulator(rig, transport, time_scale=time_scale, seed=3, setup=setup or None)
        opened.append(emulator)
        link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=2.0)
        opened.insert(0, link)
        link.controller.connect()
        link.controller.home()
        return emulator, link.controller

    yield start
    for thing in opened:
        thing.close()


def _fly_and_collect(emulator, c, x_to: float, speed: float, edges_every_mm: float = 0.0, pulse_s: float = 0.001):
    """Fly to ``x_to`` at ``speed`` while reading reports (and, with ``edges_every_mm``, pulsing the touch
    probe input as a camera's exposure output would, ``pulse_s`` of simulated time long, on a thread of its
    own: the reports go on meanwhile); returns the reports and the (rise, fall) times of the pulses."""
    reports, pulses = [], []
    c.fly_to(x_to, 0.0, speed)
    done = threading.Event()
    failure: list[BaseException] = []

    def wait() -> None:
        try:
            c.wait_arrival(x_to, 0.0, 120)
        except BaseException as exc:  # noqa: BLE001
            failure.append(exc)
        done.set()

    def pulse() -> None:
        t0 = time.monotonic()
        emulator.exposure_output(True, t0)
        t1 = t0 + pulse_s * emulator.time_scale
        while time.monotonic() < t1:
            pass
        emulator.exposure_output(False, t1)
        pulses.append((t0, t1))

    waiter = threading.Thread(target=wait)
    waiter.start()
    next_edge = edges_every_mm
    pulser: threading.Thread | None = None
    while not done.is_set():
        r = c.report()
        reports.append(r)
        if edges_every_mm and r.x_mm >= next_edge and r.x_mm < x_to - 5 and (pulser is None or not pulser.is_alive()):
            pulser = threading.Thread(target=pulse)
            pulser.start()
            next_edge = r.x_mm + edges_every_mm
    if pulser is not None:
        pulser.join()
    waiter.join()
    assert not failure, failure
    return reports, pulses


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_fly_to_moves_at_the_profile_velocity_and_reports_agree_with_the_truth(drives, transport):
    emulator, c = drives(transport)
    assert isinstance(c, FlyingController)
    mark = len(emulator.pair.journal)
    reports, _ = _fly_and_collect(emulator, c, 300.0, 80.0)
    # the profile velocity 6081h written is 80 mm/s in the drive's units (0.01 mm: 8000 per s)
    written = [v for name, index, _s, v in emulator.pair.journal[mark:] if name == "horizontal" and index == 0x6081]
    assert written and written[-1] == 8000
    # the carriage crossed the middle of the row at that speed: the emulator's own history, in its clock
    axis = emulator.pair.axes[0]
    t_mid = min((r for r in reports if 40 < r.x_mm < 260), key=lambda r: abs(r.x_mm - 150)).t_s
    a, b = axis.true_position_at(t_mid - 0.05 * SCALE), axis.true_position_at(t_mid + 0.05 * SCALE)
    assert (b - a) / 0.1 == pytest.approx(80.0, rel=1e-3)
    # every report is where the carriage was at its timestamp, within what its uncertainty allows
    # (80 mm/s over half the round trip) plus a position unit (0.01 mm)
    moving = [r for r in reports if 5 < r.x_mm < 295]
    assert len(moving) >= 10
    for r in moving:
        truth = emulator.true_position_at(r.t_s)
        assert truth is not None
        assert abs(r.x_mm - truth[0]) <= 80.0 / SCALE * r.uncertainty_s + 0.011, (r, truth)
        assert r.y_mm == pytest.approx(0.0, abs=0.011) and r.uncertainty_s >= 0
    assert c.status().position_mm == pytest.approx((300.0, 0.0), abs=0.06)
    assert c.status().state is RigState.IDLE


def test_a_row_reads_only_the_moving_drive(drives):
    emulator, c = drives("modbus")
    reads: list[int] = []
    original = c._read

    def counting(i, index, sub=0):
        if index == 0x6064:
            reads.append(i)
        return original(i, index, sub)

    def reads_of_report():
        reads.clear()
        c._read = counting
        try:
            c.report()
        finally:
            c._read = original
        return sorted(reads)

    assert reads_of_report() == [0, 1]                 # standing: both drives
    c.fly_to(100.0, 0.0, 50.0)
    assert reads_of_report() == [0]                    # a row: the vertical drive stands where it was read
    c.wait_arrival(100.0, 0.0, 60)
    assert reads_of_report() == [0, 1]


def test_fly_targets_beyond_the_limits_and_speeds_beyond_the_axis_are_refused_before_anything_is_sent(drives):
    emulator, c = drives("modbus", time_scale=0.0)
    mark = len(emulator.pair.journal)
    with pytest.raises(SoftLimitError, match="4100"):
        c.fly_to(4100.0, 0.0, 50.0)
    with pytest.raises(DeviceError, match="250 mm/s on the horizontal axis is faster than its 200 mm/s"):
        c.fly_to(1000.0, 0.0, 250.0)
    with pytest.raises(DeviceError, match="not a positive number"):
        c.fly_to(1000.0, 0.0, float("nan"))
    assert emulator.pair.journal[mark:] == []


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_stop_during_a_fly_move_quick_stops_both_drives(drives, transport):
    emulator, c = drives(transport, time_scale=0.05)
    c.fly_to(3000.0, 0.0, 150.0)
    while emulator.true_position_mm()[0] < 100:
        c.report()
    mark = len(emulator.pair.journal)
    failure: list[BaseException] = []

    def wait() -> None:
        try:
            c.wait_arrival(3000.0, 0.0, 120)
        except BaseException as exc:  # noqa: BLE001
            failure.append(exc)

    t = threading.Thread(target=wait)
    t.start()
    c.stop()
    t.join(60)
    assert len(failure) == 1 and isinstance(failure[0], MotionStopped)
    quick = {name for name, index, _s, value in emulator.pair.journal[mark:] if index == 0x6040 and value == 0x0B}
    assert quick == {"horizontal", "vertical"}
    x = c.status().position_mm[0]
    assert 100 <= x < 3000 and x == pytest.approx(emulator.true_position_mm()[0], abs=0.011)


@pytest.mark.parametrize("transport, pulse_s", [("modbus", 0.001), ("canopen", 0.001), ("modbus", 0.03)])
def test_touch_probes_latch_the_exposure_centre(drives, transport, pulse_s):
    """A 1 ms exposure, and a 30 ms one during which the driver looks at the probe and sees only its
    rising edge stored (it waits for the falling one; the latch's window still holds the whole pulse)."""
    emulator, c = drives(transport, touch_probe=True)
    assert isinstance(c, LatchesPositions)
    reports, pulses = _fly_and_collect(emulator, c, 300.0, 80.0, edges_every_mm=40.0, pulse_s=pulse_s)
    latches = c.latches()
    assert len(pulses) >= 4
    assert len(latches) == emulator.pair.axes[0].probe_latches
    assert len(latches) >= len(pulses) - 1          # a pulse while the probe was being armed again is lost
    for latch in latches:
        pulse = [p for p in pulses if latch.t_after_s <= p[0] and p[1] <= latch.t_seen_s]
        assert len(pulse) == 1, (latch, pulses)      # each latch's window holds its own pulse
        centre = emulator.true_position_at((pulse[0][0] + pulse[0][1]) / 2)
        assert latch.edges == "both"
        assert latch.x_mm == pytest.approx(centre[0], abs=0.011) and latch.y_mm == pytest.approx(0.0, abs=0.011)
    assert c.latches() == []                         # handed out once
    assert not any("touch probe" in w for w in c.status().extra["warnings"])


def test_a_drive_without_touch_probe_says_so_once_and_latches_nothing(drives):
    emulator, c = drives("modbus")                   # as the dryve D1 comes: no 60B8h
    _fly_and_collect(emulator, c, 100.0, 50.0, edges_every_mm=20.0)
    _fly_and_collect(emulator, c, 0.0, 50.0)
    assert c.latches() == [] and emulator.pair.axes[0].probe_latches == 0
    said = [w for w in c.status().extra["warnings"] if "touch probe" in w]
    assert len(said) == 1 and "interpolated from its position reads (6064h)" in said[0]


def test_a_fly_move_on_drives_whose_units_disagree_is_refused_before_anything_is_sent():
    """#38's unit check holds for fly moves: drives counting micrometres (6092h:01 = 70000) under a profile
    of 100 per mm would fly ten times too far and fast."""
    from lfstudio.rig.cia402 import UnitsMismatch

    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, "modbus", time_scale=0.0, setup={"feed": 70000})
    link = open_rig(emulator.word, rig, doing="test", lock=False, timeout_s=2.0)
    try:
        c = link.controller
        c.accept_reference()
        mark = len(emulator.pair.journal)
        with pytest.raises(UnitsMismatch, match="fly move refused.*60A8h"):
            c.fly_to(100.0, 0.0, 50.0)
        assert emulator.pair.journal[mark:] == []
    finally:
        link.close()
        emulator.close()
