"""Exposure brackets (#32): the merge's accuracy against the virtual studio's true radiance, the
clipped share before and after, the scan time per view with 3 frames vs 1, and processing CPU per
view with the merge.

    ./.venv/bin/python benchmarks/hdr_bracket.py [--width 640] [--views 3] [--time-scale 0.1]

1. Accuracy: a -2,0,+2 EV bracketed scan (instant rig, the simulated camera writing real 14-bit DNGs
   with photon and read noise) of a scene with a highlight (``highlight_gain`` 3: a disc up to 3x
   white, clipped at the middle exposure). Each view's merged radiance (``lfstudio process``'s merge,
   no rectification, no resampling: the captured frame) against the rendered truth, and the single
   middle (0 EV) frame developed alone (its values / full scale: the same unit): median relative
   error in the region the middle exposure clips (truth > 1 in a channel) and in the unclipped one
   (0.05 < truth < 0.8). Clipped share: of the middle frame, and of the merge (clipped in every frame).
2. Scan time per view on the GRBL simulator + simulated camera at its timings (4 mm moves, settle
   0.3 s, exposure 0.5 s at 0 EV, transfer 2.5 s, trigger 0.05 s), 1 frame vs -2,0,+2, from the
   engine's per-view period (in simulated seconds; ``--time-scale`` shortens everything alike), against
   the limit: the camera's part frames x (trigger + exposure) + (frames - 1) x transfer (the camera
   takes a frame only once the previous one is downloaded), the last transfer overlapped with the next
   move and settle.
3. Processing CPU per view: the 16-bit processing alone, and the merge (decode of every frame, weights,
   writing EXR and preview) from each view's own CPU time (``timings_s.cpu``), one process.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from _datasets import studio_scan, view_periods  # noqa: E402
from _measure import Timer, load_text  # noqa: E402
from lfstudio.dataset import Dataset, images  # noqa: E402
from lfstudio.dataset.bracket import parse_bracket  # noqa: E402
from lfstudio.dataset.profile import Profile  # noqa: E402
from lfstudio.optics import move_time_s  # noqa: E402
from lfstudio.processing.hdr import MergeOptions, merge_dataset, read_radiance  # noqa: E402
from lfstudio.processing.pipeline import process_dataset  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.scan.engine import ScanEngine  # noqa: E402
from lfstudio.scan.events import ScanState  # noqa: E402
from lfstudio.scan.scan_plan import ScanPlan  # noqa: E402
from lfstudio.sim.instant import InstantRig  # noqa: E402
from lfstudio.sim.sim_camera import SimulatedCamera  # noqa: E402
from lfstudio.sim.studio import VirtualStudio  # noqa: E402
from lfstudio.studio.session import create_scan_dataset  # noqa: E402

BRACKET = parse_bracket("-2,0,+2")
SETTLE_S, EXPOSURE_S, TRANSFER_S = 0.3, 0.5, 2.5


def linear_profile() -> Profile:
    profile = Profile()
    for step in (profile.color, profile.deflicker, profile.shading, profile.rectify, profile.resample):
        step.enabled = False
    return profile


def accuracy(root: Path, width: int, views: int) -> None:
    rig_cfg = load_rig()
    plan = replace(ScanPlan.centered(views, 1, (4.0, 6.0), rig_cfg, settle_s=0.0), bracket=BRACKET)
    studio = VirtualStudio(width_px=width, view_region_mm=plan.extent_mm(), highlight_gain=3.0, seed=3)
    rig = InstantRig(rig_cfg)
    rig.connect()
    camera = SimulatedCamera(studio, rig.true_position_mm, exposure_s=EXPOSURE_S, time_scale=0.0, noise=0.002)
    camera.connect()
    ds = create_scan_dataset(root, plan, rig={"name": rig_cfg.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    engine = ScanEngine(ds, plan, rig, camera, time_scale=0.0)
    engine.start()
    if engine.wait() is not ScanState.FINISHED:
        raise SystemExit(f"scan did not finish: {engine.message}")
    profile = linear_profile()
    with Timer() as t_proc:
        processed = process_dataset(root, profile, workers=0, force=True)
    with Timer() as t_merge:
        report = merge_dataset(root, MergeOptions(), profile, workers=0, force=True)
    ds = Dataset.open(root)
    rows = {"merged": {"clipped": [], "unclipped": []}, "middle frame": {"clipped": [], "unclipped": []}}
    clipped_before, clipped_after, shifts = [], [], []
    for v in ds.done_views():
        truth = studio.render(*v["commanded_mm"])
        hot = truth.max(axis=2) > 1.0
        calm = (truth.max(axis=2) < 0.8) & (truth.min(axis=2) > 0.05)
        merged = read_radiance(ds.root / v["hdr"]["file"])
        middle = images.develop(ds.path_of(v), profile.debayer).astype(np.float32) / 65535.0
        for name, img in (("merged", merged), ("middle frame", middle)):
            rel = np.abs(img - truth) / np.maximum(truth, 1e-3)
            rows[name]["clipped"].append(float(np.median(rel[hot])))
            rows[name]["unclipped"].append(float(np.median(rel[calm])))
        hdr = v["hdr"]
        clipped_before.append(hdr["clipped_fraction"]["frames"][hdr["reference_frame"]])
        clipped_after.append(hdr["clipped_fraction"]["merged"])
        shifts.append(hdr["max_misalignment_px"] or 0.0)
    print(f"1. accuracy ({views} views, {width} px, -2,0,+2 EV, highlight up to 3x white; {load_text()})")
    print(f"   {'':14s} {'median rel. error, clipped region':>34s} {'unclipped region':>18s}")
    for name, r in rows.items():
        print(f"   {name:14s} {100 * np.median(r['clipped']):33.2f} % {100 * np.median(r['unclipped']):16.2f} %")
    print(f"   clipped share: middle frame {100 * np.mean(clipped_before):.3f} %, merged {100 * np.mean(clipped_after):.3f} %"
          f"; frame misalignment (still rig) max {max(shifts):.3f} px")
    cpu_proc = np.mean([v["processed"]["timings_s"]["cpu"] for v in ds.done_views()])
    cpu_merge = np.mean([v["hdr"]["timings_s"]["cpu"] for v in ds.done_views()])
    print(f"3. processing CPU per view at {width} px: 16-bit views {cpu_proc:.3f} s, merge of 3 frames {cpu_merge:.3f} s "
          f"({cpu_merge / cpu_proc:.1f}x); whole runs {t_proc.cpu_s:.2f} / {t_merge.cpu_s:.2f} CPU-s "
          f"({processed.processed} / {report.merged} views)")


def scan_period(frames_bracket, columns: int, scale: float, width: int) -> tuple[float, float]:
    """(median period per view in simulated s, the limit) on the GRBL simulator + simulated camera."""
    rig = load_rig()
    plan = replace(ScanPlan.centered(columns, 1, (4.0, 6.0), rig, settle_s=SETTLE_S), bracket=frames_bracket)
    with studio_scan("sim", plan, rig, scale=scale, exposure_s=EXPOSURE_S, transfer_s=TRANSFER_S,
                     width_px=width) as (engine, _ds, trigger):
        periods = view_periods(engine)
        engine.start()
        if engine.wait() is not ScanState.FINISHED:
            raise SystemExit(f"scan did not finish: {engine.message}")
    times = frames_bracket.shutter_times_s(EXPOSURE_S) if frames_bracket else (EXPOSURE_S,)
    h = rig.horizontal
    move = move_time_s(4.0, h.max_speed_mm_s, h.acceleration_mm_s2)
    limit = sum(trigger + t for t in times) + (len(times) - 1) * TRANSFER_S + max(TRANSFER_S, move + SETTLE_S)
    measured = [p / scale for p in periods if p is not None]
    return float(np.median(measured)), limit


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=640, help="image width of the accuracy scan (px)")
    ap.add_argument("--views", type=int, default=3, help="views of the accuracy scan")
    ap.add_argument("--columns", type=int, default=5, help="views of each timed scan")
    ap.add_argument("--time-scale", type=float, default=0.1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        accuracy(Path(tmp) / "ds", args.width, args.views)
    one, one_limit = scan_period(None, args.columns, args.time_scale, 160)
    three, three_limit = scan_period(BRACKET, args.columns, args.time_scale, 160)
    print(f"2. scan period per view (simulated s, time scale {args.time_scale:g}; {load_text()})")
    print(f"   1 frame:  {one:6.2f} s (limit {one_limit:.2f} s, ratio {one / one_limit:.3f})")
    print(f"   3 frames: {three:6.2f} s (limit {three_limit:.2f} s, ratio {three / three_limit:.3f}); "
          f"3 frames / 1 frame = {three / one:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
