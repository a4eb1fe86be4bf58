"""How long the GUI thread (or the caller) is held by three actions that used to wait behind another
thread (the robust session): the window's STOP with a drive link stalled, ``StatusServer.close()``
while the page's loop is held up, and a step of the HDR radiance dialog's exposure slider.

    ./.venv/bin/python benchmarks/gui_never_waits.py [--trials 10] [--steps 30] [--hold-s 1]
        [--only stop,close,radiance] [--width 2000]

- **stop**: two emulated dryve D1 drives (Modbus TCP server on 127.0.0.1, the real controller behind
  its worker and QtDevice), drive x's link stalled (its emulator answers nothing; link deadline 3 s);
  the time ``MainWindow.stop_rig()`` takes on the GUI thread (it was STOP_WAIT_S, 0.25 s).
- **close**: a status page whose loop is held up building a page (the board's lock held for
  ``--hold-s``); the time ``StatusServer.close()`` takes for its caller (it was up to 10 s).
- **radiance**: the dialog with a ``--width`` × 2/3 float radiance; each slider step's GUI-thread
  slices (``_expose`` and the picture put on the screen), median and max over ``--steps`` steps (it
  was the whole exposure, 92–302 ms at 2000 px under load).

Prints the figures and the load of the machine; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from _measure import load_text  # noqa: E402
from _qt import spin_until  # noqa: E402


def _figure(name: str, ms: list[float], unit: str = "") -> str:
    return f"{name}: median {statistics.median(ms):8.2f} ms, max {max(ms):8.2f} ms ({len(ms)} {unit or 'trials'})"


def stop_figures(trials: int) -> None:
    from lfstudio.gui.app import create_window
    from lfstudio.gui.devices import QtDevice
    from lfstudio.rig.profile import load_rig
    from lfstudio.rig.worker import DeviceWorker
    from lfstudio.studio.devices import open_rig
    from lfstudio.studio.simulated import start_drive_emulator

    rig = load_rig("dryve D1 gantry 4 m x 0.5 m")
    emulator = start_drive_emulator(rig, "modbus", time_scale=0)
    link = open_rig(emulator.word, rig, doing="benchmark", lock=False, connect=False, timeout_s=3.0)
    c = link.controller
    c.connect()
    c.home()
    device = QtDevice(DeviceWorker(c, name="rig"))
    window = create_window(simulated=True)
    window.state.devices["rig"] = device
    x = emulator.pair.axes[0]
    ms = []
    try:
        for _ in range(trials):
            x.inject("lost_connection")
            t0 = time.perf_counter()
            window.stop_rig()
            ms.append((time.perf_counter() - t0) * 1000)
            x.clear_faults()
            spin_until(lambda: not [t for t in threading.enumerate() if t.name.startswith(("stop-rig", "quick-stop"))],
                       15)
    finally:
        window.state.devices.pop("rig", None)
        device.close(disconnect=True, timeout_s=10)
        from lfstudio.gui.devices import wait_for_closing

        wait_for_closing(15)
        link.close()
        emulator.close()
        window.close()
    print(_figure("window STOP, drive x's link stalled, GUI thread", ms), flush=True)


def close_figures(trials: int, hold_s: float) -> None:
    from lfstudio.scan.status_http import StatusBoard, StatusServer

    ms = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(trials):
            board = StatusBoard(Path(tmp) / "day", total=3)
            lock = board._lock
            server = StatusServer("127.0.0.1:0")
            server.start(board)
            lock.acquire()
            client = socket.create_connection(("127.0.0.1", server.port), timeout=30)
            try:
                client.sendall(b"GET / HTTP/1.0\r\n\r\n")
                while server.requests == 0:      # the loop has the request: it now waits for the board
                    time.sleep(0.001)
                release = threading.Timer(hold_s, lock.release)
                release.start()
                t0 = time.perf_counter()
                server.close()
                ms.append((time.perf_counter() - t0) * 1000)
                release.join()
                server.wait_closed(30)
            finally:
                client.close()
    print(_figure(f"StatusServer.close(), its loop held up {hold_s:g} s, caller", ms), flush=True)


def radiance_figures(steps: int, width: int) -> None:
    from types import SimpleNamespace

    import cv2
    import numpy as np

    from lfstudio.dataset import Dataset
    from lfstudio.gui.views import radiance as rv

    with tempfile.TemporaryDirectory() as tmp:
        ds = Dataset.create(Path(tmp) / "ds", camera={"name": "c", "sensor_px": [8, 8], "pixel_pitch_um": 4.0},
                            lens={"name": "l", "focal_length_mm": 50.0},
                            grid={"columns": 1, "rows": 1, "spacing_mm": [4.0, 6.0], "order": "row-meander"})
        dialog = rv.RadianceDialog(SimpleNamespace(dataset=ds), view=(0, 0))
        dialog.resize(1040, 820)
        dialog.show()
        spin_until(lambda: "no merged radiance" in dialog.caption.text(), 30)
        height = width * 2 // 3
        rad = (np.random.default_rng(1).random((height, width, 3), dtype=np.float32) * 4).astype(np.float32)
        pw = min(rv.PREVIEW_PX, width)
        dialog._data = {"radiance": rad, "preview": cv2.resize(rad, (pw, max(1, height * pw // width)),
                                                               interpolation=cv2.INTER_AREA),
                        "key": 1.0, "figures": {"file": "hdr/bench.exr", "size": (width, height), "min": 0.0,
                                                "median": 2.0, "max": 4.0, "clipped_merged": None}}
        slices: list[float] = []
        show = dialog._show_pictures

        def timed(items) -> None:
            t0 = time.perf_counter()
            show(items)
            slices.append((time.perf_counter() - t0) * 1000)

        dialog._pictures._handler = timed
        for i in range(steps):
            dialog.slider.blockSignals(True)
            dialog.slider.setValue(i % 60 - 30)
            dialog.slider.blockSignals(False)
            t0 = time.perf_counter()
            dialog._expose()
            slices.append((time.perf_counter() - t0) * 1000)
            spin_until(lambda: f"{dialog.ev:+.1f} EV" in dialog.caption.text(), 30)
        dialog.close()
    print(_figure(f"radiance slider, {width} x {height} px, GUI-thread slices", slices,
                  f"slices, {steps} steps"), flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--hold-s", type=float, default=1.0)
    p.add_argument("--width", type=int, default=2000)
    p.add_argument("--only", default="stop,close,radiance")
    args = p.parse_args()
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])  # noqa: F841 (kept while measuring)
    only = set(args.only.split(","))
    print(load_text(), flush=True)
    if "stop" in only:
        stop_figures(args.trials)
    if "close" in only:
        close_figures(args.trials, args.hold_s)
    if "radiance" in only:
        radiance_figures(args.steps, args.width)
    return 0


if __name__ == "__main__":
    sys.exit(main())
