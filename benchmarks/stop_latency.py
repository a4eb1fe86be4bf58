"""STOP to quick stop, per drive, with the other drive's link stalled (issue 42: target <= 50 ms).

    ./.venv/bin/python benchmarks/stop_latency.py [--trials 10] [--transport modbus|canopen|both]

Each trial: two emulated CiA 402 drives (the dryve D1 preset) behind the real stacks (Modbus TCP:
our gateway telegrams to pymodbus' server on 127.0.0.1; CANopen: python-canopen SDO to LocalNodes
on python-can's virtual bus), homed, a long move under way; then one drive's link stalls (the
emulator holds every request unanswered, as a drive that lost its network does) and, once the move's
poll is stuck in that drive's exchange, STOP (``Cia402Controller.stop``) is called. The figure is
the time from the call to the quick-stop control word (6040h = 0Bh) arriving in the *other* drive's
emulator (its journal of writes, stamped there). Also without any stall. The stalled drive's own
quick stop cannot arrive (it answers nothing) and is not timed; its link deadline here is 3 s.

Prints median / max per transport, stalled drive and timed drive, with the load of the machine.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _measure import load_text  # noqa: E402

from lfstudio.rig.cia402 import QUICK_STOP  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.studio.devices import open_rig  # noqa: E402
from lfstudio.studio.simulated import start_drive_emulator  # noqa: E402

RIG = "dryve D1 gantry 4 m x 0.5 m"


class Stamp(list):
    """A drive emulator's journal of writes: stamps the first quick stop's arrival."""

    def __init__(self):
        super().__init__()
        self.at: float | None = None
        self.event = threading.Event()

    def append(self, item) -> None:
        super().append(item)
        if item[1] == 0x6040 and item[3] == QUICK_STOP and self.at is None:
            self.at = time.perf_counter()
            self.event.set()


def trial(transport: str, stalled: int | None) -> dict[int, float]:
    """Seconds from STOP to the quick stop at each drive that is not stalled."""
    rig = load_rig(RIG)
    emulator = start_drive_emulator(rig, transport, time_scale=0.2)
    link = open_rig(emulator.word, rig, doing="benchmark", lock=False, connect=False, timeout_s=3.0)
    c = link.controller
    try:
        c.connect()
        if transport == "canopen":
            for lk in c.links:
                lk.node.sdo.RESPONSE_TIMEOUT = 3.0
        c.home()
        mover = threading.Thread(target=lambda: _quietly(c.move_to, 3500, 450), daemon=True)
        mover.start()
        while emulator.true_position_mm()[0] < 20 and mover.is_alive():
            time.sleep(0.002)
        stamps = [Stamp(), Stamp()]
        for axis, stamp in zip(emulator.pair.axes, stamps):
            axis.journal = stamp
        if stalled is not None:
            emulator.pair.axes[stalled].inject("lost_connection")
            time.sleep(0.1)                  # the move's poll is now stuck in the stalled drive's exchange
        stopper = threading.Thread(target=c.stop, daemon=True)
        t0 = time.perf_counter()
        stopper.start()
        out: dict[int, float] = {}
        for i, stamp in enumerate(stamps):
            if i != stalled and stamp.event.wait(10) and stamp.at is not None:
                out[i] = stamp.at - t0
        if stalled is not None:
            emulator.pair.axes[stalled].clear_faults()
        stopper.join(15)
        mover.join(30)
        return out
    finally:
        link.close()
        emulator.close()


def _quietly(fn, *args) -> None:
    try:
        fn(*args)
    except Exception:  # noqa: BLE001 - STOP ends the move; that is the point
        pass


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per case (default 10)")
    ap.add_argument("--transport", choices=["modbus", "canopen", "both"], default="both")
    args = ap.parse_args()
    import logging
    logging.disable(logging.ERROR)          # the stalled drive's failed quick stop (and SDO abort) is expected
    transports = ["modbus", "canopen"] if args.transport == "both" else [args.transport]
    print(f"STOP -> quick stop (6040h = 0Bh) at the drive's emulator; {args.trials} trials per case; {load_text()}")
    for transport in transports:
        for stalled in (None, 0, 1):
            samples: dict[int, list[float]] = {0: [], 1: []}
            missed = 0
            for _ in range(args.trials):
                got = trial(transport, stalled)
                for i in (0, 1):
                    if i == stalled:
                        continue
                    if i in got:
                        samples[i].append(got[i])
                    else:
                        missed += 1
            case = "no stall" if stalled is None else f"drive {'xy'[stalled]} stalled"
            for i in (0, 1):
                if i == stalled or not samples[i]:
                    continue
                s = samples[i]
                print(f"{transport:<8} {case:<16} drive {'xy'[i]}: median {statistics.median(s) * 1e3:6.1f} ms, "
                      f"max {max(s) * 1e3:6.1f} ms ({len(s)} trials)", flush=True)
            if missed:
                print(f"{transport:<8} {case:<16} {missed} quick stops never arrived", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
