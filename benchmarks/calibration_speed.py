"""Time to self-calibrate at ~4000 px: the paper's 2 × 3 subsample (cold < 30 s, warm < 3 s) and the
default 3 × 5 array (cold < 60 s), on two cores.

    python benchmarks/calibration_speed.py [--array 2x3|3x5] [--width 4000] [--fmt dng|png] [--keep DIR]

Renders a virtual-studio dataset holding exactly the array's views of the reference grid (columns
spread over 400 mm, rows over 120 mm: the 2 × 3 array is columns 0, 50, 100 × 4 mm and rows 0, 20 ×
6 mm) with a known orientation error and the reference rig's position noise, then times
``calibrate_dataset`` cold (features detected) and warm (features from the cache), each as wall
time and CPU time (all threads) with the load average, and prints the accuracy against the truth.
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
from lfstudio.dataset import Dataset
from lfstudio.sim.virtual_dataset import make_virtual_dataset

TARGETS_S = {"2x3": {"cold": 30.0, "warm": 3.0}, "3x5": {"cold": 60.0}, "5x5": {"cold": 60.0}, "5x9": {"cold": 60.0}}
ROT = (1.5, -2.0, 2.5)


def _timed(ds):
    with Timer() as span:
        run = calibrate_dataset(ds, "all")
    return run, span.wall_s, span.cpu_s


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--array", choices=sorted(TARGETS_S), default="2x3")
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--fmt", choices=("dng", "png"), default="dng")
    ap.add_argument("--keep", metavar="DIR", help="render into / reuse this folder")
    args = ap.parse_args()
    rows, cols = (int(x) for x in args.array.split("x"))
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="lfstudio-calbench-")) / "ds"
    if not (root / "dataset.json").is_file():
        t0 = time.perf_counter()
        make_virtual_dataset(root, cols, rows, spacing_mm=(400.0 / (cols - 1), 120.0 / (rows - 1)),
                             width_px=args.width, rotation_deg=ROT, position_noise_um=(80.0, 50.0), seed=11,
                             fmt=args.fmt, workers=2)
        print(f"rendered {rows * cols} views {args.width} px ({args.fmt}) in {time.perf_counter() - t0:.1f} s")
    ds = Dataset.open(root)
    for cache in (root / "cache" / "features").glob("*.npz"):
        cache.unlink()
    print(f"before: {load_text()}")
    run, cold, cold_cpu = _timed(ds)
    _, warm, warm_cpu = _timed(ds)
    truth = json.loads((root / "ground_truth.json").read_text())
    doc = run.document
    err = rotation_angle_deg(rotation_matrix(doc["rotation_deg"]), rotation_matrix(truth["rotation_deg"]))
    print(f"array {args.array}: image {doc['image_size_px'][0]} x {doc['image_size_px'][1]} px, detection at "
          f"{doc['settings']['max_width_px']} px, {len(doc['views_used'])} views, {len(doc['pairs'])} pairs, "
          f"{doc['fit']['matches_used']} matches used")
    targets = TARGETS_S[args.array]
    for name, wall, cpu in (("cold (detect + match + fit)", cold, cold_cpu), ("warm (features cached)", warm, warm_cpu)):
        key = name.split()[0]
        target = f"   target < {targets[key]:.0f} s   ratio {wall / targets[key]:.2f}" if key in targets else ""
        print(f"calibrate {name:28} wall {wall:5.1f} s   CPU {cpu:5.1f} s{target}")
    print(f"after: {load_text()}")
    u = doc["uncertainty"]
    print(f"rotation error vs truth: {err:.4f}°   stated 1σ per angle {', '.join(f'{s:.4f}°' for s in u['rotation_std_deg'])}"
          f"   residual RMS {doc['residual_px']['before']['rms']:.2f} -> {doc['residual_px']['after']['rms']:.2f} px")


if __name__ == "__main__":
    main()
