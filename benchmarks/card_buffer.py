"""The camera's card as the buffer (issue #40, ``--keep-on-card``) on the simulated studio with the
tethered reference camera's timings (exposure 0.5 s, trigger 0.05 s, transfer 2.5 s per picture) on the
reference grid: when the last picture is taken (the rig is free and the scene may change) and when the
last file is downloaded, in simulated minutes (wall ÷ ``--time-scale``), against the step scan's
estimate (3.0 s per view: 1 h 46 min) and the issue's ≈ 35 min for the captures.

    python benchmarks/card_buffer.py [--grid 101x21] [--time-scale 0.02] [--width 64]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._measure import Timer, load_text  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", default="101x21")
    ap.add_argument("--time-scale", type=float, default=0.02)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--timeout-s", type=float, default=24 * 3600)
    ap.add_argument("--poll-in-wall-time", action="store_true",
                    help="keep the GRBL driver's status polls at 20/s of wall time (default: 20/s of simulated "
                         "time, as on the real rig; at a small time scale wall-time polls make every move "
                         "wait up to 1 / (20 x time scale) simulated seconds for its arrival to be seen)")
    args = ap.parse_args()
    cols, rows = (int(v) for v in args.grid.lower().split("x"))

    from lfstudio.dataset import Dataset
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.card import CardBufferEngine
    from lfstudio.scan.events import EventKind, ScanState
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.devices import open_studio
    from lfstudio.studio.session import create_scan_dataset

    rig = load_rig()
    ts = args.time_scale
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), rig)
    root = Path(tempfile.mkdtemp(prefix="card-bench-"))
    studio = open_studio("sim", "sim", rig, time_scale=ts, exposure_s=0.5, transfer_s=2.5,
                         view_region_mm=plan.extent_mm(), sim_width_px=args.width)
    ds = create_scan_dataset(root / "ds", plan, rig={"name": rig.name}, camera={"name": "sim"}, lens={"name": "v"})
    driver = getattr(studio.rig, "driver", studio.rig)
    if not args.poll_in_wall_time and ts > 0:       # the rig's polls in the rig's (simulated) time
        driver.poll_period_s *= ts
        driver.min_status_interval_s *= ts
    engine = CardBufferEngine(ds, plan, studio.rig, studio.camera, time_scale=ts)
    last_exposed = [0.0]
    exposed_at: list[tuple[int, float]] = []
    parts: dict[str, list[float]] = {}

    def on_event(e) -> None:
        if e.kind is EventKind.VIEW_EXPOSED:
            now = time.perf_counter()
            last_exposed[0] = now
            exposed_at.append((e.row, now))
            for k, v in (e.timings_s or {}).items():
                parts.setdefault(k, []).append(v / ts)

    engine.subscribe(on_event)
    with Timer() as m:
        t0 = time.perf_counter()
        engine.start()
        state = engine.wait(float(args.timeout_s))
    studio.close()
    assert state is ScanState.FINISHED, engine.message
    done = Dataset.open(ds.root).status_counts()["done"]
    step = plan.estimate_duration_s(rig, 0.5, 2.5)
    captures = (last_exposed[0] - t0) / ts
    print(f"grid {cols} x {rows} = {cols * rows} views, time scale {ts:g}; {done} done and verified")
    print(f"card buffering: last picture taken after {captures / 60:.1f} min simulated (issue: ≈ 35 min), "
          f"last file downloaded after {m.wall_s / ts / 60:.1f} min; step scan estimate {step / 60:.1f} min")
    # where a view's time goes (simulated s, median; the gap is from one shutter closing to the next)
    gaps_in = [b - a for (ra, a), (rb, b) in zip(exposed_at, exposed_at[1:]) if ra == rb]
    gaps_change = [b - a for (ra, a), (rb, b) in zip(exposed_at, exposed_at[1:]) if ra != rb]
    from lfstudio.optics import move_time_s

    h = rig.horizontal
    model = (move_time_s(plan.spacing_mm[0], h.max_speed_mm_s, h.acceleration_mm_s2) + plan.settle_s + 0.05 + 0.5)
    med = {k: float(np.median(vals)) for k, vals in parts.items()}
    print("per view within a row, simulated s (median): " + ", ".join(f"{k} {med[k]:.3f}" for k in
          ("move", "settle", "camera_wait", "expose") if k in med) +
          f"; shutter to shutter {np.median(gaps_in) / ts if gaps_in else float('nan'):.3f} "
          f"(p90 {np.percentile(gaps_in, 90) / ts if gaps_in else float('nan'):.3f}) against move + settle + "
          f"trigger 0.05 + exposure 0.5 = {model:.3f}")
    if gaps_change:
        print(f"row changes: {len(gaps_change)}, shutter to shutter median {np.median(gaps_change) / ts:.2f} s, "
              f"total {sum(gaps_change) / ts / 60:.2f} min")
    print(f"captures' critical path (issue: exposure + move + settle): "
          f"{(model - 0.05) * cols * rows / 60:.1f} min; with the trigger's 0.05 s: {model * cols * rows / 60:.1f} min; "
          f"downloads {cols * rows} x 2.5 s = {cols * rows * 2.5 / 60:.1f} min")
    print(f"CPU {m.cpu_s:.0f} s over wall {m.wall_s:.0f} s ({m.cores_used:.2f} cores); {load_text()}")
    import shutil

    shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
