"""Time to self-calibrate from the paper's 2 × 3 subsample at ~4000 px width (target < 30 s on two cores).

    python benchmarks/calibration_speed.py [--width 4000] [--fmt dng|png] [--keep DIR]

Renders a virtual-studio dataset of the 2 × 3 array (columns 200 mm apart = 0, 50, 100 × 4 mm; rows
120 mm apart = 0, 20 × 6 mm) with a known orientation error, then times ``calibrate_dataset`` cold
(features detected) and warm (features from the cache), and prints the accuracy against the truth.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import argparse
import json
import tempfile
import time
from pathlib import Path

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.dataset import Dataset
from lfstudio.sim.virtual_dataset import make_virtual_dataset

TARGET_S = 30.0
ROT = (1.5, -2.0, 2.5)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--fmt", choices=("dng", "png"), default="dng")
    ap.add_argument("--keep", metavar="DIR", help="render into / reuse this folder")
    args = ap.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="lfstudio-calbench-")) / "ds"
    if not (root / "dataset.json").is_file():
        t0 = time.perf_counter()
        make_virtual_dataset(root, 3, 2, spacing_mm=(200.0, 120.0), width_px=args.width, rotation_deg=ROT,
                             position_noise_um=(80.0, 50.0), seed=11, fmt=args.fmt, workers=2)
        print(f"rendered 6 views {args.width} px ({args.fmt}) in {time.perf_counter() - t0:.1f} s")
    ds = Dataset.open(root)
    for cache in (root / "cache" / "features").glob("*.npz"):
        cache.unlink()
    t0 = time.perf_counter()
    run = calibrate_dataset(ds, "all")
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrate_dataset(ds, "all")
    warm = time.perf_counter() - t0
    truth = json.loads((root / "ground_truth.json").read_text())
    doc = run.document
    err = rotation_angle_deg(rotation_matrix(doc["rotation_deg"]), rotation_matrix(truth["rotation_deg"]))
    print(f"image {doc['image_size_px'][0]} x {doc['image_size_px'][1]} px, detection at "
          f"{doc['settings']['max_width_px']} px, {len(doc['pairs'])} pairs, "
          f"{doc['fit']['matches_used']} matches used")
    print(f"calibrate cold (detect + match + fit): {cold:.1f} s   target < {TARGET_S:.0f} s   "
          f"ratio {cold / TARGET_S:.2f}")
    print(f"calibrate warm (features cached):      {warm:.1f} s")
    print(f"rotation error vs truth: {err:.4f}°   residual RMS {doc['residual_px']['before']['rms']:.2f} -> "
          f"{doc['residual_px']['after']['rms']:.2f} px")


if __name__ == "__main__":
    main()
