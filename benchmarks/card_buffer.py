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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._measure import Timer, load_text  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", default="101x21")
    ap.add_argument("--time-scale", type=float, default=0.02)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--timeout-s", type=float, default=24 * 3600)
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
    engine = CardBufferEngine(ds, plan, studio.rig, studio.camera, time_scale=ts)
    last_exposed = [0.0]
    engine.subscribe(lambda e: e.kind is EventKind.VIEW_EXPOSED and last_exposed.__setitem__(0, time.perf_counter()))
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
    print(f"CPU {m.cpu_s:.0f} s over wall {m.wall_s:.0f} s ({m.cores_used:.2f} cores); {load_text()}")
    import shutil

    shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
