"""Self-calibration on real gantry photographs against a rotation hidden in them (issue 26, item 4).

The Stanford "Chess" 5 × 5 (../shared/data/lightfield/stanford_chess_5x5; skipped when absent) is a
real gantry light field, published rectified (and sheared so that a plane inside the scene has zero
disparity). Its views are calibrated

1. as published: the truth is no rotation (up to how well the archive rectified them);
2. each view turned by a known rotation (``--turn``, a camera turned by it sees the published view
   through ``H⁻¹``, as tests/calibration/test_observability.py does with the Middlebury pair).

Both are imported as another rig's images would be: ``import-images --positions names`` (the gantry's
recorded positions; the calibration takes its baselines from them), the focal length stated
(``--focal-length-px``, not known for the archive: 1400 px), the zero-disparity plane stated (the
archive does not publish it; ``--zero-depth-m``, default 90 % of the farthest the views allow, as
measured by the import). Printed per angle: the estimate, the stated 1σ, the error against the truth
and its z (error / σ); the target is |z| ≤ 2 (the stated 2σ covers the truth) for every angle.

    ./.venv/bin/python benchmarks/real_gantry_calibration.py [--turn 1.0,-1.5,2.0] [--views all] [--zero-depth-m D]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfstudio.calibration.calibrate import calibrate_dataset  # noqa: E402
from lfstudio.calibration.model import rectifying_homography  # noqa: E402
from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.zero_plane import zero_plane  # noqa: E402
from lfstudio.export.import_images import ImportOptions, import_images  # noqa: E402
from lfstudio.quality.shear import measure_shear  # noqa: E402

STANFORD = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lightfield" / "stanford_chess_5x5"


def turned_copy(out: Path, turn: tuple[float, float, float], f_px: float) -> Path:
    out.mkdir(parents=True)
    for p in sorted(STANFORD.glob("out_*.png")):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if any(turn):
            h, w = img.shape[:2]
            H = rectifying_homography(turn, f_px, (w, h))
            img = cv2.warpPerspective(img, np.linalg.inv(H), (w, h), flags=cv2.INTER_CUBIC)
        cv2.imwrite(str(out / p.name), img)
    return out


def calibrate(folder: Path, out: Path, truth: tuple[float, float, float], f_px: float, zero_m: float,
              views: str, label: str) -> int:
    ds = Dataset.open(import_images(ImportOptions(folder=folder, out=out, grid=(5, 5), spacing_mm=None,
                                                  positions="names", focal_length_px=f_px,
                                                  zero_disparity_depth_m=zero_m)))
    t0 = time.process_time()
    doc = calibrate_dataset(ds, views).document
    rot, std = np.array(doc["rotation_deg"]), np.array(doc["rotation_std_deg"])
    err = rot - np.asarray(truth)
    z = err / std
    print(f"\n{label} (truth rx {truth[0]:+.3f}°  ry {truth[1]:+.3f}°  rz {truth[2]:+.3f}°), views {views}, "
          f"{doc['residual_px']['after']['rms']:.3f} px RMS after, {time.process_time() - t0:.0f} s CPU:")
    print("| angle | estimate | stated 1σ | error | z |")
    print("| --- | --- | --- | --- | --- |")
    for k, name in enumerate(("rx", "ry", "rz")):
        print(f"| {name} | {rot[k]:+.3f}° | {std[k]:.3f}° | {err[k]:+.3f}° | {z[k]:+.1f} |")
    for w in doc["warnings"]:
        print(f"  ! {w}")
    return int(np.sum(np.abs(z) > 2.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--turn", default="1.0,-1.5,2.0", help="the hidden rotation rx,ry,rz (deg)")
    ap.add_argument("--views", default="all")
    ap.add_argument("--focal-length-px", type=float, default=1400.0)
    ap.add_argument("--zero-depth-m", type=float, default=None)
    args = ap.parse_args()
    if not STANFORD.is_dir():
        print("Stanford Chess: ../shared/data not present, skipped")
        return
    turn = tuple(float(v) for v in args.turn.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        zero_m = args.zero_depth_m
        if zero_m is None:
            ds = Dataset.open(import_images(ImportOptions(folder=STANFORD, out=base / "measured", grid=(5, 5),
                                                          spacing_mm=None, positions="names",
                                                          focal_length_px=args.focal_length_px, measure=measure_shear)))
            limit = zero_plane(ds).measured["depth_max_m"]
            zero_m = 0.9 * limit
            print(f"zero-disparity plane stated at {zero_m:.2f} m (the views put it nearer than {limit:.2f} m)")
        misses = calibrate(STANFORD, base / "published", (0.0, 0.0, 0.0), args.focal_length_px, zero_m, args.views,
                           "as published")
        misses += calibrate(turned_copy(base / "turned", turn, args.focal_length_px), base / "turned_ds", turn,
                            args.focal_length_px, zero_m, args.views, f"turned by {args.turn}")
    print(f"\nangles outside their stated 2σ: {misses} of 6 (target 0)")


if __name__ == "__main__":
    main()
