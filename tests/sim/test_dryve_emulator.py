"""The drive emulator agrees with the igus dryve D1 as its operating manual V2.4 and igus' own Python
sample V1.2 (with the answers a real D1 gave, listed at the sample's end) show it: the sample's
telegram sequence replayed raw over TCP gets the sample's expected answers, byte for byte; the
manual's example telegrams likewise (issue 38)."""

from __future__ import annotations

import socket

import pytest

from lfstudio.rig.profile import load_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG = load_rig("dryve D1 gantry 4 m x 0.5 m")


@pytest.fixture
def d1():
    """``d1(**setup) -> (emulator, socket to the horizontal drive)``, the emulator's clock stopped (0)."""
    opened: list = []

    def start(time_scale: float = 0.0, **setup):
        emulator = start_drive_emulator(RIG, "modbus", time_scale=time_scale, setup=setup or None)
        opened.append(emulator)
        host, port = emulator.word.removeprefix("dryve:").split(",")[0].split(":")
        sock = socket.create_connection((host, int(port)), timeout=5)
        opened.insert(0, sock)
        return emulator, sock

    yield start
    for thing in opened:
        thing.close()


def _answer(sock: socket.socket) -> list[int]:
    head = b""
    while len(head) < 6:
        chunk = sock.recv(6 - len(head))
        assert chunk, "the emulator closed the connection"
        head += chunk
    rest = b""
    while len(rest) < int.from_bytes(head[4:6], "big"):
        rest += sock.recv(int.from_bytes(head[4:6], "big") - len(rest))
    return list(head + rest)


def send(sock: socket.socket, telegram: list[int]) -> list[int]:
    sock.sendall(bytes(telegram))
    return _answer(sock)


def wait_for(sock: socket.socket, telegram: list[int], expected: list[int], within_s: float = 60.0
             ) -> list[list[int]]:
    """The sample's ``while (sendCommand(x) != expected)`` loops: the answers until the expected one
    (polling the emulator; ``within_s`` only bounds a test that fails)."""
    import time

    seen = []
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        seen.append(send(sock, telegram))
        if seen[-1] == expected:
            return seen
    raise AssertionError(f"never answered {expected}; last {seen[-1]}")


# igus' sample V1.2 (24.01.2020), its telegrams and its "Expected response telegrams" -------------
STATUS = [0, 0, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, 96, 65, 0, 0, 0, 0, 2]
SHUTDOWN = [0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 64, 0, 0, 0, 0, 2, 6, 0]
SWITCH_ON = [0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 64, 0, 0, 0, 0, 2, 7, 0]
ENABLE = [0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 64, 0, 0, 0, 0, 2, 15, 0]
START = [0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 64, 0, 0, 0, 0, 2, 31, 0]
READ_MODE = [0, 0, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, 96, 97, 0, 0, 0, 0, 1]


def written(index_hi: int, index_lo: int, sub: int = 0) -> list[int]:
    """The sample's expected answer to a write: the header, length 13, byte count 0."""
    return [0, 0, 0, 0, 0, 13, 0, 43, 13, 1, 0, 0, index_hi, index_lo, sub, 0, 0, 0, 0]


def status_is(low: int, high: int) -> list[int]:
    return [0, 0, 0, 0, 0, 15, 0, 43, 13, 0, 0, 0, 96, 65, 0, 0, 0, 0, 2, low, high]


def mode_is(mode: int) -> list[int]:
    return [0, 0, 0, 0, 0, 14, 0, 43, 13, 0, 0, 0, 96, 97, 0, 0, 0, 0, 1, mode]


def set_mode(sock, mode: int) -> list[list[int]]:
    assert send(sock, [0, 0, 0, 0, 0, 14, 0, 43, 13, 1, 0, 0, 96, 96, 0, 0, 0, 0, 1, mode]) == written(96, 96)
    return wait_for(sock, READ_MODE, mode_is(mode))


@pytest.mark.parametrize("time_scale", [0.0, 0.02])
def test_igus_sample_v1_2_runs_against_the_emulator_with_its_expected_answers(d1, time_scale):
    """The old emulator answered 0631h (bit 4 set) and the sample hung at 'wait for shdn'; it refused
    6060h = 1 while the homing run went on (the real D1 takes it: 6061h reads 6, then 1)."""
    emulator, sock = d1(time_scale)
    assert send(sock, STATUS) == status_is(0x40, 0x06)                   # 0640h after power-up
    # init(): set_shdn, set_swon, set_op_en
    for command, low in ((SHUTDOWN, 33), (SWITCH_ON, 35), (ENABLE, 39)):
        assert send(sock, command) == written(96, 64)
        wait_for(sock, STATUS, status_is(low, 6))
    # set_mode(6), then the homing parameters in the sample's own byte counts (6092h:02 in one byte)
    set_mode(sock, 6)
    for telegram, answer in (
            ([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 146, 1, 0, 0, 0, 2, 112, 23], written(96, 146, 1)),
            ([0, 0, 0, 0, 0, 14, 0, 43, 13, 1, 0, 0, 96, 146, 2, 0, 0, 0, 1, 1], written(96, 146, 2)),
            ([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 153, 1, 0, 0, 0, 2, 112, 23], written(96, 153, 1)),
            ([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 153, 2, 0, 0, 0, 2, 112, 23], written(96, 153, 2)),
            ([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 154, 0, 0, 0, 0, 2, 80, 195], written(96, 154)),
            (START, written(96, 64)), (ENABLE, written(96, 64))):
        assert send(sock, telegram) == answer
    # set_mode(1) right after starting the homing run: taken, 6061h says 6 until the run ends
    answers = set_mode(sock, 1)
    assert all(a in (mode_is(6), mode_is(1)) for a in answers)
    if time_scale:
        assert answers[0] == mode_is(6)                                # the sample's "wait for mode"
    assert emulator.pair.axes[0].homed
    for telegram, answer in (([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 129, 0, 0, 0, 0, 2, 112, 23],
                              written(96, 129)),
                             ([0, 0, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 96, 131, 0, 0, 0, 0, 2, 80, 195],
                              written(96, 131))):
        assert send(sock, telegram) == answer
    # the loop, twice: target 0, then 6000 (one revolution at 60 mm/rev in 0.01 mm); 1627h at the target
    positions = []
    for target in ([0, 0, 0, 0], [112, 23, 0, 0], [0, 0, 0, 0]):
        assert send(sock, [0, 0, 0, 0, 0, 17, 0, 43, 13, 1, 0, 0, 96, 122, 0, 0, 0, 0, 4, *target]) == written(96, 122)
        assert send(sock, START) == written(96, 64)
        wait_for(sock, STATUS, status_is(39, 22))
        assert send(sock, ENABLE) == written(96, 64)
        positions.append(emulator.pair.axes[0].true_position())
    # 6000 units of 6000 per revolution: one revolution of the axis's 70 mm/rev
    assert positions[1] - positions[0] == pytest.approx(70.0, abs=0.02)
    assert positions[2] == pytest.approx(positions[0], abs=0.02)


def test_the_manuals_exception_answers(d1):
    """Manual V2.4 6.5.6: an exception is 9 bytes, byte 7 = ABh, byte 8 the code."""
    _, sock = d1()
    # 6100h does not exist: 02 illegal data address
    assert send(sock, [0, 9, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, 0x61, 0x00, 0, 0, 0, 0, 2]) == [0, 9, 0, 0, 0, 3, 0,
                                                                                               0xAB, 2]
    # the status word is read-only: 02; mode 9 is no mode of the drive: 03 illegal data value
    assert send(sock, [0, 1, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 0x60, 0x41, 0, 0, 0, 0, 2, 6, 0])[7:] == [0xAB, 2]
    assert send(sock, [0, 1, 0, 0, 0, 14, 0, 43, 13, 1, 0, 0, 0x60, 0x60, 0, 0, 0, 0, 1, 9])[7:] == [0xAB, 3]
    # more bytes than the object has (6060h is one byte): 03; another function code: 01 illegal function
    assert send(sock, [0, 1, 0, 0, 0, 15, 0, 43, 13, 1, 0, 0, 0x60, 0x60, 0, 0, 0, 0, 2, 1, 0])[7:] == [0xAB, 3]
    assert send(sock, [0, 1, 0, 0, 0, 6, 0, 3, 0, 0, 0, 1])[7:] == [0x83, 1]
    assert send(sock, STATUS) == status_is(0x40, 0x06)                   # the connection goes on


def test_a_read_is_answered_with_the_objects_size_whatever_byte_count_it_asked(d1):
    _, sock = d1()
    # 6064h (4 bytes) asked with 2; 6061h (1 byte) asked with 4: the old emulator answered exception 04
    answer = send(sock, [0, 5, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, 0x60, 0x64, 0, 0, 0, 0, 2])
    assert answer[:6] == [0, 5, 0, 0, 0, 17] and answer[18] == 4 and len(answer) == 23
    answer = send(sock, [0, 6, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, 0x60, 0x61, 0, 0, 0, 0, 4])
    assert answer == [0, 6, 0, 0, 0, 14, 0, 43, 13, 0, 0, 0, 0x60, 0x61, 0, 0, 0, 0, 1, 0]


def test_two_requests_in_one_tcp_segment_get_two_answers(d1):
    _, sock = d1()
    sock.sendall(bytes([0, 1, *STATUS[2:]] + [0, 2, *READ_MODE[2:]]))
    assert _answer(sock) == [0, 1, *status_is(0x40, 0x06)[2:]]
    assert _answer(sock) == [0, 2, *mode_is(0)[2:]]


def test_objects_a_d1_has_are_there(d1):
    """60A8h is read by OptovisTech/DryveD1API at every connect; 607Bh, 60FDh, 6067h and 6092h:0 are
    D1 objects the old emulator refused (exception 02)."""
    _, sock = d1()

    def read(index: int, sub: int = 0) -> list[int]:
        answer = send(sock, [0, 0, 0, 0, 0, 13, 0, 43, 13, 0, 0, 0, index >> 8, index & 0xFF, sub, 0, 0, 0, 4])
        assert answer[7] == 43, f"{index:04X}h:{sub} refused: {answer}"
        return answer[19:]

    assert read(0x60A8) == [0, 0, 0x01, 0xFB]                # metre, 10^-5: 0.01 mm (DryveD1API's default)
    assert read(0x6092, 0) == [2]
    assert int.from_bytes(bytes(read(0x6092, 1)), "little") == 7000    # 0.01 mm on a 70 mm/rev belt
    for index, sub in ((0x607B, 1), (0x607B, 2), (0x60FD, 0), (0x6067, 0), (0x6068, 0)):
        read(index, sub)


def test_bit_11_goes_down_with_the_move_it_limited():
    from lfstudio.sim.cia402_drive import AxisSetup, DriveAxis

    axis = DriveAxis(AxisSetup(100.0, 500.0, 100.0, 100.0, 300.0, 0.0, 500.0), time_scale=1e9)   # time frozen
    for cw in (6, 7, 15):
        axis.write(0x6040, 0, cw)
    axis.write(0x6060, 0, 1)
    axis.write(0x607A, 0, 90000)                        # 900 mm, beyond 607Dh's 500 mm: clamped
    axis.write(0x6040, 0, 0x1F)
    assert axis.read(0x6041, 0) & 0x0800
    axis.time_scale = 0.0                               # the move completes
    sw = axis.read(0x6041, 0)
    assert sw & 0x0400 and not sw & 0x0800


def test_the_feed_constant_changes_the_scale():
    from lfstudio.sim.cia402_drive import AxisSetup, DriveAxis

    axis = DriveAxis(AxisSetup(100.0, 500.0, 100.0, 100.0, 300.0, 0.0, 500.0, mm_per_rev=70.0), time_scale=0.0)
    start = axis.true_position()
    assert axis.read(0x6064, 0) == 0
    axis.write(0x6092, 1, 3500)                          # half the units per revolution: 0.02 mm
    for cw in (6, 7, 15):
        axis.write(0x6040, 0, cw)
    axis.write(0x6060, 0, 1)
    axis.write(0x607A, 0, 1000)
    axis.write(0x6040, 0, 0x1F)
    assert axis.read(0x6064, 0) == 1000
    assert axis.true_position() - start == pytest.approx(20.0)      # 1000 units of 0.02 mm
