"""Deadlines and STOP on the CiA 402 drive links (issue 42): every exchange has a deadline for the
whole answer (a hostile peer on a real TCP socket that trickles its answer or announces 65 535
bytes), and STOP reaches every drive on its own path at once, whatever another link does (one
drive's link stalled; the quick stop is observed arriving at the other drive's emulator while the
stalled exchange is still stalled). Both transports, real protocol stacks at both ends."""

from __future__ import annotations

import logging
import socket
import struct
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from lfstudio.rig.cia402 import QUICK_STOP, DriveNotAnswering
from lfstudio.rig.dryve import DryveLink, decode_request
from lfstudio.rig.motion import RigState
from lfstudio.rig.profile import load_rig
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
HANG_GUARD_S = 5.0                  # only against a hang: the deadlines under test are 0.5 s


class HostilePeer:
    """A Modbus TCP peer on 127.0.0.1 that reads each request and answers it byte by byte, one
    byte every ``interval_s`` (``huge``: after a header whose length field says 65 535), until
    closed."""

    def __init__(self, interval_s: float = 0.25, huge: bool = False):
        self.interval_s = interval_s
        self.huge = huge
        self.closing = threading.Event()
        self.requests = 0
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        self.listener.settimeout(0.1)
        while not self.closing.is_set():
            try:
                conn, _ = self.listener.accept()
            except OSError:
                continue
            threading.Thread(target=self._answer, args=(conn,), daemon=True).start()

    def _answer(self, conn: socket.socket) -> None:
        with conn:
            try:
                request = conn.recv(64)
                transaction, write, index, sub, size, _ = decode_request(request)
                self.requests += 1
                if self.huge:       # the header at once, then the 65 535 bytes it announces, trickling
                    conn.sendall(struct.pack(">HHH", transaction, 0, 65535))
                    answer = b"\x00" * 65535
                else:               # a well-formed answer to the read: status word 0237h
                    body = bytes([0, 0x2B, 0x0D, 0, 0, 0, index >> 8, index & 0xFF, sub, 0, 0, 0, size])
                    answer = struct.pack(">HHH", transaction, 0, len(body) + size) + body + (0x0237).to_bytes(size, "little")
                for byte in answer:
                    if self.closing.wait(self.interval_s):
                        return
                    conn.sendall(bytes([byte]))
            except OSError:
                return

    def close(self) -> None:
        self.closing.set()
        self.listener.close()
        self.thread.join(5)


@pytest.fixture
def peer():
    peers: list[HostilePeer] = []

    def make(**kw) -> HostilePeer:
        peers.append(HostilePeer(**kw))
        return peers[-1]

    yield make
    for p in peers:
        p.close()


@pytest.mark.parametrize("huge", [False, True], ids=["trickle", "length-65535"])
def test_a_trickling_or_huge_answer_ends_within_the_links_deadline(peer, huge):
    hostile = peer(huge=huge)
    link = DryveLink("127.0.0.1", hostile.port, timeout_s=0.5)
    pool = ThreadPoolExecutor(1)
    try:
        failure = pool.submit(link.read, 0x6041, 0, 2, False).exception(timeout=HANG_GUARD_S)
    finally:
        hostile.close()                               # the peer goes: nothing can hang past this test
        pool.shutdown()
        link.close()
    assert isinstance(failure, DriveNotAnswering)
    text = str(failure)
    assert f"127.0.0.1:{hostile.port}" in text and "\n" not in text
    if huge:        # refused at once: no gateway answer is longer than 17 bytes
        assert "length field says 65535 bytes" in text
    else:           # a deadline for the whole answer, not for each recv
        assert "no whole answer within 0.5 s" in text and "bytes of it arrived" in text
    assert link._sock is None                         # the link is closed: the next access connects again


@pytest.fixture
def drives():
    rig = load_rig(RIG_NAME)
    opened: list = []

    def start(transport: str, time_scale: float = 0.05, timeout_s: float = 0.5):
        emulator = start_drive_emulator(rig, transport, time_scale=time_scale)
        opened.append(emulator)
        link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=timeout_s)
        opened.insert(0, link)
        link.controller.connect()
        return emulator, link.controller

    yield start
    for thing in opened:
        thing.close()


def test_a_hostile_peer_marks_the_link_lost_in_one_line_stating_the_position(drives, peer):
    emulator, c = drives("modbus", time_scale=0)
    c.home()
    hostile = peer()
    link = c.links[0]
    assert isinstance(link, DryveLink)
    link.close()
    link.host, link.port, link.address = "127.0.0.1", hostile.port, f"127.0.0.1:{hostile.port}"
    pool = ThreadPoolExecutor(1)
    try:
        c._last_t = 0.0                               # the next status reads the drives
        st = pool.submit(c.status).result(timeout=HANG_GUARD_S)
    finally:
        hostile.close()
        pool.shutdown()
    assert st.state is RigState.DISCONNECTED and st.position_mm is None
    assert link.address in st.message and "no whole answer within 0.5 s" in st.message
    assert "position is unknown until it answers (last read at (0.000, 0.000) mm" in st.message
    assert "\n" not in st.message and not c.connected


class _QuickStopSeen(list):
    """An emulated drive's journal of writes that sets ``event`` when the quick stop arrives and
    records then whether the stalled drive's quick stop had already failed."""

    def __init__(self, failed_x: list[str]):
        super().__init__()
        self.event = threading.Event()
        self.failed_x = failed_x
        self.x_failed_first: list[bool] = []

    def append(self, item) -> None:
        super().append(item)
        _, index, _, value = item
        if index == 0x6040 and value == QUICK_STOP and not self.event.is_set():
            self.x_failed_first.append(bool(self.failed_x))
            self.event.set()


class _Failures(logging.Handler):
    def __init__(self, failed_x: list[str]):
        super().__init__()
        self.failed_x = failed_x

    def emit(self, record: logging.LogRecord) -> None:
        if "quick stop of drive x" in record.getMessage():
            self.failed_x.append(record.getMessage())


@pytest.mark.parametrize("transport", ["modbus", "canopen"])
def test_stop_reaches_the_other_drive_at_once_while_one_link_is_stalled(drives, transport):
    emulator, c = drives(transport, time_scale=0.2, timeout_s=30.0)   # the stall outlasts the test's wait
    if transport == "canopen":
        for link in c.links:
            link.node.sdo.RESPONSE_TIMEOUT = 30.0
    emulator.time_scale = 0.0                         # homed at once, then moving in 1/5 of real time
    c.home()
    emulator.time_scale = 0.2
    failed_x: list[str] = []
    handler = _Failures(failed_x)
    logging.getLogger("lfstudio.rig.cia402").addHandler(handler)
    seen = _QuickStopSeen(failed_x)
    emulator.pair.axes[1].journal = seen
    outcome: list[BaseException] = []

    def move() -> None:
        try:
            c.move_to(4000, 400)
        except BaseException as exc:  # noqa: BLE001
            outcome.append(exc)

    mover = threading.Thread(target=move)
    stopper = threading.Thread(target=c.stop)
    try:
        mover.start()
        while emulator.true_position_mm()[0] < 50 and mover.is_alive():
            emulator.pair.axes[0].true_position()     # polling the emulator until the axes are under way
        assert mover.is_alive()
        emulator.pair.axes[0].inject("lost_connection")   # drive x's link stalls: nothing comes back
        stopper.start()
        assert seen.event.wait(HANG_GUARD_S), "the quick stop never reached drive y"
        # it reached y before x's stalled exchange and x's own quick stop ended (30 s deadline)
        assert seen.x_failed_first == [False]
        # and STOP returned (the window calls it on its own thread) while x's link is still stalled
        stopper.join(HANG_GUARD_S)
        assert not stopper.is_alive() and not emulator.pair.axes[0].answering
    finally:
        emulator.pair.axes[0].clear_faults()
        if transport == "canopen":          # the request x missed while off the bus is never answered
            c.links[0].node.sdo.interrupt()
        stopper.join(10) if stopper.ident else None
        mover.join(30)
        logging.getLogger("lfstudio.rig.cia402").removeHandler(handler)
    assert not mover.is_alive() and len(outcome) == 1
    x, y = emulator.true_position_mm()
    assert y < 400                                    # drive y did not finish the move
    # nor did x: a quick stop its stalled link never delivered is sent again once it answers
    assert x < 4000


def test_ctrl_c_of_rig_move_reaches_the_other_drive_while_one_link_is_stalled():
    """``lfstudio rig … move`` in its own process; drive x's link stalls (its deadline: 30 s), then
    Ctrl+C: the quick stop reaches drive y at once, not after x's exchange (it used to wait behind
    x's, 18–21 s with a trickling peer)."""
    import os
    import signal
    import subprocess
    import sys

    from tests.conftest import REPO_ROOT
    from tests.faults.test_kill import wait_until

    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, "modbus", time_scale=0.1)
    seen = _QuickStopSeen([])
    emulator.pair.axes[1].journal = seen
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "rig", "--port", emulator.word, "--rig-profile",
                             RIG_NAME, "--timeout-s", "30", "home", "move", "3500", "450"], cwd=REPO_ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: any(index == 0x607A and value == 45000 for _, index, _, value in list(seen))
                   or proc.poll() is not None, 60, "the move sent to drive y")
        wait_until(lambda: emulator.true_position_mm()[0] > 20 or proc.poll() is not None, 60, "the move under way")
        assert proc.poll() is None, proc.communicate()
        emulator.pair.axes[0].inject("lost_connection")   # drive x's link stalls
        proc.send_signal(signal.SIGINT)
        assert seen.event.wait(HANG_GUARD_S), "Ctrl+C: the quick stop never reached drive y"
        assert not emulator.pair.axes[0].answering      # ... while x's link was still stalled
        emulator.pair.axes[0].clear_faults()
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        emulator.close()
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert "Ctrl+C: stopping the rig" in err
    assert emulator.true_position_mm()[1] < 450


def test_a_canopen_node_trickling_a_segmented_answer_ends_within_the_links_deadline():
    """A node on the (virtual) CAN bus that answers an upload with a segmented transfer of 65 535 bytes
    and each segment within python-canopen's per-response timeout, 0.25 s apart: the whole transfer has
    the link's deadline (it used to go on for 65 535 / 7 segments)."""
    import os

    import can

    from lfstudio.rig.canopen_link import CanopenLink

    channel = f"lfstudio-hostile-{os.getpid()}"
    node = 5
    closing = threading.Event()
    segments = []
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)

    def serve() -> None:
        while not closing.is_set():
            msg = bus.recv(0.05)
            if msg is None or msg.arbitration_id != 0x600 + node:
                continue
            cmd = msg.data[0]
            if cmd & 0xE0 == 0x40:                    # initiate upload: segmented, 65 535 bytes announced
                answer = bytes([0x41, msg.data[1], msg.data[2], msg.data[3]]) + (65535).to_bytes(4, "little")
            elif cmd & 0xE0 == 0x60:                  # upload segment: 7 more bytes, never the last
                if closing.wait(0.25):
                    return
                segments.append(cmd)
                answer = bytes([cmd & 0x10]) + b"\x00" * 7
            else:
                continue
            bus.send(can.Message(arbitration_id=0x580 + node, data=answer, is_extended_id=False))

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    link = CanopenLink(f"virtual-{channel}", node, timeout_s=0.5)
    pool = ThreadPoolExecutor(1)
    try:
        link.open()
        failure = pool.submit(link.read, 0x6041, 0, 2, False).exception(timeout=HANG_GUARD_S)
    finally:
        closing.set()
        pool.shutdown()
        link.close()
        server.join(5)
        bus.shutdown()
    assert isinstance(failure, DriveNotAnswering), failure
    assert f"virtual-{channel} node {node}" in str(failure) and "no whole answer within 0.5 s" in str(failure)
    assert 0 < len(segments) < 10                    # it was answering, segment by segment


@pytest.mark.parametrize("transport", ["modbus", "canopen"])
def test_closing_after_a_lost_drive_waits_for_the_other_drives_quick_stop(drives, transport):
    """Drive x's link is lost mid-move: the quick stop for drive y goes out on its own thread. The
    command then fails and the CLI closes the rig and exits: disconnect() must not close the links
    (nor the process end) before that quick stop is out. It was sent from a thread that started the
    quick stop threads later, unknown to disconnect(): here that thread is held until the links are
    closed, as a busy machine may hold it, and drive y went on alone."""
    emulator, c = drives(transport, time_scale=1.0, timeout_s=0.5)   # real time: y needs 4 s for 400 mm
    emulator.time_scale = 0.0
    c.home()
    emulator.time_scale = 1.0
    seen = _QuickStopSeen([])
    emulator.pair.axes[1].journal = seen
    released = threading.Event()
    real_quick_stop_all = c._quick_stop_all

    def quick_stop_all(*args, **kwargs):
        if threading.current_thread().name == "quick-stop-on-loss":
            released.wait(HANG_GUARD_S)               # the old on-loss thread, held until the links are closed
        return real_quick_stop_all(*args, **kwargs)

    c._quick_stop_all = quick_stop_all
    y_link = c.links[1]
    real_close = y_link.close
    out_at_close: list[bool] = []

    def close() -> None:
        out_at_close.append(seen.event.is_set())
        released.set()
        real_close()

    y_link.close = close
    outcome: list[BaseException] = []

    def move() -> None:
        try:
            c.move_to(4000, 400)
        except BaseException as exc:  # noqa: BLE001
            outcome.append(exc)

    mover = threading.Thread(target=move)
    mover.start()
    while emulator.true_position_mm()[0] < 50 and mover.is_alive():
        emulator.pair.axes[0].true_position()         # polling the emulator until the axes are under way
    emulator.pair.axes[0].inject("lost_connection")   # drive x stops answering mid-move
    mover.join(HANG_GUARD_S * 4)
    assert not mover.is_alive() and len(outcome) == 1 and isinstance(outcome[0], DriveNotAnswering), outcome
    try:
        c.disconnect()                                # what the CLI does next, before it exits
    finally:
        released.set()
        emulator.pair.axes[0].clear_faults()
    assert out_at_close == [True]                     # drive y had its quick stop before its link closed
