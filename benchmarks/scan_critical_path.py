"""Pipelined scan vs its critical path, on the simulated studio with realistic timings: GRBL
simulator on a pty (4 mm moves at the rig's speed and acceleration), settle 0.3 s, exposure 0.5 s,
transfer 2.5 s (plus the simulated camera's 0.05 s trigger delay). The critical path is the slowest
chain of unavoidable steps when the transfer overlaps the next move and settle
(``lfstudio.optics.view_period_s`` per view). ``--time-scale`` shortens every simulated
duration by the same factor, so the ratio keeps its meaning. Target: within 3 % (ratio <= 1.03).

    python benchmarks/scan_critical_path.py [--columns 12 --rows 3 --time-scale 0.2]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _datasets import studio_scan, timed_scan, view_periods  # noqa: E402
from lfstudio.optics import move_time_s  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.scan.scan_plan import ScanPlan  # noqa: E402

SETTLE_S, EXPOSURE_S, TRANSFER_S = 0.3, 0.5, 2.5


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--columns", type=int, default=12)
    ap.add_argument("--rows", type=int, default=3)
    ap.add_argument("--time-scale", type=float, default=0.2)
    ap.add_argument("--width-px", type=int, default=320, help="simulated image width (rendering cost)")
    args = ap.parse_args()
    rig = load_rig()
    plan = ScanPlan.centered(args.columns, args.rows, (4.0, 6.0), rig, settle_s=SETTLE_S)
    scale = args.time_scale
    with studio_scan("sim", plan, rig, scale=scale, exposure_s=EXPOSURE_S, transfer_s=TRANSFER_S,
                     width_px=args.width_px) as (engine, _ds, trigger_s):
        periods = view_periods(engine)
        total_s = timed_scan(engine)
        if total_s is None:
            return 1
    critical_s = plan.estimate_duration_s(rig, exposure_s=trigger_s + EXPOSURE_S, transfer_s=TRANSFER_S) * scale
    serial_s = plan.estimate_duration_s(rig, exposure_s=trigger_s + EXPOSURE_S, transfer_s=TRANSFER_S,
                                        pipelined=False) * scale
    h = rig.horizontal
    n = len(plan)
    steady = [p for p in periods if p][1:]
    print(f"grid                       {plan.columns} x {plan.rows} = {n} views, time scale {scale:g}")
    print(f"4 mm move (trapezoid)      {move_time_s(4.0, h.max_speed_mm_s, h.acceleration_mm_s2):.3f} s at "
          f"{h.max_speed_mm_s:g} mm/s, {h.acceleration_mm_s2:g} mm/s² (unscaled)")
    print(f"measured scan              {total_s:.2f} s  ({total_s / scale:.1f} s at real time)")
    print(f"critical path              {critical_s:.2f} s  ({critical_s / scale:.1f} s at real time)")
    print(f"without pipelining         {serial_s:.2f} s  (for comparison)")
    if steady:
        print(f"median view period         {sorted(steady)[len(steady) // 2] / scale:.3f} s real-time equivalent "
              f"(critical: {(trigger_s + EXPOSURE_S + TRANSFER_S):.3f} s)")
    ratio = total_s / critical_s
    print(f"ratio measured/critical    {ratio:.4f}   (target <= 1.03: {'OK' if ratio <= 1.03 else 'MISSED'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
