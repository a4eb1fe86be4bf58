"""Fly scan of the reference grid on the simulated studio (issue #40): wall time against the step scan,
the motion blur rendered into the views, and the recorded positions against the simulator's truth.

The GRBL simulator (reference gantry profile, on a pty through the real driver) and the simulated
camera (20 frames/s, 1 ms exposure, trigger latency 0.5 ms ± 0.2 ms) run at ``--time-scale``: every
simulated duration is multiplied by it, and the times printed are simulated seconds (wall ÷ scale).
The camera is the reference camera's pixel (4.53 µm, 50 mm lens) on a ``--width`` px crop, so a pixel
of blur here is one of the reference camera. The speed is decided as ``lfstudio scan --fly`` decides it
(the planner with the camera's frame rate and exposure and the controller's measured report rate).

Figures:
- fly scan: simulated wall time (target ≤ 10 min), of which the rig's part (moves, settles, rows and
  the views taken again standing still) and the waits for the camera's frames at row ends (rendering
  on this machine: a real camera delivers during the row); views flown and taken again;
- step scan with the same camera and with the tethered reference camera (3.0 s per view): the
  critical-path estimate (``ScanPlan.estimate_duration_s``; measured step scans run within ~1.2 % of
  it: scan_critical_path.py), or run for real with ``--run-step``;
- blur: the carriage's travel during each exposure projected at the nearest scene depth, in px (what
  the renderer integrated; target ≤ 0.5 px): median, p99, max;
- recorded position error against the truth at each exposure's centre: RMS (target ≤ 80 µm), and
  after removing each row's constant offset (the repeatability draw of the run-up move, which no
  report can see: what the interpolation itself adds).

    python benchmarks/fly_scan.py [--grid 101x21] [--time-scale 0.5] [--width 160] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._measure import Timer, load_text  # noqa: E402

PITCH_UM = 4.53


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", default="101x21")
    ap.add_argument("--time-scale", type=float, default=0.5)
    ap.add_argument("--width", type=int, default=160, help="rendered width in px (4.53 µm pixels)")
    ap.add_argument("--fps", type=float, default=20.0)
    ap.add_argument("--exposure-s", type=float, default=0.001)
    ap.add_argument("--run-step", action="store_true", help="also run the step scan with the same camera")
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args()
    cols, rows = (int(v) for v in args.grid.lower().split("x"))

    from lfstudio.dataset import Dataset
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.engine import ScanEngine
    from lfstudio.scan.events import ScanState
    from lfstudio.scan.fly import FlyScanEngine
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.devices import open_studio
    from lfstudio.studio.session import ScanRequest, ScanSession, create_scan_dataset

    rig = load_rig()
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), rig)
    root = args.keep or Path(tempfile.mkdtemp(prefix="fly-bench-"))
    ts = args.time_scale

    def studio_for(width: int):
        studio = open_studio("sim", "sim", rig, time_scale=ts, exposure_s=args.exposure_s, transfer_s=0.0,
                             view_region_mm=plan.extent_mm(), sim_width_px=width)
        cam = studio.camera
        cam.frame_rate_fps = args.fps
        kw = dict(cam.studio.init_kwargs())
        kw["sensor_width_mm"] = width * PITCH_UM / 1000.0      # the reference camera's pixel, cropped
        cam.studio = type(cam.studio)(**kw)
        return studio

    studio = studio_for(args.width)
    ds = create_scan_dataset(root / "fly", plan, rig={"name": rig.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    # the speed as 'lfstudio scan --fly' decides it
    session = ScanSession(ScanRequest(root / "fly", time_scale=ts, fly=True))
    decided = session._decide_fly(studio.rig, studio.camera, plan, None, rig)
    print(f"speed {decided['speed_mm_s']:.1f} mm/s ({decided['binding']} binds); limits "
          + ", ".join(f"{k} {v:.4g}" for k, v in decided["limits_mm_s"].items())
          + f" mm/s; planned motion {decided['time_s']:.0f} s; controller reports {decided['report_rate_hz']:.0f}/s "
            "(simulated time)")
    engine = FlyScanEngine(ds, plan, studio.rig, studio.camera, time_scale=ts, speed_mm_s=decided["speed_mm_s"])
    with Timer() as m:
        engine.start()
        state = engine.wait(24 * 3600)
    studio.close()
    assert state is ScanState.FINISHED, engine.message
    wall = m.wall_s
    done = Dataset.open(ds.root)
    blur, errors, by_pass = [], [], {}
    for v in done.views:
        fly = v.get("fly") or {}
        if "recorded_mm" not in fly:
            continue
        truth = json.loads((done.root / v["sidecars"][1]).read_text())
        blur.append(truth["blur_px_near"])
        e = (fly["recorded_mm"][0] - truth["true_position_mm"][0], fly["recorded_mm"][1] - truth["true_position_mm"][1])
        errors.append(e)
        by_pass.setdefault(fly["pass"], []).append(e)
    flown = len(errors)
    rms = math.sqrt(statistics.fmean(ex * ex + ey * ey for ex, ey in errors)) if errors else float("nan")
    centred = []
    for es in by_pass.values():
        mx, my = statistics.fmean(e[0] for e in es), statistics.fmean(e[1] for e in es)
        centred += [(ex - mx) ** 2 + (ey - my) ** 2 for ex, ey in es]
    rms_c = math.sqrt(statistics.fmean(centred)) if centred else float("nan")
    blur.sort()
    step_same = plan.estimate_duration_s(rig, args.exposure_s, 1.0 / args.fps)
    step_ref = plan.estimate_duration_s(rig, 0.5, 2.5)
    print(f"grid {cols} x {rows} = {cols * rows} views at time scale {ts:g}, {args.width} px wide ({PITCH_UM} µm px)")
    print(f"fly scan: {wall / ts / 60:.1f} min simulated (wall {wall:.0f} s; target ≤ 10 min); rig "
          f"{engine.rig_s / ts / 60:.1f} min, waiting for frames at row ends {engine.camera_wait_s / ts / 60:.1f} min; "
          f"{engine.rows_flown} rows flown, {flown} views on the fly, {engine.retaken} taken again standing still")
    print(f"step scan, same camera (estimate): {step_same / 60:.1f} min; tethered reference camera "
          f"(3.0 s per view): {step_ref / 60:.1f} min; fly / step same camera = {wall / ts / step_same:.3f}")
    if blur:
        print(f"blur at the nearest depth: median {statistics.median(blur):.3f} px, p99 "
              f"{blur[min(len(blur) - 1, int(0.99 * len(blur)))]:.3f} px, max {blur[-1]:.3f} px (target ≤ 0.5 px)")
    print(f"recorded position vs truth: RMS {1000 * rms:.0f} µm (target ≤ 80 µm); without each row's "
          f"repeatability offset {1000 * rms_c:.0f} µm")
    print(f"CPU {m.cpu_s:.0f} s over wall {m.wall_s:.0f} s ({m.cores_used:.2f} cores); {load_text()}")
    if args.run_step:
        studio = studio_for(args.width)
        ds2 = create_scan_dataset(root / "step", plan, rig={"name": rig.name}, camera={"name": "sim"},
                                  lens={"name": "virtual"})
        studio.camera.transfer_s = 1.0 / args.fps
        engine2 = ScanEngine(ds2, plan, studio.rig, studio.camera, time_scale=ts)
        t0 = time.monotonic()
        engine2.start()
        engine2.wait(24 * 3600)
        studio.close()
        print(f"step scan, same camera (run): {(time.monotonic() - t0) / ts / 60:.1f} min simulated")
    if args.keep is None:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    if not flown:
        print(f"FAILED: no view was taken on the fly ({engine.rows_flown} rows flown, {engine.retaken} views taken "
              "again standing still): no blur or position figure of a fly scan", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
