"""Rig command latency and status rate through the pseudo-terminal (driver <-> simulated GRBL).

    ./.venv/bin/python benchmarks/rig_latency.py [--n 500] [--seconds 2]
    ./.venv/bin/python benchmarks/rig_latency.py --firmware [--n 200] [--speedup 10]

Prints median / p95 round-trip times of a G-code line (send, wait for ``ok``), of a ``?`` status
query (send, wait for the report), and of a complete ``move_to`` on an instant simulator
(time_scale 0: protocol overhead only), plus the sustained status-report rate and its headroom over
the driver's 20 Hz polling while waiting for a move.

``--firmware``: the same round trips against the real GRBL 1.1h firmware (its official simulator,
built and bridged to a pty by ``tests/grbl_firmware.py``, as the tests do), and instead of the
instant move a 100 mm move at the firmware's default rates ($110 = 500 mm/min: 12.8 s of machine
time) at ``--speedup`` x real time, with the wall and CPU time it took.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.studio.devices import open_rig  # noqa: E402


def stats_ms(samples: list[float]) -> tuple[float, float]:
    s = sorted(samples)
    return statistics.median(s) * 1e3, s[min(len(s) - 1, int(0.95 * len(s)))] * 1e3


def timed(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500, help="round trips per figure (default 500)")
    ap.add_argument("--seconds", type=float, default=2.0, help="duration of the status-rate run (default 2)")
    ap.add_argument("--firmware", action="store_true", help="against the real GRBL 1.1h firmware simulator")
    ap.add_argument("--speedup", type=float, default=10.0, help="firmware simulator speed (default 10x)")
    args = ap.parse_args()
    if args.firmware:
        return firmware(args)

    link = open_rig("sim", load_rig(), time_scale=0.0)
    controller, sim = link.controller, link.simulator
    try:
        controller.home()
        line = stats_ms(timed(lambda: controller._command("G90"), args.n))
        query = stats_ms(timed(controller._query_status, args.n))
        targets = iter([(10.0 + (i % 2) * 5.0, 10.0) for i in range(args.n)])
        move = stats_ms(timed(lambda: controller.move_to(*next(targets)), args.n))
        count, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            controller._query_status()
            count += 1
        rate_hz = count / (time.perf_counter() - t0)
    finally:
        link.close()

    poll_hz = 1.0 / controller.poll_period_s
    print(f"GRBL driver <-> simulator over a pty, {args.n} round trips each")
    print(f"  G-code line (send, wait ok):   median {line[0]:.3f} ms   p95 {line[1]:.3f} ms")
    print(f"  status query ('?' -> report):  median {query[0]:.3f} ms   p95 {query[1]:.3f} ms")
    print(f"  move_to, instant simulator:    median {move[0]:.3f} ms   p95 {move[1]:.3f} ms")
    print(f"  sustained status rate:         {rate_hz:.0f} reports/s = {rate_hz / poll_hz:.0f}x the driver's "
          f"{poll_hz:.0f} Hz polling, {rate_hz / 5:.0f}x GRBL's recommended 5 Hz")
    return 0


def firmware(args) -> int:
    import os
    import tempfile

    from lfstudio.rig.grbl import GrblController
    from tests.grbl_firmware import FirmwareSimulator, FirmwareUnavailable, build_firmware_simulator

    try:
        exe = build_firmware_simulator()
    except FirmwareUnavailable as exc:
        print(f"GRBL firmware simulator unavailable: {exc}")
        return 1
    with tempfile.TemporaryDirectory() as tmp, FirmwareSimulator(exe, Path(tmp), speedup=args.speedup) as fw:
        controller = GrblController(fw.port, load_rig())
        controller.connect()
        try:
            controller.set_origin()
            line = stats_ms(timed(lambda: controller._command("G90"), args.n))
            query = stats_ms(timed(controller._query_status, args.n))
            ticks = os.sysconf("SC_CLK_TCK")

            def fw_cpu_s() -> float:
                fields = Path(f"/proc/{fw._proc.pid}/stat").read_text().split()
                return (int(fields[13]) + int(fields[14])) / ticks

            machine_s = controller.expected_move_s(100.0, 0.0)
            c0, f0, t0 = time.process_time(), fw_cpu_s(), time.perf_counter()
            controller.move_to(100.0, 0.0)
            wall = time.perf_counter() - t0
            cpu, fw_cpu = time.process_time() - c0, fw_cpu_s() - f0
        finally:
            controller.disconnect()
    print(f"GRBL driver <-> GRBL 1.1h firmware (official simulator, {args.speedup:g}x) over a pty, "
          f"{args.n} round trips each")
    print(f"  G-code line (send, wait ok):   median {line[0]:.3f} ms   p95 {line[1]:.3f} ms")
    print(f"  status query ('?' -> report):  median {query[0]:.3f} ms   p95 {query[1]:.3f} ms")
    print(f"  100 mm move at $110=500 mm/min: {machine_s:.2f} s machine time took {wall:.2f} s wall "
          f"({machine_s / wall:.1f}x); CPU: driver {cpu:.2f} s, firmware simulator {fw_cpu:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
