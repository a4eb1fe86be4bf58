"""Time to self-calibrate at ~4000 px on two cores: the default views (cold < 60 s) and the paper's
2 × 3 subsample (cold < 30 s, warm < 3 s).

    python benchmarks/calibration_speed.py [--views default|array:3x2|SPEC] [--width 4000] [--fmt dng|png] [--keep DIR]
                                           [--profile]

Renders a virtual-studio dataset of the reference grid (101 × 21 positions, 4 mm × 6 mm apart)
holding only the chosen views (``--views``: a selection as ``lfstudio calibrate --views`` reads it;
default: what ``lfstudio calibrate`` uses without one) with a known orientation error and the
reference rig's position noise, then times ``calibrate_dataset`` cold (features detected) and warm
(features from the cache), each as wall time and CPU time (this process and its workers) with the
load average, and prints the accuracy against the truth. ``--profile`` adds where the cold run's
time went (detection, matching, fit).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import argparse
import json
import tempfile
import time

from _measure import Timer, load_text
from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.calibration.pairs import DEFAULT_VIEWS
from lfstudio.dataset import Dataset
from lfstudio.dataset.grid import Grid
from lfstudio.sim.virtual_dataset import make_virtual_dataset

GRID = Grid(101, 21, (4.0, 6.0))
TARGETS_S = {"default": {"cold": 60.0}, "array:3x2": {"cold": 30.0, "warm": 3.0}}
ROT = (1.5, -2.0, 2.5)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="default", help="the views to render and calibrate (default: the default)")
    ap.add_argument("--array", dest="views", help=argparse.SUPPRESS)      # the older spelling
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--fmt", choices=("dng", "png"), default="dng")
    ap.add_argument("--keep", metavar="DIR", help="render into / reuse this folder")
    ap.add_argument("--profile", action="store_true", help="print the cold run's stage times")
    args = ap.parse_args()
    spec = DEFAULT_VIEWS if args.views == "default" else args.views
    chosen = GRID.select(spec, GRID.views(), field_name="--views")
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="lfstudio-calbench-")) / "ds"
    if not (root / "dataset.json").is_file():
        t0 = time.perf_counter()
        make_virtual_dataset(root, GRID.columns, GRID.rows, spacing_mm=GRID.step_mm, width_px=args.width,
                             rotation_deg=ROT, position_noise_um=(80.0, 50.0), seed=11, fmt=args.fmt, workers=2,
                             only_views=chosen)
        print(f"rendered {len(chosen)} views {args.width} px ({args.fmt}) in {time.perf_counter() - t0:.1f} s")
    ds = Dataset.open(root)
    for cache in (root / "cache" / "features").glob("*.npz"):
        cache.unlink()
    stages: list[tuple[float, str]] = []

    def progress(done, total, message=""):
        stages.append((time.perf_counter(), message))

    print(f"before: {load_text()}")
    with Timer() as cold:
        run = calibrate_dataset(ds, spec, progress=progress)
    cold_stages = list(stages)
    with Timer() as warm:
        calibrate_dataset(ds, spec)
    truth = json.loads((root / "ground_truth.json").read_text())
    doc = run.document
    err = rotation_angle_deg(rotation_matrix(doc["rotation_deg"]), rotation_matrix(truth["rotation_deg"]))
    print(f"views {args.views} ({spec}): image {doc['image_size_px'][0]} x {doc['image_size_px'][1]} px, detection "
          f"at {doc['settings']['max_width_px']} px, {len(doc['views_used'])} views, {len(doc['pairs'])} pairs "
          f"({doc['settings']['pair_set']}), {doc['fit']['matches_used']} matches used")
    targets = TARGETS_S.get(args.views, {})
    for name, span in (("cold (detect + match + fit)", cold), ("warm (features cached)", warm)):
        key = name.split()[0]
        target = f"   target < {targets[key]:.0f} s   ratio {span.wall_s / targets[key]:.2f}" if key in targets else ""
        print(f"calibrate {name:28} wall {span.wall_s:5.1f} s   CPU {span.cpu_s:5.1f} s   "
              f"({span.cores_used:.2f} cores){target}")
    if args.profile and cold_stages:
        t0 = cold_stages[0][0]
        detected = max((t for t, m in cold_stages if m.startswith("features")), default=t0)
        fitting = next((t for t, m in cold_stages if m.startswith("fitting")), detected)
        print(f"cold stages (wall): detection {detected - t0:.1f} s, matching {fitting - detected:.1f} s, "
              f"fit + report {cold.wall_s - (fitting - t0):.1f} s")
    print(f"after: {load_text()}")
    u = doc["uncertainty"]
    print(f"rotation error vs truth: {err:.4f}°   stated 1σ per angle {', '.join(f'{s:.4f}°' for s in u['rotation_std_deg'])}"
          f"   residual RMS {doc['residual_px']['before']['rms']:.2f} -> {doc['residual_px']['after']['rms']:.2f} px")


if __name__ == "__main__":
    main()
