"""Industrial drives as they really are (issue 38): each drive's objects, units and reference are
learnt and checked at connect, never assumed. Every case on both transports (Modbus TCP gateway to
the emulator's server, CANopen SDO to python-canopen LocalNodes), against the emulator told to lack
objects, to count in other units, or to be found enabled but never homed."""

from __future__ import annotations

import logging

import pytest

from lfstudio.rig.cia402 import MissingObject, UnitsMismatch, si_units_per_mm
from lfstudio.rig.profile import load_rig
from lfstudio.errors import DeviceError
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
TRANSPORTS = ["modbus", "canopen"]


@pytest.fixture
def rig():
    return load_rig(RIG_NAME)


@pytest.fixture
def drives(rig):
    """``drives(transport, setup=None, connect=True, **options) -> (emulator, controller)``; ``setup``:
    the emulated drives' AxisSetup fields (both, or a (horizontal, vertical) pair)."""
    opened = []

    def start(transport: str, setup=None, connect: bool = True, time_scale: float = 0.0, **options):
        emulator = start_drive_emulator(rig, transport, time_scale=time_scale, seed=2, setup=setup)
        opened.append(emulator)
        link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=0.5, **options)
        opened.insert(0, link)
        if connect:
            link.controller.connect()
        return emulator, link.controller

    yield start
    for thing in opened:
        thing.close()


def _control_writes(emulator) -> list:
    return [w for w in emulator.pair.journal if w[1] in (0x6040, 0x607A)]


def test_si_unit_position_as_the_d1_writes_it():
    # OptovisTech/DryveD1API Modules/SIUnitPosition.cs: byte 21 = 01h linear, byte 22 = FBh (0.01 mm, default)
    assert si_units_per_mm(int.from_bytes(bytes([0, 0, 0x01, 0xFB]), "little")) == pytest.approx(100)
    assert si_units_per_mm(0xFD010000) == pytest.approx(1)          # mm
    assert si_units_per_mm(0xFA010000) == pytest.approx(1000)       # µm
    assert si_units_per_mm(0xFE410000) is None                      # 41h: degrees, a rotary axis


# -- units -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize("leave_out, named", [((), ("60A8h", "6092h")), ((0x60A8,), ("6092h",)),
                                              ((0x6092,), ("60A8h",))])
def test_a_drive_counting_other_units_than_the_profile_moves_nothing(drives, transport, leave_out, named):
    """A drive set up for 1 mm position units (6092h:01 = 70 for a 70 mm/rev belt, 60A8h = FD010000h)
    under a profile of 100 increments per mm: 'home move 50 10' drove the carriage to 100 times the
    distance (old code). Now: refused before anything moves, naming both and the fix; 'units' writes
    the profile's units to the stopped drives, then the same commands land where they should."""
    emulator, c = drives(transport, setup={"feed": 70, "leave_out": leave_out})
    st = c.status()
    for name in named:
        assert name in st.message
    assert "increments_per_mm = 100" in st.message and "units" in st.message and "\n" not in st.message
    del emulator.pair.journal[:]
    for attempt in (c.home, lambda: c.move_to(50, 10)):
        with pytest.raises(UnitsMismatch) as exc:
            attempt()
        assert "drive x (horizontal)" in str(exc.value) and "nothing moves" in str(exc.value)
    assert _control_writes(emulator) == []                          # not one control word or target
    if leave_out == (0x6092,):
        # only 60A8h: the drive's unit is written; the emulator's scale follows 6092h, still 70 per rev
        return
    written = c.write_units()
    assert any("6092h = 7000" in line for line in written)
    # the drive's 607Dh kept its numbers, now in 0.01 mm: 4000 -> 40 mm, 500 -> 5 mm (said)
    assert any("607Dh now read 0 … 40 mm" in line for line in written)
    assert not any(c.units_problem) and not c.status().homed
    c.home()
    c.move_to(30, 4)
    assert emulator.true_position_mm() == pytest.approx((30.0, 4.0), abs=0.011)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_units_are_not_written_to_a_moving_drive(drives, transport):
    emulator, c = drives(transport, time_scale=0.05)
    c.home()
    c.jog(300, 0)
    with pytest.raises(DeviceError, match="moving"):
        c.write_units()
    c.stop()


# -- reference ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_drive_found_enabled_is_not_taken_as_homed(drives, transport, caplog):
    """Enabled in profile position mode by another program and never homed: the old driver took such
    drives as homed ('kept') and 'move 100 100' drove from a reference nobody established."""
    emulator, c = drives(transport, setup={"enabled_unhomed": True})
    st = c.status()
    assert st.extra["power_state"] == {"x": "OPERATION ENABLED", "y": "OPERATION ENABLED"}
    assert not st.homed and st.extra["reference"] == ""
    del emulator.pair.journal[:]
    with pytest.raises(DeviceError, match="home the rig first"):
        c.move_to(100, 100)
    assert _control_writes(emulator) == []
    # the operator accepts the drives' own reference explicitly: logged, reported as kept
    with caplog.at_level(logging.WARNING, logger="lfstudio.rig.cia402"):
        c.accept_reference()
    assert any("kept the drives' reference" in r.getMessage() for r in caplog.records)
    st = c.status()
    assert st.homed and st.extra["reference"] == "kept"
    start = emulator.true_position_mm()
    c.move_to(100, 100)                                   # from the drives' own zero (their power-up point)
    assert emulator.true_position_mm() == pytest.approx((start[0] + 100, start[1] + 100), abs=0.011)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_the_reference_option_at_connect(drives, transport):
    _, c = drives(transport, setup={"enabled_unhomed": True}, accept_reference=True)
    assert c.status().homed and c.reference == "kept"
    c.connect()                                          # a new connection: not kept unless asked again
    assert not c.status().homed                          # (the option is the first connection's only)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_reconnect_after_a_power_cut_never_keeps_the_reference(drives, transport):
    """The reference option (lfstudio rig --keep-drive-reference; since the rig kinds, also scan
    --rig-option accept_reference=true and the Rig panel's Options box) is for the drives as the
    operator found them. A scan's recovery and the Rig panel's Recover reconnect the same driver after
    a lost link: the old driver took the drives' reference again at that connect, after a power cut
    too, where each counter restarts at 0 wherever the carriage stood, and 'move 100 20' went 100 mm
    past where it should. Now the reconnected rig is not homed and the move is refused."""
    emulator, c = drives(transport, accept_reference=True)
    c.home()
    c.move_to(100, 20)
    assert emulator.true_position_mm() == pytest.approx((100, 20), abs=0.011)
    for axis in emulator.pair.axes:
        axis.power_cycle()
    c.connect()                                          # what ScanEngine._recover / Recover do
    st = c.status()
    assert not st.homed and st.extra["reference"] == ""
    del emulator.pair.journal[:]
    with pytest.raises(DeviceError, match="home the rig first"):
        c.move_to(100, 20)
    assert _control_writes(emulator) == [] and emulator.true_position_mm() == pytest.approx((100, 20), abs=0.011)


# -- objects ------------------------------------------------------------------------------------------
OPTIONAL_CASES = [(0x605A, "605Ah"), (0x607D, "607Dh"), (0x603F, "603Fh"), (0x60F4, "60F4h"), (0x6085, "6085h"),
                  (0x606C, "606Ch"), (0x6067, "6067h"), (0x6084, "6084h")]


@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize("index, name", OPTIONAL_CASES)
def test_a_drive_without_an_optional_object_works_and_says_so_once(drives, transport, index, name, caplog):
    """None of these is mandatory in CiA 402 (a real drive's EDS lacks 603Fh, 606Ch and 6084h); the
    old driver refused to connect without 605Ah/607Dh, to report status without 603Fh/60F4h, and every
    move without 6085h."""
    with caplog.at_level(logging.WARNING, logger="lfstudio.rig.cia402"):
        emulator, c = drives(transport, setup={"leave_out": (index,)}, time_scale=0.0)
        st = c.status()
        c.home()
        st = c.move_to(120.5, 40.25)
        c.status()
        c.move_to(10, 10)
    assert st.position_mm == pytest.approx((120.5, 40.25), abs=1e-9)
    said = [r.getMessage() for r in caplog.records if name in r.getMessage()]
    assert len(said) == 2 and {"drive x" in said[0], "drive y" in said[1]} == {True}   # once per drive
    assert any(name in w for w in c.status().extra["warnings"])
    assert emulator.true_position_mm() == pytest.approx((10.0, 10.0), abs=0.011)


@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize("index", [0x605A, 0x6085, 0x606C])
def test_stop_works_without_the_optional_objects(drives, transport, index):
    import threading
    import time

    emulator, c = drives(transport, setup={"leave_out": (index,)}, time_scale=0.05)
    c.home()
    failure: list[BaseException] = []
    t = threading.Thread(target=lambda: _catch(failure, lambda: c.move_to(4000, 0)))
    t.start()
    deadline = time.monotonic() + 30
    while emulator.true_position_mm()[0] < 100 and time.monotonic() < deadline and t.is_alive():
        emulator.pair.axes[0].true_position()
    c.stop()
    t.join(30)
    assert len(failure) == 1 and "STOP" in str(failure[0])
    x, _ = c.status().position_mm
    assert 100 <= x < 4000 and c.status().homed
    assert c.move_to(x - 10, 0).position_mm == pytest.approx((x - 10, 0))


def _catch(out: list, fn) -> None:
    try:
        fn()
    except BaseException as exc:  # noqa: BLE001
        out.append(exc)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_drive_lacking_a_mandatory_object_is_refused_by_name_before_anything_moves(drives, transport):
    emulator, c = drives(transport, setup=({}, {"leave_out": (0x607A,)}), connect=False)
    with pytest.raises(MissingObject) as exc:
        c.connect()
    text = str(exc.value)
    assert "drive y (vertical)" in text and "607Ah (target position)" in text and "\n" not in text
    assert not c.connected and _control_writes(emulator) == []


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_homing_without_6098h_is_refused_by_name(drives, transport):
    emulator, c = drives(transport, setup={"leave_out": (0x6098,)})
    del emulator.pair.journal[:]
    with pytest.raises(MissingObject, match=r"drive x \(horizontal\).*6098h \(homing method\)"):
        c.home()
    assert _control_writes(emulator) == []


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_homing_method_the_drive_does_not_list_is_refused(drives, transport):
    emulator, c = drives(transport, setup={"supported_homing": (35, 37)})
    del emulator.pair.journal[:]
    with pytest.raises(MissingObject) as exc:
        c.home()
    text = str(exc.value)
    assert "homing method 17" in text and "60E3h" in text and "35, 37" in text and "horizontal.homing_method" in text
    assert emulator.pair.journal == []
    c.set_origin()                                       # 37 is listed: setting the origin works
    assert c.status().homed


# -- position window ------------------------------------------------------------------------------------
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_the_drives_position_window_is_used(drives, transport):
    """A drive settling 0.04 mm off inside its own window (6067h = 0.05 mm): the old fixed 0.02 mm
    tolerance said 'position error … home again', which aborts a scan."""
    emulator, c = drives(transport, setup={"settle_error_mm": 0.04})
    assert c.window_mm == [pytest.approx(0.05), pytest.approx(0.05)]
    c.home()
    st = c.move_to(200, 100)
    assert st.position_mm == pytest.approx((200.04, 100.04), abs=1e-9)
    assert st.extra["position_window_mm"] == [pytest.approx(0.05), pytest.approx(0.05)]


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_tolerance_may_tighten_the_window_never_loosen_it(drives, transport):
    emulator, c = drives(transport, setup={"settle_error_mm": 0.04}, tolerance_mm=0.02)
    c.home()
    with pytest.raises(DeviceError, match="position error"):
        c.move_to(200, 100)
    _, loose = drives(transport, tolerance_mm=1.0)
    assert loose.tolerance(0) == pytest.approx(0.05)
    assert any("looser than the drive's position window 6067h" in w for w in loose.status().extra["warnings"])


# -- the CLI -----------------------------------------------------------------------------------------------
def test_rig_cli_refuses_units_and_unhomed_drives_and_keeps_the_reference_on_request(run_cli):
    """``lfstudio sim-drive`` options make the variety; ``lfstudio rig`` in another process."""
    import subprocess
    import sys

    from tests.conftest import REPO_ROOT
    from tests.scankill import lfstudio_env

    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "sim-drive", "--time-scale", "0", "--feed-constant",
                             "70", "--enabled-unhomed"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=lfstudio_env(), cwd=REPO_ROOT)
    try:
        word = proc.stdout.readline().strip()
        assert word.startswith("dryve:127.0.0.1:"), proc.stderr.read() if proc.poll() is not None else word
        r = run_cli("rig", "--port", word, "--rig-profile", RIG_NAME, "move", "50", "10")
        assert r.returncode == 1
        lines = [line for line in r.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and "60A8h" in lines[0] and "increments_per_mm = 100" in lines[0]
        r = run_cli("rig", "--port", word, "--rig-profile", RIG_NAME, "units", "status")
        assert r.returncode == 0, r.stderr
        assert "units: drive x (horizontal)" in r.stdout and "6092h = 7000" in r.stdout
        r = run_cli("rig", "--port", word, "--rig-profile", RIG_NAME, "move", "50", "10")
        assert r.returncode == 1 and "home the rig first" in r.stderr     # enabled, but nobody homed it
        # (the drives' 607Dh kept its numbers, now 0 … 40 mm and 0 … 5 mm: 'units' said so)
        r = run_cli("rig", "--port", word, "--rig-profile", RIG_NAME, "--keep-drive-reference", "move", "30", "4")
        assert r.returncode == 0, r.stderr
        assert "reference kept from the drive" in r.stdout and "kept the drives' reference" in r.stderr
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stdout.close()
        proc.stderr.close()


# -- EDS/DCF -------------------------------------------------------------------------------------------------
def _rig_with_eds(tmp_path, objects, leave_out=(), text=None):
    """The drive rig's profile with ``eds_file`` (relative: next to the profile file) on both axes."""
    from lfstudio.resources import load_presets_with_files
    from lfstudio.rig.profile import rig_from_dict
    from lfstudio.sim.drive_servers import eds_text

    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in load_presets_with_files("rigs")[RIG_NAME][0].items()}
    (tmp_path / "drive.eds").write_text(text if text is not None else
                                        eds_text({k: v for k, v in objects.items() if k[0] not in leave_out}))
    for axis in ("horizontal", "vertical"):
        data[axis]["eds_file"] = "drive.eds"
    return rig_from_dict("with eds", data, str(tmp_path / "rigs.toml"))


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_the_objects_are_the_eds_files(tmp_path, transport, caplog):
    """The profile names an EDS without 6085h: the drive has it, the driver does not use it (605Ah = 5)."""
    from lfstudio.sim.cia402_drive import OBJECTS

    rig = _rig_with_eds(tmp_path, OBJECTS, leave_out=(0x6085,))
    assert rig.horizontal.eds_file == str(tmp_path / "drive.eds")
    emulator = start_drive_emulator(rig, transport, time_scale=0.0)
    link = open_rig(emulator.word, rig, lock=False, connect=False, timeout_s=0.5)
    try:
        with caplog.at_level(logging.WARNING, logger="lfstudio.rig.cia402"):
            link.controller.connect()
        c = link.controller
        assert (0x6085, 0) not in c.objects[0] and (0x6084, 0) in c.objects[0]
        assert any("has no 6085h" in r.getMessage() for r in caplog.records)
        if transport == "canopen":                       # python-canopen built the node's dictionary from it
            assert 0x607D in c.links[0].node.object_dictionary
        c.home()
        c.move_to(10, 20)
        assert not [w for w in emulator.pair.journal if w[1] == 0x6085]
        assert ("horizontal", 0x605A, 0, 5) in emulator.pair.journal
    finally:
        link.close()
        emulator.close()


@pytest.mark.parametrize("text, words", [("not an eds at all\n", "is not an EDS/DCF file"),
                                         ("[Foo]\nbar=1\n", "no [DeviceInfo] section"),
                                         ("[DeviceInfo]\nVendorName=x\n", "lists no CiA 402 drive"),
                                         (None, "no such file")])
def test_an_eds_that_is_not_one_is_one_line_and_nothing_moves(tmp_path, text, words):
    from lfstudio.errors import InputError
    from lfstudio.sim.cia402_drive import OBJECTS

    rig = _rig_with_eds(tmp_path, OBJECTS, text=text if text is not None else "")
    if text is None:
        (tmp_path / "drive.eds").unlink()
    emulator = start_drive_emulator(rig, "modbus", time_scale=0.0)
    try:
        with pytest.raises(InputError) as exc:
            open_rig(emulator.word, rig, lock=False, timeout_s=0.5)
        line = str(exc.value)
        assert words in line and "horizontal.eds_file (drive x)" in line and str(tmp_path / "drive.eds") in line
        assert "\n" not in line and "leave eds_file out" in line
        assert emulator.pair.journal == []
    finally:
        emulator.close()


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_an_eds_without_a_mandatory_object_refuses_by_name(tmp_path, transport):
    from lfstudio.sim.cia402_drive import OBJECTS

    rig = _rig_with_eds(tmp_path, OBJECTS, leave_out=(0x6081,))
    emulator = start_drive_emulator(rig, transport, time_scale=0.0)
    link = open_rig(emulator.word, rig, lock=False, connect=False, timeout_s=0.5)
    try:
        with pytest.raises(MissingObject, match=r"6081h \(profile velocity\).*its EDS/DCF lists no such object"):
            link.controller.connect()
        assert emulator.pair.journal == []
    finally:
        link.close()
        emulator.close()


class _Objects:
    """A drive as a bare object dictionary (no motion): for what connect learns from the values."""

    def __init__(self, address: str, objects: dict):
        self.address = address
        self.objects = dict(objects)

    def open(self) -> None: ...
    def close(self) -> None: ...

    def read(self, index: int, sub: int, size: int, signed: bool) -> int:
        from lfstudio.rig.cia402 import ObjectAccessRefused

        if (index, sub) not in self.objects:
            raise ObjectAccessRefused(f"{index:04X}h:{sub} does not exist")
        return self.objects[(index, sub)]

    def write(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        self.read(index, sub, size, signed)
        self.objects[(index, sub)] = value

    write_now = write


@pytest.mark.parametrize("velocity, acceleration, kv, ka", [
    (0xFD010300, 0xFD015700, 1.0, 1.0),                  # mm/s, mm/s²: one unit per mm/s
    (0xFB014700, None, 6000.0, 100.0),                    # 0.01 mm/min: 6000 per mm/s; no 60AAh: position units
    (None, None, 100.0, 100.0)])                          # neither: position units per second (the D1)
def test_speeds_and_accelerations_in_the_units_the_drive_reports(rig, velocity, acceleration, kv, ka):
    from lfstudio.rig.cia402 import Cia402Controller

    base = {(0x6040, 0): 0, (0x6041, 0): 0x0640, (0x6060, 0): 0, (0x6061, 0): 0, (0x6064, 0): 0, (0x607A, 0): 0,
            (0x6081, 0): 0, (0x6083, 0): 0, (0x6098, 0): 17, (0x6099, 1): 0, (0x6099, 2): 0,
            (0x60A8, 0): 0xFB010000}
    if velocity is not None:
        base[(0x60A9, 0)] = velocity
    if acceleration is not None:
        base[(0x60AA, 0)] = acceleration
    c = Cia402Controller((_Objects("x", base), _Objects("y", base)), rig)
    c.connect()
    assert c._kv == [kv, kv] and c._ka == [ka, ka]
    assert not any(c.units_problem)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_units_refused_for_one_drive_are_written_to_neither(transport):
    """'units' with a profile whose vertical feed constant (125 per mm) no SI unit 60A8h expresses: it
    is refused, naming the drive, and nothing is written to either drive. The horizontal drive's 60A8h
    and 6092h used to be written before the vertical one was refused: a pair left half converted."""
    from lfstudio.resources import load_presets
    from lfstudio.rig.profile import rig_from_dict

    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in load_presets("rigs")[RIG_NAME].items()}
    data["vertical"]["increments_per_mm"] = 125.0
    rig = rig_from_dict("odd vertical units", data)
    emulator = start_drive_emulator(rig, transport, time_scale=0.0, seed=2, setup=({"feed": 70}, {}))
    link = None
    try:
        link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=0.5)
        c = link.controller
        c.connect()
        assert c.units_problem[0] and c.units_problem[1]        # x counts mm; y's 60A8h says 0.01 mm
        del emulator.pair.journal[:]
        with pytest.raises(UnitsMismatch) as exc:
            c.write_units()
        assert emulator.pair.journal == []                       # not one write, to either drive
        assert "drive y (vertical)" in str(exc.value) and "125" in str(exc.value)
        assert "nothing was written" in str(exc.value)
    finally:
        if link is not None:
            link.close()
        emulator.close()
