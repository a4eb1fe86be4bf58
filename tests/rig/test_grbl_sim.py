"""The GRBL driver against our simulated controller over a real pseudo-terminal: what only the
simulator offers (ground truth, fault injection, instant motion for property tests). The protocol
itself is checked against the real firmware and the simulator alike in test_grbl_protocol.py."""

from __future__ import annotations

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lfstudio.errors import DeviceError
from lfstudio.rig.grbl import ConnectionLost, GrblAlarm, PositionError
from lfstudio.rig.motion import MotionController, RigState, SoftLimitError
from lfstudio.rig.profile import load_rig
from lfstudio.sim.grbl_controller import GrblSimulator
from lfstudio.studio.devices import open_rig as _open_rig


def open_rig(port, rig, **options):
    """``(controller, simulator)`` for ``port`` "sim", connected (no port lock: one process here)."""
    link = _open_rig(port, rig, lock=False, **options)
    return link.controller, link.simulator


def inside(rig, target):
    return rig.horizontal.contains(target[0]) and rig.vertical.contains(target[1])


def _line_starting(port, prefix: bytes) -> bytes:
    """The next line starting with ``prefix`` (banner lines from power-up may come first)."""
    for _ in range(20):
        line = port.readline()
        if line.startswith(prefix) or not line:
            return line
    return b""


def test_simulator_speaks_grbl_on_a_pty():
    rig = load_rig()
    with GrblSimulator(rig, time_scale=0) as sim:
        assert sim.port.startswith("/dev/")
        with serial.Serial(sim.port, 115200, timeout=1) as port:
            port.write(b"\x18")  # soft reset: the banner again (the power-up one may predate the open)
            assert _line_starting(port, b"Grbl") == b"Grbl 1.1h ['$' for help]\r\n"
            assert _line_starting(port, b"[MSG") == b"[MSG:'$H'|'$X' to unlock]\r\n"
            port.write(b"?")
            assert _line_starting(port, b"<").startswith(b"<Alarm|MPos:")
            port.write(b"$I\n")
            assert _line_starting(port, b"[VER") == b"[VER:1.1h.20190830:]\r\n"
            port.write(b"G0 X10\n")  # locked until homed or unlocked
            assert _line_starting(port, b"error") == b"error:9\r\n"


def test_handshake_home_move_and_ground_truth(sim_rig):
    controller, sim = sim_rig
    assert isinstance(controller, MotionController)
    assert controller.version.startswith("1.1") and controller.settings[110] == 200 * 60
    status = controller.move_to(1234.5, 321.0)
    assert status.state is RigState.IDLE and status.homed
    assert status.position_mm == pytest.approx((1234.5, 321.0), abs=0.02)
    true_x, true_y = sim.true_position_mm()
    assert abs(true_x - 1234.5) < 5 * 0.080 and abs(true_y - 321.0) < 5 * 0.050
    assert (true_x, true_y) != (1234.5, 321.0)  # the repeatability error is there
    assert sim.records[-1].target_mm == pytest.approx((1234.5, 321.0))


def test_no_motion_before_homing_and_nothing_sent_outside_soft_limits():
    rig = load_rig()
    controller, sim = open_rig("sim", rig, time_scale=0, timeout_s=1.0)
    try:
        assert controller.status().state is RigState.ALARM
        with pytest.raises(DeviceError, match="home the rig"):
            controller.move_to(10, 10)
        controller.unlock()
        with pytest.raises(DeviceError, match="position is unknown"):
            controller.jog(5, 0)
        controller.home()
        with pytest.raises(SoftLimitError, match=r"4000.5 mm is outside the soft limits.*0 … 4000 mm"):
            controller.move_to(4000.5, 10)
        with pytest.raises(SoftLimitError, match="target y"):
            controller.move_to(10, -0.1)
        with pytest.raises(SoftLimitError, match="not a finite number"):
            controller.move_to(float("nan"), 1)
        assert sim.records == []
        controller.move_to(3990, 495)
        controller.jog(100, 100)          # clamped to the soft limits
        assert sim.records[-1].target_mm == (4000.0, 500.0)
        controller.jog(10, 10)            # already at the limit: nothing is sent
        assert len(sim.records) == 2
    finally:
        controller.disconnect()
        sim.close()


def test_rig_without_switches_needs_an_origin():
    rig = load_rig("Desktop slider 1 m")   # X and Z axes, no homing
    controller, sim = open_rig("sim", rig, time_scale=0, timeout_s=1.0)
    try:
        with pytest.raises(DeviceError, match="no limit switches"):
            controller.home()
        with pytest.raises(DeviceError, match="set the origin first"):
            controller.move_to(1, 1)
        controller.set_origin()
        status = controller.move_to(500, 100)
        assert status.position_mm == pytest.approx((500, 100))
        assert sim.lines_received[-1].startswith("G90 G54 G0 X500.000 Z100.000")
        assert sim.reported_position_mm() == pytest.approx((500, 100))
    finally:
        controller.disconnect()
        sim.close()


def test_fault_alarm_mid_move(sim_rig):
    controller, sim = sim_rig
    sim.inject("alarm_mid_move")
    with pytest.raises(GrblAlarm, match="hard limit"):
        controller.move_to(2000, 200)
    status = controller.status()
    assert status.state is RigState.ALARM and not status.homed and "home" in status.message
    with pytest.raises(DeviceError):
        controller.move_to(10, 10)
    controller.home()                       # recovery: reset + home
    assert controller.move_to(10, 10).state is RigState.IDLE


def test_fault_position_error(sim_rig):
    controller, sim = sim_rig
    sim.inject("position_error")
    with pytest.raises(PositionError, match=r"stopped at \(499.500, 50.000\).*target \(500.000, 50.000\)"):
        controller.move_to(500, 50)
    assert controller.move_to(500, 50).position_mm == pytest.approx((500, 50))


def test_fault_garbage_is_ignored(sim_rig):
    controller, sim = sim_rig
    sim.inject("garbage")
    for i in range(6):
        assert controller.move_to(10 + i, 5).position_mm == pytest.approx((10 + i, 5))
    assert controller.garbage_lines > 0


def test_fault_silent_then_reconnect(sim_rig):
    controller, sim = sim_rig
    sim.inject("silent")
    with pytest.raises(ConnectionLost, match="did not"):
        controller.move_to(20, 20)
    status = controller.status()
    assert status.state is RigState.DISCONNECTED and "connect again" in status.message
    with pytest.raises(ConnectionLost):
        controller.jog(1, 0)
    sim.clear_faults()
    controller.connect()
    # the controller was not reset (not in ALARM): a new connection keeps its homing
    assert controller.status().state is RigState.IDLE and controller.status().homed
    controller.home()
    assert controller.move_to(20, 20).homed


def test_fault_drop(sim_rig):
    controller, sim = sim_rig
    sim.inject("drop")
    with pytest.raises(ConnectionLost, match="lost"):
        controller.move_to(30, 30)
    assert controller.status().state is RigState.DISCONNECTED
    with pytest.raises(DeviceError, match="cannot open"):
        controller.connect()


def test_unknown_fault_is_refused():
    with pytest.raises(ValueError, match="drop, silent"):
        GrblSimulator(load_rig()).inject("fire")


_rig = load_rig()
commands = st.one_of(
    st.tuples(st.just("move"), st.floats(-500, 4500, allow_nan=False), st.floats(-100, 600, allow_nan=False)),
    st.tuples(st.just("jog"), st.floats(-5000, 5000, allow_nan=False), st.floats(-700, 700, allow_nan=False)),
    st.tuples(st.just("origin"), st.just(0.0), st.just(0.0)),
)


@pytest.fixture(scope="module")
def instant_rig():
    controller, sim = open_rig("sim", _rig, time_scale=0, timeout_s=1.0)
    controller.home()
    yield controller, sim
    controller.disconnect()
    sim.close()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(commands, min_size=1, max_size=8))
def test_property_no_target_outside_soft_limits_is_ever_sent(instant_rig, sequence):
    controller, sim = instant_rig
    for kind, a, b in sequence:
        try:
            if kind == "move":
                controller.move_to(a, b)
            elif kind == "jog":
                controller.jog(a, b)
                controller.jog_cancel()
            else:
                controller.home()
        except SoftLimitError:
            assert not inside(_rig, (a, b))
    assert sim.records, "some motion reached the controller"
    bad = [r for r in sim.records if not inside(_rig, r.target_mm)]
    assert bad == []


def test_simulator_gcode_dialect_over_raw_serial():
    rig = load_rig()
    with GrblSimulator(rig, time_scale=0) as sim:
        with serial.Serial(sim.port, 115200, timeout=1) as port:
            def answer(line: bytes) -> bytes:
                port.write(line + b"\n")
                for _ in range(30):
                    got = port.readline()
                    if got.startswith((b"ok", b"error", b"ALARM")) or not got:
                        return got
                return b""

            assert answer(b"$H") == b"ok\r\n"
            port.write(b"$$\n")
            settings_lines = []
            while (got := port.readline()) not in (b"ok\r\n", b""):
                settings_lines.append(got)
            assert b"$110=12000.000\r\n" in settings_lines and b"$22=1\r\n" in settings_lines
            assert answer(b"G1 X10") == b"error:22\r\n"          # G1 needs a feed rate
            assert answer(b"G91 G0 X5 Y2") == b"ok\r\n"          # relative, from MPos (-3999, -499)
            assert answer(b"G0 X5") == b"ok\r\n"
            assert sim.reported_position_mm() == pytest.approx((-3989, -497))
            assert answer(b"G90 G92 X0 Y0") == b"ok\r\n"          # work offset: here is (0, 0)
            assert sim.reported_position_mm() == pytest.approx((0, 0))
            assert answer(b"G92.1") == b"ok\r\n"
            assert answer(b"G10 L20 P1 X1 Y1") == b"ok\r\n"
            assert sim.reported_position_mm() == pytest.approx((1, 1))
            assert answer(b"$J=G90 X9999 F1000") == b"error:15\r\n"   # jog beyond the travel
            assert answer(b"$J=G90 X20") == b"error:22\r\n"          # jog without feed
            assert answer(b"G7") == b"error:20\r\n"
            assert answer(b"$H X") == b"error:3\r\n"


def test_malformed_lines_are_logged_and_ignored_by_the_reader(sim_rig):
    controller, sim = sim_rig
    before = controller.garbage_lines
    for text in ("$1=.", "$1=1.2.3", "[G54:1..2,0,0]", "ALARM:" + "9" * 5000, "error:" + "7" * 4500,
                 "<Idle|MPos:1,2", "\x00\xff\x85 noise"):
        sim.push_line(text)
    controller._handshake()                 # the lines arrive among the answers to ?, $I, $$ and $#
    assert controller.garbage_lines - before == 7
    assert controller.settings[110] == 200 * 60 and controller.settings[1] == 25   # "$1=." changed nothing
    assert controller.move_to(100, 100).position_mm == pytest.approx((100, 100))
