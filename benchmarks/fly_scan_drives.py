"""Fly scan on emulated CiA 402 drives (issue #40): the dryve D1 emulator (Modbus TCP gateway telegrams,
and/or CANopen SDO on python-can's virtual bus) with the simulated camera, through the real driver and
``FlyScanEngine``, as ``lfstudio scan --fly --port sim-dryve`` runs it.

For each transport, the drives as the dryve D1 comes (no touch probe: every frame's position is
interpolated from time-stamped 6064h reads) and, with ``--touch-probe``, as a generic CiA 402 drive with
touch probe 1 wired to the camera's exposure output (the drives latch the position on both edges):

- wall time of the fly scan in simulated minutes (wall ÷ time scale), against the step scan's estimate
  with the same camera; views flown / taken again standing still;
- recorded position vs the emulator's truth at each exposure's centre (the truth sidecar the simulated
  camera writes from the emulator's own history of where the carriage was): RMS and max, by source
  (touch probe / 6064h reads). The emulated drives have no repeatability error (unlike the GRBL
  simulator's draw): the figure is what the recording itself adds;
- the drives' measured report rate (reports/s in simulated time) and the row speed the planner chose;
- STOP during a fly move: real milliseconds from ``stop()`` until the quick stop reached both drives.

The drives are homed at time scale 0 (their search run would take most of a small benchmark), then
everything runs at ``--time-scale``. The grid starts at (40, 20) mm, near where the drives home.

    python benchmarks/fly_scan_drives.py [--grid 21x5] [--time-scale 0.5] [--transport modbus|canopen|both]
                                         [--touch-probe] [--width 64]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._measure import Timer, load_text  # noqa: E402

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"


def run_one(transport: str, touch_probe: bool, args: argparse.Namespace, root: Path) -> dict:
    from lfstudio.dataset import Dataset
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.events import ScanState
    from lfstudio.scan.fly import FlyScanEngine
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio import simulated
    from lfstudio.studio.devices import open_studio
    from lfstudio.studio.session import ScanRequest, ScanSession, create_scan_dataset

    rig = load_rig(RIG_NAME)
    cols, rows = (int(v) for v in args.grid.lower().split("x"))
    plan = ScanPlan(cols, rows, (4.0, 6.0), (40.0, 20.0), settle_s=0.3)
    ts = args.time_scale
    real = simulated.start_drive_emulator

    def with_setup(*a, **kw):                   # the emulated drives' variety (sim-drive --touch-probe)
        kw["setup"] = {"touch_probe": True} if touch_probe else None
        return real(*a, **kw)

    simulated.start_drive_emulator = with_setup
    try:
        studio = open_studio("sim-dryve" if transport == "modbus" else "sim-canopen", "sim", rig, time_scale=0.0,
                             exposure_s=args.exposure_s, transfer_s=0.0, view_region_mm=plan.extent_mm(),
                             sim_width_px=args.width, timeout_s=2.0)
    finally:
        simulated.start_drive_emulator = real
    studio.simulator.time_scale = ts
    cam = studio.camera
    cam.time_scale = ts
    cam.frame_rate_fps = args.fps
    name = f"{transport}{'-probe' if touch_probe else ''}"
    ds = create_scan_dataset(root / name, plan, rig={"name": rig.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    session = ScanSession(ScanRequest(root / name, time_scale=ts, fly=True))
    decided = session._decide_fly(studio.rig, cam, plan, None, rig)
    engine = FlyScanEngine(ds, plan, studio.rig, cam, time_scale=ts, speed_mm_s=decided["speed_mm_s"])
    with Timer() as m:
        engine.start()
        state = engine.wait(24 * 3600)
    studio.close()
    assert state is ScanState.FINISHED, engine.message
    done = Dataset.open(ds.root)
    errors: dict[str, list[float]] = {}
    worst: list[tuple[float, str]] = []
    for v in done.views:
        fly = v.get("fly") or {}
        if "recorded_mm" not in fly:
            continue
        truth = json.loads((done.root / v["sidecars"][1]).read_text())["true_position_mm"]
        e = math.hypot(fly["recorded_mm"][0] - truth[0], fly["recorded_mm"][1] - truth[1])
        errors.setdefault(fly.get("source", "reports"), []).append(e)
        worst.append((e, f"r{v['row']:02d} c{v['column']:03d} {fly.get('source')}: recorded {fly['recorded_mm']}, "
                         f"truth [{truth[0]:.4f}, {truth[1]:.4f}], t {fly['t_s']}"))
    step = plan.estimate_duration_s(rig, args.exposure_s, 1.0 / args.fps)
    return {"name": name, "views": cols * rows, "speed": decided["speed_mm_s"], "binding": decided["binding"],
            "report_hz": decided["report_rate_hz"], "wall_min": m.wall_s / ts / 60, "step_min": step / 60,
            "flown": sum(len(e) for e in errors.values()), "retaken": engine.retaken, "errors": errors,
            "cpu": m.cpu_s, "wall": m.wall_s, "worst": sorted(worst, reverse=True)[:2]}


def stop_latency(transport: str, trials: int) -> list[float]:
    """STOP during a fly move: ms from ``stop()`` until the quick stop (6040h = 0Bh) reached both drives
    (the emulator notes when each took it), ``trials`` times."""
    import threading
    import time

    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig
    from lfstudio.studio.simulated import start_drive_emulator

    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, transport, time_scale=0.0)
    link = open_rig(emulator.word, rig, doing="benchmark", lock=False, timeout_s=2.0)
    out = []
    try:
        link.controller.home()
        emulator.time_scale = 0.2
        for axis in emulator.pair.axes:
            original = axis._control

            def noting(cw: int, axis=axis, original=original) -> None:
                if cw == 0x0B and getattr(axis, "stopped_at", None) is None:
                    axis.stopped_at = time.monotonic()
                original(cw)

            axis._control = noting
        c = link.controller
        for k in range(trials):
            x = 200.0 + 400.0 * (k % 2)
            for axis in emulator.pair.axes:
                axis.stopped_at = None
            c.fly_to(x, 0.0, 150.0)
            waiter = threading.Thread(target=lambda: _quietly(c.wait_arrival, x, 0.0, 60))
            waiter.start()
            time.sleep(0.05)
            t0 = time.monotonic()
            c.stop()
            waiter.join(60)
            out.append(1000 * (max(axis.stopped_at for axis in emulator.pair.axes) - t0))
            c.move_to(x, 0.0)
    finally:
        link.close()
        emulator.close()
    return out


def _quietly(fn, *args) -> None:
    try:
        fn(*args)
    except Exception:  # noqa: BLE001 - STOP ends it: that is the point
        pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", default="21x5")
    ap.add_argument("--time-scale", type=float, default=0.5)
    ap.add_argument("--transport", choices=("modbus", "canopen", "both"), default="both")
    ap.add_argument("--touch-probe", action="store_true", help="also the drives with touch probe 1")
    ap.add_argument("--width", type=int, default=64, help="rendered width in px")
    ap.add_argument("--fps", type=float, default=20.0)
    ap.add_argument("--exposure-s", type=float, default=0.001)
    ap.add_argument("--stop-trials", type=int, default=5, help="STOP during a fly move, per transport (0: none)")
    args = ap.parse_args()
    transports = ("modbus", "canopen") if args.transport == "both" else (args.transport,)
    probes = (False, True) if args.touch_probe else (False,)
    root = Path(tempfile.mkdtemp(prefix="fly-drives-bench-"))
    results = []
    try:
        for transport in transports:
            for probe in probes:
                results.append(run_one(transport, probe, args, root))
    finally:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    print(f"grid {args.grid} at time scale {args.time_scale:g}, camera {args.fps:g} frames/s, "
          f"{args.exposure_s * 1000:g} ms; rig {RIG_NAME!r} (emulated dryve D1 drives)")
    print("| drives | speed mm/s (binds) | reports/s | fly scan min | step estimate min | flown / retaken "
          "| source: RMS / max µm (n) |")
    print("|---|---|---|---|---|---|---|")
    failed = False
    for r in results:
        parts = []
        for source, es in sorted(r["errors"].items()):
            rms = math.sqrt(statistics.fmean(e * e for e in es))
            parts.append(f"{source}: {1000 * rms:.1f} / {1000 * max(es):.1f} ({len(es)})")
        print(f"| {r['name']} | {r['speed']:.1f} ({r['binding']}) | {r['report_hz']:.0f} | {r['wall_min']:.2f} | "
              f"{r['step_min']:.2f} | {r['flown']} / {r['retaken']} | {'; '.join(parts) or '–'} |")
        failed |= r["flown"] == 0
    for r in results:
        for e, what in r["worst"]:
            print(f"  worst of {r['name']}: {1000 * e:.1f} µm at {what}")
    every = [e for r in results for es in r["errors"].values() for e in es]
    if every:
        print(f"recorded position vs truth, all: RMS {1000 * math.sqrt(statistics.fmean(e * e for e in every)):.1f} µm "
              f"(target ≤ 80 µm) over {len(every)} views")
    for transport in transports if args.stop_trials > 0 else ():
        ms = sorted(stop_latency(transport, args.stop_trials))
        print(f"STOP during a fly move ({transport}): the quick stop reached both drives after median "
              f"{statistics.median(ms):.1f} ms, max {ms[-1]:.1f} ms ({len(ms)} trials)")
    print(f"CPU {sum(r['cpu'] for r in results):.0f} s over wall {sum(r['wall'] for r in results):.0f} s; {load_text()}")
    if failed:
        print("FAILED: a run took no view on the fly: no position figure of a fly scan", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
