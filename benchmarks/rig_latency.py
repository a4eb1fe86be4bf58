"""Rig command latency and status rate through the pseudo-terminal (driver <-> simulated GRBL).

    ./.venv/bin/python benchmarks/rig_latency.py [--n 500] [--seconds 2]
    ./.venv/bin/python benchmarks/rig_latency.py --firmware [--n 200] [--speedup 10]

Prints median / p95 round-trip times of a G-code line (send, wait for ``ok``), of a ``?`` status
query (send, wait for the report), and of a complete ``move_to`` on an instant simulator
(time_scale 0: protocol overhead only), plus the sustained status-report rate and its headroom over
the driver's 20 Hz polling while waiting for a move.

``--drive dryve|canopen``: the CiA 402 driver against the emulated drives (Modbus TCP gateway
telegrams to the emulator's Modbus TCP server on 127.0.0.1, or python-canopen SDO to a LocalNode on python-can's
virtual bus): the round trip of one object read and write and of a full status (5 objects per
drive), STOP-to-standstill of a long move in the emulator's own time (vs the quick-stop ramp's
v/a), and a ``--grid`` scan (default 101x21) on ``sim-dryve``/``sim-canopen`` with the simulated
camera at ``--time-scale`` (default 0.05): measured / critical path (target <= 1.03; the same
critical path as benchmarks/scan_critical_path.py). ``--grid 0`` skips the scan.

    ./.venv/bin/python benchmarks/rig_latency.py --drive dryve [--n 500] [--grid 101x21 --time-scale 0.05]

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

from _measure import cpu_s, load_text  # noqa: E402
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
    ap.add_argument("--drive", choices=("dryve", "canopen"), help="the CiA 402 driver on emulated drives")
    ap.add_argument("--grid", default="101x21", help="with --drive: the scan's grid (0: no scan)")
    ap.add_argument("--time-scale", type=float, default=0.05, help="with --drive: the scan's time scale")
    ap.add_argument("--width-px", type=int, default=160, help="with --drive: simulated image width")
    args = ap.parse_args()
    if args.firmware:
        return firmware(args)
    if args.drive:
        return drive(args)

    link = open_rig("sim", load_rig(), time_scale=0.0)
    controller = link.controller
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


def drive(args) -> int:
    from lfstudio.rig import cia402
    from lfstudio.rig.motion import RigState

    rig = load_rig("dryve D1 gantry 4 m x 0.5 m")
    word = {"dryve": "sim-dryve", "canopen": "sim-canopen"}[args.drive]
    link = open_rig(word, rig, time_scale=0.0, lock=False)
    c, emulator = link.controller, link.simulator
    try:
        c.home()
        link0 = c.links[0]
        read = stats_ms(timed(lambda: link0.read(cia402.STATUS, 0, 2, False), args.n))
        write = stats_ms(timed(lambda: link0.write(cia402.PROFILE_VELOCITY, 0, 20000, 4, False), args.n))
        status = stats_ms(timed(c._query, max(20, args.n // 10)))
        targets = iter([(10.0 + (i % 2) * 5.0, 10.0) for i in range(args.n)])
        move = stats_ms(timed(lambda: c.move_to(*next(targets)), max(20, args.n // 5)))
        # STOP-to-standstill, in the emulator's time (real time here): a long move at cruise speed, then STOP
        emulator.time_scale = 1.0
        axis = emulator.pair.axes[0]
        import threading
        received: list[float] = []
        original_write = axis.write

        def recording_write(index: int, sub: int, value: int) -> None:
            if index == cia402.CONTROL and value == cia402.QUICK_STOP and not received:
                received.append(axis._now())
            original_write(index, sub, value)

        axis.write = recording_write
        result: list = []
        mover = threading.Thread(target=lambda: result.append(_try(lambda: c.move_to(3900.0, 10.0))))
        mover.start()
        h = rig.horizontal
        cruise = h.max_speed_mm_s * h.increments_per_mm
        while axis.read(cia402.VELOCITY, 0) < 0.999 * cruise and mover.is_alive():
            time.sleep(0.001)
        t_stop_emu = axis._now()
        x_stop = axis.position_mm()
        w0 = time.perf_counter()
        c.stop()
        stop_call_ms = (time.perf_counter() - w0) * 1e3
        t_rest = None
        while t_rest is None:
            with axis._lock:
                axis._advance()
                if axis._v == 0.0:
                    t_rest = axis._last
            time.sleep(0.0005)
        mover.join(60)
        x_rest = axis.position_mm()
        quick_decel = 4 * h.acceleration_mm_s2
        ideal_s = h.max_speed_mm_s / quick_decel
        ended = c.status()
    finally:
        link.close()
    print(f"CiA 402 driver <-> emulated drives over {'Modbus TCP (dryve D1 gateway)' if args.drive == 'dryve' else 'CANopen SDO (virtual bus)'}")
    print(f"  object read (6041h):           median {read[0]:.3f} ms   p95 {read[1]:.3f} ms")
    print(f"  object write (6081h):          median {write[0]:.3f} ms   p95 {write[1]:.3f} ms")
    print(f"  full status (10 objects):      median {status[0]:.3f} ms   p95 {status[1]:.3f} ms")
    print(f"  move_to, instant emulator:     median {move[0]:.3f} ms   p95 {move[1]:.3f} ms")
    print(f"  STOP at {h.max_speed_mm_s:g} mm/s (emulator at real time): stop() returned in {stop_call_ms:.2f} ms; "
          f"quick stop at the drive {(received[0] - t_stop_emu) * 1e3:.1f} ms after the call, standstill "
          f"{(t_rest - received[0]) * 1e3:.1f} ms later (quick-stop ramp v/a = {ideal_s * 1e3:.1f} ms); "
          f"STOP-to-standstill {(t_rest - t_stop_emu) * 1e3:.1f} ms, {x_rest - x_stop:.2f} mm "
          f"(ramp alone v²/2a = {h.max_speed_mm_s ** 2 / 2 / quick_decel:.2f} mm)")
    print(f"  after STOP: {ended.state.value} at x = {ended.position_mm[0]:.3f} mm (true {x_rest:.3f} mm), the move "
          f"{'ended by STOP' if result and isinstance(result[0], cia402.MotionStopped) else repr(result)}")
    assert ended.state is not RigState.ALARM
    if args.grid and args.grid != "0":
        return drive_scan(args, rig, word)
    return 0


def _try(fn):
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 - the benchmark reports it
        return exc


def drive_scan(args, rig, word: str) -> int:

    from _datasets import studio_scan, timed_scan
    from lfstudio.numbers import parse_grid
    from lfstudio.scan.scan_plan import ScanPlan

    settle_s, exposure_s, transfer_s = 0.3, 0.5, 2.5
    columns, rows = parse_grid("--grid", args.grid)
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), rig, settle_s=settle_s)
    scale = args.time_scale
    with studio_scan(word, plan, rig, scale=scale, exposure_s=exposure_s, transfer_s=transfer_s,
                     width_px=args.width_px) as (engine, ds, trigger_s):
        cpu0 = cpu_s()
        total_s = timed_scan(engine)
        scan_cpu_s = cpu_s() - cpu0
        if total_s is None:
            return 1
        steps: dict[str, list[float]] = {}          # where each view's time went (the engine's own timings)
        for v in ds.done_views():
            for key, value in (v.get("timings_s") or {}).items():
                steps.setdefault(key, []).append(value)
    critical_s = plan.estimate_duration_s(rig, exposure_s=trigger_s + exposure_s, transfer_s=transfer_s) * scale
    ratio = total_s / critical_s
    print(f"  scan {plan.columns} x {plan.rows} = {len(plan)} views on {word}, time scale {scale:g}: measured "
          f"{total_s:.1f} s, critical path {critical_s:.1f} s, ratio {ratio:.4f} "
          f"(target <= 1.03: {'OK' if ratio <= 1.03 else 'MISSED'})")
    print(f"    CPU {scan_cpu_s:.1f} s in {total_s:.1f} s wall ({scan_cpu_s / total_s:.2f} cores); {load_text()}")
    per_view = {"expose": (trigger_s + exposure_s) * scale, "transfer": transfer_s * scale,
                "period": critical_s / len(plan)}
    print("    per view, median (critical path): " + ", ".join(
        f"{key} {1e3 * statistics.median(values):.1f} ms" + (f" ({1e3 * per_view[key]:.1f})" if key in per_view else "")
        for key, values in steps.items() if values))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
