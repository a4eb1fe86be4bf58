"""The window's STOP never waits on a drive link (issue 42's leftover: it could hold the GUI thread
for up to 0.25 s behind a stalled link). Two emulated CiA 402 drives (Modbus TCP server / CANopen
nodes, real protocol stacks), the real controller behind a real worker and QtDevice, the window's
own STOP (``MainWindow.stop_rig``, the toolbar button and Esc). Drive x's link stalls; the driver's
stop is made to wait for every drive's quick stop (``STOP_WAIT_S = None``), so a GUI thread that
waits on it cannot come back before x's quick stop has ended one way or the other. The test checks
the order of events, not a duration: STOP returned while x's quick stop was neither delivered nor
failed, and drive y got its quick stop anyway."""

from __future__ import annotations

import logging
import threading

import pytest

from lfstudio.gui.app import create_window
from lfstudio.gui.devices import QtDevice, wait_for_closing
from lfstudio.rig import cia402
from lfstudio.rig.cia402 import QUICK_STOP
from lfstudio.rig.profile import load_rig
from lfstudio.rig.worker import DeviceWorker
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
HANG_GUARD_S = 10.0        # only against a hang (old code): the stall ends here, so the test can end


class _XFailures(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if "quick stop of drive x" in record.getMessage():
            self.lines.append(record.getMessage())


def _quick_stops(journal: list, axis: str) -> int:
    return sum(1 for name, index, _, value in list(journal)
               if name == axis and index == 0x6040 and value == QUICK_STOP)


@pytest.mark.parametrize("transport", ["modbus", "canopen"])
def test_the_windows_stop_returns_while_a_drive_link_is_stalled(qtbot, monkeypatch, transport):
    monkeypatch.setattr(cia402, "STOP_WAIT_S", None)     # the driver's stop waits for both quick stops
    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, transport, time_scale=0)
    link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=60.0)
    c = link.controller
    c.connect()
    if transport == "canopen":
        for node_link in c.links:
            node_link.node.sdo.RESPONSE_TIMEOUT = 60.0
    c.home()
    device = QtDevice(DeviceWorker(c, name="rig"))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.devices["rig"] = device
    journal = emulator.pair.journal
    failures = _XFailures()
    logging.getLogger("lfstudio.rig.cia402").addHandler(failures)
    x = emulator.pair.axes[0]

    def end_the_stall() -> None:
        x.clear_faults()
        if transport == "canopen":          # the request x missed while off the bus is never answered
            c.links[0].node.sdo.interrupt()

    guard = threading.Timer(HANG_GUARD_S, end_the_stall)
    try:
        x.inject("lost_connection")                     # drive x's link stalls: nothing comes back
        guard.start()
        window.stop_rig()                               # on the GUI thread, as the button does
        x_done_at_return = bool(failures.lines) or _quick_stops(journal, x.name) > 0
        stalled_at_return = not x.answering
        qtbot.waitUntil(lambda: _quick_stops(journal, emulator.pair.axes[1].name) > 0, timeout=10000)
        assert "Rig: STOP" in window.statusBar().currentMessage()
    finally:
        guard.cancel()
        end_the_stall()
        logging.getLogger("lfstudio.rig.cia402").removeHandler(failures)
        window.state.devices.pop("rig", None)
        device.close(disconnect=True, timeout_s=30.0)
        wait_for_closing(30.0)                          # the worker disconnected the driver
        link.close(disconnect=False)
        emulator.close()
    # STOP came back to the GUI thread before x's quick stop ended (delivered or failed)
    assert stalled_at_return and not x_done_at_return
