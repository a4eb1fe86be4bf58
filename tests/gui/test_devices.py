"""QtDevice: worker results, errors and snapshots arrive as signals on the GUI thread."""

from __future__ import annotations

import threading

from PySide6.QtCore import QThread

from lfstudio.errors import DeviceError
from lfstudio.gui.devices import QtDevice
from lfstudio.rig.worker import DeviceWorker


class Driver:
    def __init__(self):
        self.stopped = False

    def add(self, a, b):
        return a + b

    def fail(self):
        raise DeviceError("rig: alarm 1, hard limit")

    def status(self):
        return {"thread": threading.current_thread().name}

    def stop(self):
        self.stopped = True


def test_signals_on_gui_thread(qtbot):
    device = QtDevice(DeviceWorker(Driver(), name="d", publish_hz=50))
    gui_thread = QThread.currentThread()
    seen = {}

    def on_status(snapshot):
        seen["status_thread"] = QThread.currentThread() is gui_thread
        seen["status"] = snapshot

    device.statusChanged.connect(on_status)
    results = []
    with qtbot.waitSignal(device.callFinished, timeout=5000) as blocker:
        device.run("add", 2, 3, on_result=lambda r: results.append((r, QThread.currentThread() is gui_thread)))
    assert blocker.args == ["add", 5]
    assert results == [(5, True)]
    qtbot.waitUntil(lambda: "status" in seen, timeout=5000)
    assert seen["status_thread"] and seen["status"]["thread"] == "device-d"

    errors = []
    with qtbot.waitSignal(device.errorOccurred, timeout=5000) as blocker:
        device.run("fail", on_error=errors.append)
    assert "hard limit" in blocker.args[0] and errors == [blocker.args[0]]
    assert not device.busy

    device.stop_now()                 # dispatched on a thread of its own: the GUI thread never waits
    qtbot.waitUntil(lambda: device.driver.stopped, timeout=5000)
    device.close()


def test_an_unexpected_device_error_goes_to_the_log_not_to_stderr(capfd, caplog):
    import logging

    from lfstudio.gui.devices import error_text

    try:
        raise ZeroDivisionError("division by zero in a driver")
    except ZeroDivisionError as exc:
        with caplog.at_level(logging.ERROR, logger="lfstudio.gui.devices"):
            text = error_text(exc)
    assert text == "Unexpected error: ZeroDivisionError: division by zero in a driver"
    assert "Traceback" not in capfd.readouterr().err                # printed to the terminal before
    assert any("Traceback" in r.getMessage() and "ZeroDivisionError" in r.getMessage() for r in caplog.records)


def test_close_never_waits_on_a_driver_call_and_then_runs_after_the_disconnect(qtbot):
    """Disconnect in the Rig/Camera panel: the GUI thread waited (up to 2 s) for a driver call still
    running, e.g. on a stalled link. Now a thread of its own waits, then releases the port (``then``)."""
    gate = threading.Event()
    order: list[str] = []

    class Stuck:
        def hold(self):
            gate.wait(30)                      # a call on a stalled link
            order.append("call ended")

        def disconnect(self):
            order.append("disconnect")

        def stop(self):
            pass

    device = QtDevice(DeviceWorker(Stuck(), name="stuck", status_method=None))
    device.run("hold")
    qtbot.waitUntil(lambda: device.worker.current_command == "hold", timeout=5000)
    guard = threading.Timer(15.0, gate.set)    # only against a hang (old code)
    guard.start()
    try:
        device.close(disconnect=True, timeout_s=60.0, then=lambda: order.append("port released"))
        returned_while_stuck = not gate.is_set()
    finally:
        gate.set()
        guard.cancel()
    qtbot.waitUntil(lambda: "port released" in order, timeout=10000)
    assert returned_while_stuck
    assert order == ["call ended", "disconnect", "port released"]


def test_the_port_is_released_only_after_the_disconnect_even_past_the_close_timeout(qtbot):
    """Disconnect in the Rig/Camera panel closes with a 2 s timeout. A driver call still under way past it
    (a long move, a stalled link: bounded by the driver's own deadline) ran on while ``then`` released the
    port's lock and stopped the simulator: another process could take the port this process still had
    open and was still talking on. ``then`` must come after the driver's disconnect, however long the call
    takes. Here the call ends at its own deadline, or as soon as ``then`` runs (the old order)."""
    gate = threading.Event()
    order: list[str] = []

    class Slow:
        def hold(self):
            gate.wait(3.0)                     # the driver's own deadline
            order.append("call ended")

        def disconnect(self):
            order.append("disconnect")

        def stop(self):
            pass

    def released() -> None:
        order.append("port released")
        gate.set()

    device = QtDevice(DeviceWorker(Slow(), name="slow", status_method=None))
    device.run("hold")
    qtbot.waitUntil(lambda: device.worker.current_command == "hold", timeout=5000)
    device.close(disconnect=True, timeout_s=0.01, then=released)
    qtbot.waitUntil(lambda: "port released" in order and "disconnect" in order, timeout=15000)
    assert order == ["call ended", "disconnect", "port released"]
