"""The GRBL protocol, checked against the real GRBL 1.1h firmware (its official simulator, built from
../shared/vendor/grbl by tests/grbl_firmware.py) and against our simulator
(lfstudio/sim/grbl_controller.py), with the same tests: the ``grbl`` fixture yields either backend
(as python-microscope's DeviceTests run one suite against every device). Where the firmware and our
simulator disagree, our simulator is wrong.

Both backends run at about 10x real time; no test depends on it: tests wait for states and events.
Raw-serial tests pin down the firmware's own behaviour; driver tests run
lfstudio.rig.grbl.GrblController over pyserial on the same pty.
"""

from __future__ import annotations

import threading
import time

import pytest
import serial

from lfstudio.rig.grbl import GrblController, MotionStopped
from lfstudio.rig.motion import AxisConfig, RigConfig, RigState, SoftLimitError
from lfstudio.rig.profile import load_rig
from lfstudio.rig.worker import DeviceWorker
from lfstudio.sim.grbl_controller import GrblSimulator
from tests.grbl_firmware import FIRMWARE_DEFAULTS, FirmwareSimulator


def _axis(name: str, letter: str, travel: float = 200.0, soft_max: float = 200.0) -> AxisConfig:
    return AxisConfig(name, letter, travel, 0.0, soft_max, 25.0, 100.0, 10.0)


#: the rig the protocol tests drive: X/Y, 200 mm of travel (GRBL's default $130/$131)
RIG = RigConfig("protocol test rig", _axis("horizontal", "X"), _axis("vertical", "Y"), homing=False)
HOMING_RIG = RigConfig("protocol test rig, switches", _axis("horizontal", "X"), _axis("vertical", "Y"))
#: settings written to both backends before each test (they match RIG: no profile warnings)
SETTINGS = {110: 1500.0, 111: 1500.0, 120: 100.0, 121: 100.0, 130: 200.0, 131: 200.0, 21: 0, 23: 0, 25: 500.0}
HOMING = {22: 1, 20: 1}
#: the firmware's limit switches (mm from its power-up position), placed as our simulator places
#: them for RIG: the carriage powers up near the high end, the switches 1 mm outside the travel
SWITCHES = ((-181.0, 21.0), (-181.0, 21.0), (-196.0, 5.0))


class Backend:
    """One GRBL controller on a pty: the firmware or our simulator, driven the same way."""

    def __init__(self, name: str, sim: FirmwareSimulator | GrblSimulator):
        self.name = name
        self.sim = sim

    @property
    def port(self) -> str:
        return self.sim.port

    @property
    def lines_received(self) -> list[str]:
        return self.sim.lines_received

    @property
    def lines_sent(self) -> list[str]:
        return self.sim.lines_sent

    @property
    def realtime_received(self) -> list[bytes]:
        return self.sim.realtime_received

    def configure(self, settings: dict[int, float]) -> None:
        """Settings as an operator's setup tool writes them, then a power cycle."""
        if isinstance(self.sim, FirmwareSimulator):
            self.sim.configure(settings)
        else:
            self.sim.set_settings(settings)
            self.sim.wait_port_closed()
            self.sim.power_cycle()

    def reset_on_open(self) -> None:
        self.sim.reset_on_open = True

    def wait_port_closed(self) -> None:
        assert self.sim.wait_port_closed(10)


@pytest.fixture(params=["firmware", "ours"])
def grbl(request, tmp_path):
    if request.param == "firmware":
        exe = request.getfixturevalue("grbl_firmware_exe")
        sim = FirmwareSimulator(exe, tmp_path / "firmware", speedup=10.0, switches=SWITCHES)
    else:
        sim = GrblSimulator(RIG, time_scale=0.1, seed=3)
    sim.start()
    backend = Backend(request.param, sim)
    backend.configure(SETTINGS)
    yield backend
    sim.close()


@pytest.fixture
def connect(grbl):
    opened: list[GrblController] = []

    def make(rig: RigConfig = RIG, **options) -> GrblController:
        controller = GrblController(grbl.port, rig, timeout_s=3.0, **options)
        controller.connect()
        opened.append(controller)
        return controller

    yield make
    for controller in opened:
        controller.disconnect()


class Raw:
    """A bare pyserial session on the backend's port, line by line."""

    def __init__(self, port: str):
        self.port = serial.Serial(port, 115200, timeout=0.05)
        self.buf = bytearray()

    def close(self) -> None:
        self.port.close()

    def line(self, timeout_s: float = 10.0) -> str | None:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self.buf:
            if time.monotonic() > deadline:
                return None
            self.buf += self.port.read(256)
        raw, _, rest = bytes(self.buf).partition(b"\n")
        self.buf = bytearray(rest)
        return raw.decode("ascii", "replace").strip()

    def until(self, predicate, timeout_s: float = 10.0) -> list[str]:
        """Lines up to and including the first one ``predicate`` accepts."""
        seen = []
        while True:
            got = self.line(timeout_s)
            assert got is not None, f"timed out; got {seen}"
            if got:
                seen.append(got)
                if predicate(got):
                    return seen

    def send(self, text: str) -> str:
        """Send a line; its answer (ok / error:N / ALARM:N), push lines before it skipped."""
        self.port.write(text.encode() + b"\n")
        return self.until(lambda s: s == "ok" or s.startswith(("error:", "ALARM:")))[-1]

    def report(self) -> str:
        self.port.write(b"?")
        return self.until(lambda s: s.startswith("<"))[-1]

    def sync(self) -> None:
        """Wait until the controller answers (it may still be booting; bytes sent then are lost)."""
        deadline = time.monotonic() + 20
        while True:
            self.port.write(b"?")
            got = self.line(0.3)
            while got is not None and not got.startswith("<"):
                got = self.line(0.3)
            if got is not None:
                self.buf.clear()
                return
            assert time.monotonic() < deadline, "the controller never answered"


@pytest.fixture
def raw(grbl):
    sessions: list[Raw] = []

    def open_raw() -> Raw:
        session = Raw(grbl.port)
        session.sync()
        sessions.append(session)
        return session

    yield open_raw
    for s in sessions:
        s.close()


# -- the handshake ---------------------------------------------------------------------------------
def test_handshake_reads_version_settings_and_offsets(grbl, connect):
    c = connect()
    assert c.version.startswith("1.1h")
    assert c.settings[110] == 1500 and c.settings[121] == 100 and c.settings[130] == 200
    assert c.firmware.max_rate_mm_min["X"] == 1500 and not c.firmware.soft_limits
    assert c.warnings == [] and c.board_resets == 0 and c.alarms == []
    status = c.status()
    assert status.state is RigState.IDLE and not status.homed and "set the origin" in status.message
    assert grbl.lines_received[-4:] == ["$I", "$$", "$#", "$G"]


def test_a_board_reset_on_open_is_reported_and_the_controller_is_locked(grbl, connect):
    grbl.configure(HOMING)
    grbl.reset_on_open()
    c = connect(HOMING_RIG)
    assert c.board_resets == 1 and c.locked and "'$H'|'$X' to unlock" in c.messages
    status = c.status()
    assert status.state is RigState.ALARM and not status.homed
    assert status.message == "The controller restarted and is locked (alarm): home the rig"
    assert status.extra["locked"] and status.extra["reference"] == ""
    with pytest.raises(Exception, match="locked"):
        c.move_to(10, 10)
    c.unlock()
    assert c.status().state is RigState.IDLE and "Caution: Unlocked" in c.messages
    with pytest.raises(Exception, match="position is unknown; home the rig first"):
        c.move_to(10, 10)
    c.home()
    status = c.status()
    # GRBL homes to the switch at the high end and pulls off $27 = 1 mm: MPos -1; our frame is
    # MPos + $130, so the home position is 199 mm, the frame 0 … 200 mm
    assert status.homed and status.extra["reference"] == "homed"
    assert status.position_mm == pytest.approx((199.0, 199.0), abs=0.01)
    assert status.extra["mpos"][:2] == pytest.approx((-1.0, -1.0), abs=0.01)
    c.disconnect()
    grbl.wait_port_closed()
    c.connect()                          # the port opens again: the board reboots, locked again
    assert c.board_resets == 1 and c.status().state is RigState.ALARM and not c.status().homed


def test_a_later_connection_trusts_only_a_homing_lfstudio_did_since_the_last_reset(grbl, raw, connect):
    grbl.configure(HOMING)
    c = connect(HOMING_RIG)
    c.home()
    assert grbl.lines_received[-1] == "T1" and c.reference == "homed"
    c.move_to(100.0, 100.0)
    c.reset()                                  # idle: GRBL keeps its position, lfstudio its reference
    assert c.status().homed and grbl.lines_received[-1] == "T1"
    c.disconnect()
    grbl.wait_port_closed()
    c.connect()                                # not reset since: homed, at the same place
    status = c.status()
    assert status.homed and status.position_mm == pytest.approx((100.0, 100.0))
    c.disconnect()
    grbl.wait_port_closed()
    grbl.configure({})                         # a power cycle: locked; $X unlocks without homing
    r = raw()
    assert r.send("$X") == "ok"
    r.close()
    grbl.wait_port_closed()
    c.connect()
    status = c.status()
    assert status.state is RigState.IDLE and not status.homed and "home the rig" in status.message


def test_connecting_to_a_controller_stuck_in_a_critical_alarm_resets_it(grbl, raw, connect):
    grbl.configure(HOMING)
    r = raw()
    assert r.send("$X") == "ok" and r.send("G0 X5") == "ALARM:2"    # critical: silent until a reset
    r.close()
    grbl.wait_port_closed()
    c = connect(HOMING_RIG)
    status = c.status()
    assert status.state is RigState.ALARM and status.message.endswith("locked (alarm): home the rig")
    assert c.board_resets == 0 and not c._critical
    c.home()
    assert c.status().homed


# -- motion through the driver ---------------------------------------------------------------------
def test_set_origin_then_move(grbl, connect):
    c = connect()
    c.set_origin()
    status = c.move_to(50.0, 20.0)
    assert status.state is RigState.IDLE and status.position_mm == pytest.approx((50.0, 20.0))
    assert grbl.lines_received[-1] == "G90 G54 G0 X50.000 Y20.000"
    again = c.status()
    assert again.extra["mpos"][:2] == pytest.approx(
        (again.position_mm[0] + c._wco[0], again.position_mm[1] + c._wco[1]))


def test_jog_then_jog_cancel(grbl, connect):
    c = connect()
    c.set_origin()
    c.move_to(10.0, 10.0)
    c.jog(150.0, 0.0, speed_mm_s=10.0)
    assert grbl.lines_received[-1] == "$J=G90 G21 X160.000 Y10.000 F600"
    assert c.status().state is RigState.JOGGING
    deadline = time.monotonic() + 20
    while c.status().position_mm[0] < 11.0:       # under way
        assert time.monotonic() < deadline
    c.jog_cancel()
    status = c.status()
    assert status.state is RigState.IDLE and 10.0 < status.position_mm[0] < 160.0
    assert status.position_mm[1] == pytest.approx(10.0)


def _subscribe(worker: DeviceWorker):
    snapshots = []
    seen = {s: threading.Event() for s in RigState}

    def on(snapshot):
        snapshots.append(snapshot)
        seen[snapshot.state].set()

    worker.subscribe(on)
    return snapshots, seen


def test_feed_hold_completes_as_hold_0_and_resume_finishes_the_move(grbl, connect):
    c = connect()
    c.set_origin()
    worker = DeviceWorker(c, name="rig", publish_hz=100)
    snapshots, seen = _subscribe(worker)
    try:
        future = worker.submit("move_to", 150.0, 100.0)
        assert seen[RigState.MOVING].wait(20)
        c.feed_hold()
        assert seen[RigState.HOLD].wait(20)
        deadline = time.monotonic() + 20
        while not any(s.extra.get("grbl_state") == "Hold:0" for s in snapshots):
            assert time.monotonic() < deadline, [s.extra.get("grbl_state") for s in snapshots]
            time.sleep(0.02)
        assert not future.done()
        holds = [s.extra["grbl_state"] for s in snapshots if s.state is RigState.HOLD]
        first_complete = holds.index("Hold:0")   # Hold:1 (decelerating) never comes after Hold:0
        assert set(holds[:first_complete]) <= {"Hold:1"} and set(holds[first_complete:]) == {"Hold:0"}
        c.resume()
        assert future.result(60).position_mm == pytest.approx((150.0, 100.0))
    finally:
        worker.close(disconnect=False)


def test_stop_during_a_long_move_ends_idle_at_a_known_position(grbl, connect):
    c = connect()
    c.set_origin()
    c.move_to(10.0, 10.0)
    worker = DeviceWorker(c, name="rig", publish_hz=100)
    moved = threading.Event()
    worker.subscribe(lambda s: moved.set() if s.state is RigState.MOVING and s.position_mm
                     and s.position_mm[0] > 12.0 else None)
    try:
        future = worker.submit("move_to", 190.0, 190.0)
        assert moved.wait(20)
        worker.stop_now()
        with pytest.raises(MotionStopped, match=r"stopped by STOP; the rig is idle at \("):
            future.result(30)
        status = worker.call("status")
    finally:
        worker.close(disconnect=False)
    assert status.state is RigState.IDLE and status.homed       # the reference is kept
    x, y = status.position_mm
    assert 12.0 < x < 190.0 and x == pytest.approx(y, abs=0.01)  # on the line, short of the target
    assert c.alarms == [] and not any(line.startswith("ALARM") for line in grbl.lines_sent)
    # the reset came only once the hold was complete: the last report before the banner says Hold:0
    assert grbl.realtime_received == [b"!", b"\x85", b"\x18"]
    banner = max(i for i, line in enumerate(grbl.lines_sent) if line.startswith("Grbl "))
    assert [line for line in grbl.lines_sent[:banner] if line.startswith("<")][-1].startswith("<Hold:0|")
    c.disconnect()
    c.connect()                          # the controller itself kept that position
    assert c.status().extra["mpos"][:2] == pytest.approx(status.extra["mpos"][:2], abs=0.001)
    c.set_origin()
    assert c.move_to(5.0, 5.0).position_mm == pytest.approx((5.0, 5.0))


def test_stop_during_homing_resets_and_the_driver_stays_in_step(grbl, connect):
    """GRBL sends no status report while homing: the driver announces HOMING itself; STOP resets
    at once (GRBL ignores a feed hold while homing): ALARM 6, then the late 'ok' of $H, which the
    driver does not take for the answer to its next command."""
    grbl.configure(HOMING)
    c = connect(HOMING_RIG)
    worker = DeviceWorker(c, name="rig", publish_hz=50)
    homing = threading.Event()
    worker.subscribe(lambda s: homing.set() if getattr(s, "state", None) is RigState.HOMING else None)
    try:
        future = worker.submit("home")
        assert homing.wait(30)
        worker.stop_now()
        with pytest.raises(MotionStopped, match="interrupted by STOP"):
            future.result(30)
        status = worker.call("status")
        assert status.state is RigState.ALARM and not status.homed
        assert c.alarms in ([6], [])          # [] when the reset reached GRBL before the $H line did
        assert grbl.realtime_received == [b"\x18"]
        worker.call("unlock")
        assert worker.call("status").state is RigState.IDLE and grbl.lines_received[-1] == "$X"
        worker.call("home")
        assert worker.call("status").position_mm == pytest.approx((199.0, 199.0), abs=0.01)
    finally:
        worker.close(disconnect=False)


def test_moves_at_grbl_default_rates_use_the_controllers_rates(grbl, connect):
    """GRBL's defaults ($110=500 mm/min, $120=10 mm/s²) with the reference gantry's profile
    (200 mm/s): the driver warns and times the move from the controller, and a 100 mm move completes."""
    grbl.configure({k: v for k, v in FIRMWARE_DEFAULTS.items() if k in (110, 111, 120, 121)})
    c = connect(load_rig())
    assert any("$110 = 500 mm/min" in w for w in c.warnings)
    assert any("$120 = 10 mm/s²" in w for w in c.warnings)
    assert c.expected_move_s(100.0, 0.0) == pytest.approx(100 / (500 / 60) + (500 / 60) / 10, rel=1e-6)
    c.set_origin()
    status = c.move_to(100.0, 0.0)
    assert status.position_mm == pytest.approx((100.0, 0.0)) and status.state is RigState.IDLE


# -- soft limits and the frame ---------------------------------------------------------------------
def test_soft_limits_map_our_frame_onto_grbls_negative_machine_frame(grbl, connect):
    grbl.configure(HOMING)
    wide = RigConfig("wide profile", _axis("horizontal", "X", 250.0, 250.0), _axis("vertical", "Y", 250.0, 250.0))
    c = connect(wide)
    assert c.firmware.soft_limits and any("$130 = 200 mm" in w for w in c.warnings)
    c.home()
    assert c.firmware_range_mm() == ((0.0, 200.0), (0.0, 200.0))
    for target in ((5.0, 5.0), (200.0, 200.0), (0.0, 0.0), (120.0, 30.0)):
        assert c.move_to(*target).position_mm == pytest.approx(target)
    sent = len(grbl.lines_received)
    with pytest.raises(SoftLimitError) as exc:
        c.move_to(220.0, 10.0)
    assert (exc.value.kind, exc.value.field, exc.value.valid) == ("soft-limit", "target x (horizontal)", "0 … 200 mm")
    assert "$130 = 200 mm" in str(exc.value)          # names the controller's setting that limits it
    with pytest.raises(SoftLimitError) as exc:
        c.move_to(10.0, -0.5)
    assert exc.value.kind == "soft-limit" and exc.value.field.startswith("target y")
    assert len(grbl.lines_received) == sent
    c.jog(500.0, 0.0)                     # clamped to the controller's travel: no error:15
    assert grbl.lines_received[-1].startswith("$J=G90 G21 X200.000 Y30.000")
    c.jog_cancel()
    assert c.alarms == [] and c.status().state is RigState.IDLE


def test_with_hard_limits_the_driver_keeps_off_the_home_switch(grbl, connect):
    """GRBL's envelope ends where the home switch triggers; with $21 = 1 touching it is ALARM 1:
    the driver's range stops at the home position (the pull-off, $27 = 1 mm, from the switch)."""
    grbl.configure({**HOMING, 21: 1})
    c = connect(HOMING_RIG)
    c.home()
    assert c.firmware_range_mm() == ((0.0, 199.0), (0.0, 199.0))
    assert c.move_to(0.0, 199.0).position_mm == pytest.approx((0.0, 199.0))
    sent = len(grbl.lines_received)
    with pytest.raises(SoftLimitError) as exc:
        c.move_to(199.5, 10.0)
    assert (exc.value.kind, exc.value.field, exc.value.valid) == ("soft-limit", "target x (horizontal)", "0 … 199 mm")
    assert "$27 = 1 mm" in str(exc.value)            # names the pull-off
    c.jog(0.0, 10.0)                                # y is at its home position: clamped, nothing sent
    assert len(grbl.lines_received) == sent and c.alarms == []


def test_grbl_soft_limits_in_machine_coordinates_raw(grbl, raw):
    """GRBL checks every target against -$130 … 0 whether homed or not: a jog is refused with
    error:15, a move raises ALARM 2; then nothing is answered, not even '?', until a reset, and the
    move's own 'ok' comes after the reset, before the banner."""
    grbl.configure(HOMING)
    r = raw()
    assert r.report().startswith("<Alarm|MPos:0.000,0.000,")
    assert r.send("G0 X-5") == "error:9"            # locked: no G-code
    assert r.send("$J=G91 X-5 F100") == "error:8"   # locked: no jog
    assert r.send("$X") == "ok"
    assert r.send("$J=G91 X5 F100") == "error:15"   # MPos +5 is outside -200 … 0
    assert r.send("G1 X5") == "error:22"            # the parser's errors come first
    assert r.send("G0 X5") == "ALARM:2"
    assert r.line() == "[MSG:Reset to continue]"
    r.port.write(b"?")
    assert r.line(1.0) is None                      # critical alarm: no report
    r.port.write(b"\x18")
    assert r.until(lambda s: s.startswith("[MSG:'$H'")) == [
        "ok", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert r.report().startswith("<Alarm|")


def test_settings_guard_homing_and_soft_limits_raw(grbl, raw):
    r = raw()
    assert r.send("$H") == "error:5"               # homing off ($22=0)
    assert r.send("$20=1") == "error:10"           # soft limits need homing
    assert r.send("$22=1") == "ok"
    assert r.send("$20=1") == "ok"
    assert r.send("$22=0") == "ok"                 # turning homing off turns soft limits off
    r.port.write(b"$$\n")
    settings = r.until(lambda s: s == "ok")
    assert "$20=0" in settings and "$22=0" in settings and "$110=1500.000" in settings


def test_homing_sets_grbls_negative_machine_frame_raw(grbl, raw):
    grbl.configure(HOMING)
    r = raw()
    assert r.send("$H") == "ok"
    report = r.report()
    assert report.startswith("<Idle|MPos:-1.000,-1.000,")
    assert r.send("G0 X-150 Y-50") == "ok"
    deadline = time.monotonic() + 30
    while not (report := r.report()).startswith("<Idle|MPos:-150.000,-50.000"):
        assert time.monotonic() < deadline, report


def test_hold_substates_and_what_a_reset_does_raw(grbl, raw):
    """'!' while moving: Hold:1 while decelerating, then Hold:0; '~' resumes. A reset in Hold:0
    keeps the position (no alarm); a reset while moving raises ALARM 3 (position lost)."""
    grbl.configure({120: 1.0, 121: 1.0})           # slow ramps: the deceleration is easy to see
    r = raw()
    assert r.send("G91 G1 X-150 F1500") == "ok"
    deadline = time.monotonic() + 60
    while True:                                    # until it runs at >= 5 mm/s
        report = r.report()
        if report.startswith("<Run") and float(report.split("FS:")[1].split(",")[0]) >= 300:
            break
        assert time.monotonic() < deadline, report
    r.port.write(b"!")
    states = []
    while not states or states[-1] != "Hold:0":
        states.append(r.report()[1:].split("|")[0])
        assert time.monotonic() < deadline, states
    while states[0] == "Run":
        states.pop(0)                              # GRBL may report before it handles the '!'
    assert states[0] == "Hold:1" and set(states[:-1]) == {"Hold:1"}
    r.port.write(b"~")
    while not r.report().startswith("<Run"):       # (a report may still show the hold)
        assert time.monotonic() < deadline
    r.port.write(b"!")
    while not r.report().startswith("<Hold:0|"):
        assert time.monotonic() < deadline
    held = r.report().split("|")[1]
    r.port.write(b"\x18")
    assert r.until(lambda s: s.startswith("Grbl")) == ["Grbl 1.1h ['$' for help]"]
    after = r.report()
    assert after.startswith("<Idle|") and after.split("|")[1] == held     # position kept, no alarm
    assert r.send("G91 G1 X-100 F1500") == "ok"
    while not r.report().startswith("<Run"):
        assert time.monotonic() < deadline
    r.port.write(b"\x18")
    assert r.until(lambda s: s.startswith("[MSG:")) == [
        "ALARM:3", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert r.report().startswith("<Alarm|")


def test_status_report_fields_raw(grbl, raw):
    """$10=1: MPos, FS, no Bf; WCO on the first report after a reset and every 10th when idle,
    Ov on the report after WCO and every 10th after that; $10=2 adds Bf and reports WPos."""
    r = raw()
    r.port.write(b"\x18")
    r.until(lambda s: s.startswith("Grbl"))
    reports = [r.report() for _ in range(12)]
    assert all(p.startswith("<Idle|MPos:") and "|FS:0,0" in p and "Bf:" not in p for p in reports)
    assert [("WCO:" in p, "Ov:" in p) for p in reports] == [
        (True, False), (False, True)] + [(False, False)] * 8 + [(True, False), (False, True)]
    assert r.send("$10=2") == "ok"
    p = r.report()
    assert p.startswith("<Idle|WPos:") and "|Bf:15,128" in p
