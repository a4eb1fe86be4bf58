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
- recorded position error against the truth at each exposure's centre (target RMS ≤ 80 µm). The
  truth is where the simulated carriage really was: the controller's position plus its repeatability
  error (σ 80 µm horizontally, 50 µm vertically, one draw per completed move, so one per row: a row is
  one move). No report sees that error and a step scan records it exactly as wrongly, so it is printed
  apart: the RMS against the truth (2-D, and per axis), the RMS of the repeatability draws themselves
  (what any scan of this rig has; few rows make it a noisy figure: 21 draws give ± 15 %), and the
  RMS of what the fly recording adds (recorded − (truth − repeatability error): the interpolation or
  the trigger line's latency model);
- with ``--calibrate``: the calibration's true rectification error on a fly-scanned grid. The views
  ``lfstudio calibrate`` uses by default (array:4ex10: the first two and the last two columns of ten
  rows) are flown again at ``--calibrate-width`` px (a fly scan of that subset: the same speed,
  trigger, run-ups; the virtual studio's own camera, whose whole frame shows the textured scene, not
  the reference pixel's narrow crop, where features are too few to calibrate), calibrated as ``lfstudio calibrate --json --no-save`` does, at their recorded
  positions, and the estimate compared with the virtual studio's true rotation and principal point
  (``lfstudio.calibration.uncertainty.probe_errors`` at the corner probes of a full row and column:
  RMS and max over the probes, px; target ≤ 0.05 px RMS), with the rotation error.

``--trigger``: who fires the camera (default ``auto``: the hardware trigger line, GRBL's spindle output
in laser mode, which the simulated studio's controller has; ``software``: timed from the reports).

    python benchmarks/fly_scan.py [--grid 101x21] [--time-scale 0.5] [--width 160] [--trigger auto]
                                  [--calibrate] [--calibrate-width 800] [--keep DIR]
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
    ap.add_argument("--trigger", default="auto", choices=("auto", "hardware", "software"))
    ap.add_argument("--calibrate", action="store_true",
                    help="also fly the default calibration views at --calibrate-width and measure the true error")
    ap.add_argument("--calibrate-width", type=int, default=800)
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

    def studio_for(width: int, crop: bool = True):
        studio = open_studio("sim", "sim", rig, time_scale=ts, exposure_s=args.exposure_s, transfer_s=0.0,
                             view_region_mm=plan.extent_mm(), sim_width_px=width)
        cam = studio.camera
        cam.frame_rate_fps = args.fps
        if not crop:
            return studio
        kw = dict(cam.studio.init_kwargs())
        kw["sensor_width_mm"] = width * PITCH_UM / 1000.0      # the reference camera's pixel, cropped
        cam.studio = type(cam.studio)(**kw)
        return studio

    studio = studio_for(args.width)
    ds = create_scan_dataset(root / "fly", plan, rig={"name": rig.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    # the speed as 'lfstudio scan --fly' decides it
    session = ScanSession(ScanRequest(root / "fly", time_scale=ts, fly=True, fly_trigger=args.trigger))
    decided = session._decide_fly(studio.rig, studio.camera, plan, None, rig)
    print(f"trigger: {decided['trigger']}; speed {decided['speed_mm_s']:.1f} mm/s ({decided['binding']} binds); limits "
          + ", ".join(f"{k} {v:.4g}" for k, v in decided["limits_mm_s"].items())
          + f" mm/s; planned motion {decided['time_s']:.0f} s; controller reports {decided['report_rate_hz']:.0f}/s "
            "(simulated time)")
    engine = FlyScanEngine(ds, plan, studio.rig, studio.camera, time_scale=ts, speed_mm_s=decided["speed_mm_s"],
                           trigger=decided["trigger"])
    with Timer() as m:
        engine.start()
        state = engine.wait(24 * 3600)
    studio.close()
    assert state is ScanState.FINISHED, engine.message
    wall = m.wall_s
    done = Dataset.open(ds.root)
    blur, errors, unseen, added, rows_seen = [], [], [], [], set()
    for v in done.views:
        fly = v.get("fly") or {}
        if "recorded_mm" not in fly:
            continue
        truth = json.loads((done.root / v["sidecars"][1]).read_text())
        blur.append(truth["blur_px_near"])
        rec, true = fly["recorded_mm"], truth["true_position_mm"]
        rep_err = truth.get("repeatability_error_mm", [0.0, 0.0])
        errors.append((rec[0] - true[0], rec[1] - true[1]))
        unseen.append((rep_err[0], rep_err[1]))
        added.append((rec[0] - (true[0] - rep_err[0]), rec[1] - (true[1] - rep_err[1])))
        rows_seen.add(fly["pass"])
    flown = len(errors)

    def rms(pairs, axis=None):
        if not pairs:
            return float("nan")
        if axis is None:
            return math.sqrt(statistics.fmean(a * a + b * b for a, b in pairs))
        return math.sqrt(statistics.fmean(p[axis] ** 2 for p in pairs))
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
    print(f"recorded position vs truth: RMS {1000 * rms(errors):.0f} µm (x {1000 * rms(errors, 0):.0f}, "
          f"y {1000 * rms(errors, 1):.0f}; target ≤ 80 µm), over {flown} views in {len(rows_seen)} rows")
    print(f"  of which the rig's repeatability (seen by no report; a step scan records it as wrongly): RMS "
          f"{1000 * rms(unseen):.0f} µm (x {1000 * rms(unseen, 0):.0f}, y {1000 * rms(unseen, 1):.0f}; "
          f"{len(rows_seen)} draws, σ {rig.horizontal.repeatability_um:g} / {rig.vertical.repeatability_um:g} µm)")
    print(f"  added by the fly recording ({decided['trigger']} trigger): RMS {1000 * rms(added):.1f} µm "
          f"(x {1000 * rms(added, 0):.1f}, y {1000 * rms(added, 1):.1f})")
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
    if args.calibrate:
        calibrate_fly(args, rig, plan, root, studio_for, decided, ts)
    if args.keep is None:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    if not flown:
        print(f"FAILED: no view was taken on the fly ({engine.rows_flown} rows flown, {engine.retaken} views taken "
              "again standing still): no blur or position figure of a fly scan", file=sys.stderr)
        return 1
    return 0


def calibrate_fly(args, rig, plan, root, studio_for, decided, ts) -> None:
    """Fly the default calibration views at --calibrate-width, calibrate, compare with the truth."""
    import subprocess

    import numpy as np

    from lfstudio.calibration.pairs import DEFAULT_VIEWS
    from lfstudio.calibration.model import CalibrationUncertainty, rotation_angle_deg, rotation_matrix
    from lfstudio.calibration.uncertainty import corner_probes, metric_of, probe_errors
    from lfstudio.dataset import Dataset
    from lfstudio.scan.events import ScanState
    from lfstudio.scan.fly import FlyScanEngine
    from lfstudio.studio.session import create_scan_dataset, describe_camera

    cells = [tuple(v) for v in plan.grid.select(DEFAULT_VIEWS, [(r, c) for r in range(plan.rows)
                                                                 for c in range(plan.columns)])]
    sub = plan.with_subset(cells)
    studio = studio_for(args.calibrate_width, crop=False)
    # 1 ms instead of the reference 0.5 s: as bright as the reference exposure (strobe light, a bright
    # studio) through ISO and aperture, so the views have the texture the features need
    studio.camera.iso, studio.camera.aperture = 1600, 2.8
    camera_info, lens = describe_camera(studio.camera, None)     # focal length, pixel pitch: as a scan records
    ds = create_scan_dataset(root / "calib", sub, rig={"name": rig.name}, camera=camera_info, lens=lens)
    ds.manifest["acquisition"] = {"mode": "fly", "positions": "recorded", **decided}
    ds.save()
    engine = FlyScanEngine(ds, sub, studio.rig, studio.camera, time_scale=ts, speed_mm_s=decided["speed_mm_s"],
                           trigger=decided["trigger"])
    t0 = time.monotonic()
    engine.start()
    state = engine.wait(24 * 3600)
    studio.close()
    assert state is ScanState.FINISHED, engine.message
    done = Dataset.open(ds.root)
    flown = sum(1 for v in done.views if "recorded_mm" in (v.get("fly") or {}))
    print(f"calibration views ({DEFAULT_VIEWS}, {len(cells)} views at {args.calibrate_width} px): flown in "
          f"{(time.monotonic() - t0) / ts:.0f} s simulated, {flown} on the fly, {engine.retaken} taken again")
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "lfstudio", "calibrate", str(ds.root), "--json", "--no-save"],
                          capture_output=True, text=True, timeout=3600)
    print(f"lfstudio calibrate: {time.monotonic() - t0:.0f} s wall")
    if proc.returncode != 0:
        print(f"calibration failed: {proc.stderr.strip().splitlines()[-1:]}")
        return
    doc = json.loads(proc.stdout)
    first = next(v for v in done.views if v.get("sidecars"))
    truth = json.loads((done.root / first["sidecars"][1]).read_text())
    u = CalibrationUncertainty.from_document(doc)
    if u is None:
        print("calibration: no uncertainty in its document, no corner probes")
        return
    probes = corner_probes(doc["image_size_px"], u.row_disparity_px, u.column_disparity_px)
    params = list(doc["rotation_deg"]) + list(doc["principal_point_offset_px"])
    true = list(truth["rotation_deg"]) + list(truth["pp_offset_px"])
    errs = probe_errors(probes, params, true, doc["focal_length_px"], doc["image_size_px"])
    rot = rotation_angle_deg(rotation_matrix(np.array(doc["rotation_deg"])), rotation_matrix(np.array(truth["rotation_deg"])))
    print(f"calibration on the fly-scanned grid: true rectification error RMS {metric_of(errs, 'rms'):.4f} px, "
          f"max {metric_of(errs, 'max'):.4f} px at the corner probes of a full row and column (target ≤ 0.05 px "
          f"RMS); rotation error {rot:.4f}° (estimate {np.round(doc['rotation_deg'], 3).tolist()}°, true "
          f"{truth['rotation_deg']}°); stated corner error 1σ/2σ {u.corner_error_px[0]:.3f}/{u.corner_error_px[1]:.3f} px")


if __name__ == "__main__":
    sys.exit(main())
