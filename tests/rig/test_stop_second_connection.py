"""STOP's quick stop on a dryve D1 link that is busy (an exchange in flight): the second TCP
connection is real, checked against the emulated gateway (a real asyncio Modbus TCP server), and a
gateway that serves one client only (refuses the second connection, or takes it and never answers)
still gets the quick stop, on the link's own connection, as soon as that is free.

"An exchange in flight" is the link's own lock held by the test: exactly what a stalled exchange
holds. The order of events is checked (the quick stop arrives while the lock is held / only once
it is released), never a duration."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest

from lfstudio.rig.cia402 import CONTROL, QUICK_STOP, SIZES
from lfstudio.rig.dryve import DryveLink
from lfstudio.rig.profile import load_rig
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
HANG_GUARD_S = 20.0


@pytest.fixture
def pair():
    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, "modbus", time_scale=0)
    link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=30.0)
    link.controller.connect()
    link.controller.home()
    pool = ThreadPoolExecutor(1)
    yield emulator, link.controller, pool
    pool.shutdown()
    link.close()
    emulator.close()


def _quick_stops(emulator, axis: int) -> int:
    name = emulator.pair.axes[axis].name
    return sum(1 for n, index, _, value in list(emulator.pair.journal)
               if n == name and index == CONTROL and value == QUICK_STOP)


def test_the_quick_stop_goes_out_on_a_second_connection_while_the_link_is_busy(pair):
    emulator, c, pool = pair
    x = c.links[0]
    assert isinstance(x, DryveLink)
    seen = emulator.servers[0].clients_seen
    x._lock.acquire()                                  # an exchange in flight on the link's connection
    try:
        pool.submit(x.write_now, CONTROL, 0, QUICK_STOP, *SIZES[CONTROL]).result(timeout=HANG_GUARD_S)
        # delivered while the link's own connection is still busy: it came on a connection of its own
        assert _quick_stops(emulator, 0) == 1
        assert emulator.servers[0].clients_seen == seen + 1
    finally:
        x._lock.release()


@pytest.mark.parametrize("extra", ["refuse", "ignore"])
def test_a_gateway_serving_one_client_gets_the_quick_stop_once_the_link_is_free(pair, extra):
    emulator, c, pool = pair
    x = c.links[0]
    assert isinstance(x, DryveLink)
    server = emulator.servers[0]
    server.extra_clients = extra
    seen = server.clients_seen
    x._lock.acquire()
    try:
        sent = pool.submit(x.write_now, CONTROL, 0, QUICK_STOP, *SIZES[CONTROL])
        while server.clients_seen == seen and not sent.done():
            emulator.pair.axes[0].true_position()     # waiting until the gateway saw the second connection
        assert _quick_stops(emulator, 0) == 0 and not sent.done()
    finally:
        x._lock.release()                              # the exchange in flight ends
    sent.result(timeout=HANG_GUARD_S)                  # no error: it went out on the link's own connection
    assert _quick_stops(emulator, 0) == 1
