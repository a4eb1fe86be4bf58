"""A status report answered late is dated by the question it answers, not by the next one.

The driver asks ``?`` again after 0.5 s without a report. If the report to the first ``?`` then
comes, the report to the second is still on its way when the next query asks: the next query
must not take it for its own answer (it was made before that question was sent, so a short round
trip would date it wrongly, and a fly scan's recorded position with it).

A pty peer between GrblController and our GRBL simulator (lfstudio/sim/grbl_controller.py) holds
the simulator's reports: the first until the driver asks again, the second until the driver's next
``?``. Each report it passes is tagged (its first coordinate set to -10 - k for the k-th report) so
the test knows which report the driver returned, and the peer records when it forwarded each ``?``
and when it got each report from the simulator (the report was made in between).
"""

from __future__ import annotations

import os
import re
import select
import threading
import time
import tty

import pytest

from lfstudio.rig.grbl import GrblController
from lfstudio.sim.grbl_controller import GrblSimulator
from tests.rig.test_grbl_protocol import RIG, SETTINGS, Backend

COORD = re.compile(rb"([MW]Pos:)(-?[0-9.]+)")


class LateAnswers:
    """The pty peer (see the module docstring). Pass-through until :meth:`arm`."""

    def __init__(self, sim_port: str, share_first: bool = False):
        #: share_first: the second '?' shares the first's report (as GRBL answers all the '?' it holds
        #: with one report): the simulator's report to it is dropped
        self.share_first = share_first
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.sim = os.open(sim_port, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.sim)
        self.armed = False
        self.questions: list[float] = []          # when each '?' since arm() went to the simulator
        self.reports: list[float] = []            # when each report since arm() came from it
        self.held: list[bytes] = []
        self.second_held = threading.Event()
        self._lock = threading.Lock()
        self._running = True
        self._from_sim = bytearray()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def arm(self) -> None:
        with self._lock:
            self.armed = True

    def close(self) -> None:
        self._running = False
        self._thread.join(5)
        for fd in (self.master, self.slave, self.sim):
            os.close(fd)

    def _serve(self) -> None:
        while self._running:
            ready, _, _ = select.select([self.master, self.sim], [], [], 0.05)
            if self.master in ready:
                self._from_driver(os.read(self.master, 4096))
            if self.sim in ready:
                self._from_simulator(os.read(self.sim, 4096))

    def _from_driver(self, data: bytes) -> None:
        with self._lock:
            if not self.armed:
                os.write(self.sim, data)
                return
            for byte in data:
                if byte == 0x3F:
                    self.questions.append(time.monotonic())   # recorded before the driver can read a reply
                    if len(self.questions) in (2, 3) and self.held:   # asked again: the held report comes now
                        os.write(self.master, self.held.pop(0))
                os.write(self.sim, bytes([byte]))

    def _from_simulator(self, data: bytes) -> None:
        with self._lock:
            self._from_sim += data
            while b"\n" in self._from_sim:
                line, _, rest = bytes(self._from_sim).partition(b"\n")
                self._from_sim = bytearray(rest)
                line += b"\n"
                if not (self.armed and line.startswith(b"<")):
                    os.write(self.master, line)
                    continue
                self.reports.append(time.monotonic())
                k = len(self.reports)
                line = COORD.sub(lambda m: m.group(1) + f"{-10 - k:.3f}".encode(), line, count=1)
                if k == 2 and self.share_first:
                    continue
                if k == 1 or (k == 2 and len(self.questions) < 3):
                    self.held.append(line)
                    if k == 2:
                        self.second_held.set()
                else:
                    os.write(self.master, line)


@pytest.fixture
def peer(tmp_path):
    sim = GrblSimulator(RIG, time_scale=0.1, seed=3)
    sim.start()
    assert sim.port is not None
    Backend("ours", sim).configure(SETTINGS)
    peers: list[LateAnswers] = []

    def make(**options) -> LateAnswers:
        assert sim.port is not None
        peers.append(LateAnswers(sim.port, **options))
        return peers[-1]

    yield make
    for p in peers:
        p.close()
    sim.close()


def _check_dates(late: LateAnswers, got: list, first_x: float) -> list[int]:
    """Each report returned is dated over the time its report was made; returns which reports they were."""
    which = []
    for report in got:
        k = 1 + round(abs(report.x_mm - first_x))
        asked, made = late.questions[k - 1], late.reports[k - 1]
        start, end = report.t_s - report.uncertainty_s, report.t_s + report.uncertainty_s
        assert start <= made and end >= asked, (
            f"report {k} was made between {asked:.4f} and {made:.4f} s but dated {start:.4f}-{end:.4f} s")
        which.append(k)
    return which


def test_a_report_answered_after_the_driver_asked_again_does_not_date_the_next_query(peer):
    late = peer()
    controller = GrblController(late.port, RIG, timeout_s=5.0)
    controller.connect()
    try:
        late.arm()
        first = controller.report()          # its '?' is answered only after the driver asks again
        assert len(late.questions) == 2
        assert late.second_held.wait(10), "the simulator did not answer the second '?'"
        second = controller.report()         # the report to the second '?' arrives after this '?'
    finally:
        controller.disconnect()

    assert _check_dates(late, [first, second], first.x_mm) == [1, 3]   # the second query waited for its own


def test_after_two_questions_shared_one_report_the_driver_dates_honestly_and_catches_up(peer):
    late = peer(share_first=True)
    controller = GrblController(late.port, RIG, timeout_s=5.0)
    controller.connect()
    try:
        late.arm()
        got = [controller.report() for _ in range(4)]
    finally:
        controller.disconnect()
    which = _check_dates(late, got, got[0].x_mm)
    assert which == [1, 3, 4, 5]
    # caught up: the last report is dated by its own question, after the one before it was read
    assert got[3].t_s - got[3].uncertainty_s >= got[2].t_s + got[2].uncertainty_s
