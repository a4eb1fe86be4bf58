"""STOP to quick stop, per drive, with the other drive's link stalled (issue 42: target <= 50 ms).

    ./.venv/bin/python benchmarks/stop_latency.py [--trials 10] [--transport modbus|canopen|both]

Each trial: two emulated CiA 402 drives (the dryve D1 preset) behind the real stacks (Modbus TCP:
our gateway telegrams to the emulator's Modbus TCP server on 127.0.0.1; CANopen: python-canopen SDO to LocalNodes
on python-can's virtual bus), homed, a long move under way; then one drive's link stalls (the
emulator holds every request unanswered, as a drive that lost its network does) and, once the move's
poll is stuck in that drive's exchange, STOP (``Cia402Controller.stop``) is called. The figure is
the time from the call to the quick-stop control word (6040h = 0Bh) arriving in the *other* drive's
emulator (its journal of writes, stamped there). Also without any stall. The stalled drive's own
quick stop cannot arrive (it answers nothing) and is not timed; its link deadline here is 3 s.

``--cli``: the same through Ctrl+C of a real process (Modbus TCP only: the CANopen virtual bus does
not cross processes): ``lfstudio rig … home move 3500 450`` and ``lfstudio scan --camera instant``
on the emulated pair, drive x's link stalled mid-move, then SIGINT; the figure is SIGINT → quick
stop at drive y (the process's own signal handling included).

Prints median / max per transport, stalled drive and timed drive, with the load of the machine.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
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


def cli_trial(kind: str) -> float | None:
    """Seconds from SIGINT to the quick stop at drive y, drive x's link stalled; ``kind``: rig or scan."""
    rig = load_rig(RIG)
    emulator = start_drive_emulator(rig, "modbus", time_scale=0.1)
    stamps = [Stamp(), Stamp()]
    for axis, stamp in zip(emulator.pair.axes, stamps):
        axis.journal = stamp
    repo = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(repo) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with tempfile.TemporaryDirectory(prefix="lfstudio-stop-") as tmp:
        if kind == "rig":
            args = ["rig", "--port", emulator.word, "--rig-profile", RIG, "home", "move", "3500", "450"]
        else:
            args = ["scan", "--port", emulator.word, "--rig-profile", RIG, "--camera", "instant", "--home",
                    "--grid", "3x2", "--spacing-mm", "1500x200", "--out", str(Path(tmp) / "ds")]
        proc = subprocess.Popen([sys.executable, "-m", "lfstudio", *args], cwd=repo, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 60
            # under way: a target beyond 20 mm written to x, and x past 20 mm
            while proc.poll() is None and time.monotonic() < deadline and not (
                    any(i == 0x607A and v > 2000 for _, i, _, v in list(stamps[0]))
                    and emulator.true_position_mm()[0] > 20):
                time.sleep(0.005)
            if proc.poll() is not None:
                return None
            emulator.pair.axes[0].inject("lost_connection")
            time.sleep(0.1)                  # the move's poll is now stuck in x's exchange
            t0 = time.perf_counter()
            proc.send_signal(signal.SIGINT)
            got = stamps[1].event.wait(10)
            emulator.pair.axes[0].clear_faults()
            proc.wait(60)
            return stamps[1].at - t0 if got and stamps[1].at is not None else None
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
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
    ap.add_argument("--cli", action="store_true", help="Ctrl+C of 'lfstudio rig … move' and of a scan instead")
    args = ap.parse_args()
    import logging
    logging.disable(logging.ERROR)          # the stalled drive's failed quick stop (and SDO abort) is expected
    if args.cli:
        print(f"SIGINT -> quick stop at drive y, drive x's link stalled (Modbus TCP); {args.trials} trials; {load_text()}")
        for kind in ("rig", "scan"):
            got = [cli_trial(kind) for _ in range(args.trials)]
            s = [g for g in got if g is not None]
            label = "lfstudio rig … move" if kind == "rig" else "lfstudio scan"
            if s:
                print(f"{label:<20} median {statistics.median(s) * 1e3:6.1f} ms, max {max(s) * 1e3:6.1f} ms "
                      f"({len(s)} trials)" + (f", {len(got) - len(s)} without a figure" if len(s) < len(got) else ""),
                      flush=True)
            else:
                print(f"{label:<20} no figure ({len(got)} trials)", flush=True)
        return 0
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
