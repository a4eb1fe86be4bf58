"""Dataset quality check: time per view at 2000 px, the disparity map's error against the virtual
studio's ground truth, and the report's time on a clean 9 x 9 render against calibrating it.

    ./.venv/bin/python benchmarks/quality_check.py [--width 2000] [--grid 9x9] [--keep DIR]

Renders a clean virtual-studio dataset (DNG, the demo orientation error), calibrates it with the
default 2 x 3 views (``lfstudio calibrate``: cold feature cache) and checks it (``lfstudio check``,
uncalibrated, nothing written), ``--repeat`` times each, interleaved; prints the best wall and CPU
time (``time.process_time``, all threads) of each, since this machine's two cores are shared.
Then checks once more with the calibration and writes the report, and compares the disparity map
of the centre view with the ground truth.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402


def timed(fn, *args, **kwargs):
    t, c = time.perf_counter(), time.process_time()
    result = fn(*args, **kwargs)
    return result, time.perf_counter() - t, time.process_time() - c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=2000, help="image width in px (default 2000)")
    ap.add_argument("--grid", default="9x9", help="columns x rows (default 9x9)")
    ap.add_argument("--keep", type=Path, help="render into (and keep) this folder; reused when it exists")
    ap.add_argument("--repeat", type=int, default=3, help="time calibrate and check this many times (default 3)")
    args = ap.parse_args()
    cols, rows = (int(v) for v in args.grid.lower().split("x"))

    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import save_calibration
    from lfstudio.dataset import Dataset
    from lfstudio.quality import check_dataset
    from lfstudio.sim.studio import DEMO_ROTATION_DEG
    from lfstudio.sim.virtual_dataset import make_virtual_dataset, true_disparity_px

    root = args.keep or Path(tempfile.mkdtemp(prefix="lfstudio-quality-bench-")) / "dataset"
    if (root / "dataset.json").is_file():
        ds = Dataset.open(root)
        print(f"dataset: {root} (reused)")
    else:
        ds, wall, cpu = timed(make_virtual_dataset, root, cols, rows, width_px=args.width, fmt="dng",
                              rotation_deg=DEMO_ROTATION_DEG, workers=2)
        print(f"dataset: {root}: {cols} x {rows} views, {args.width} px DNG, rendered in {wall:.1f} s")
    n = len(ds.done_views())
    (root / "calibration.json").unlink(missing_ok=True)

    cal_runs, check_runs = [], []
    for _ in range(args.repeat):
        for cache in (root / "cache" / "features").glob("*.npz"):
            cache.unlink()
        run, wall, cpu = timed(calibrate_dataset, Dataset.open(root), "array:3x2")
        cal_runs.append((wall, cpu))
        report, wall, cpu = timed(check_dataset, Dataset.open(root), write=False)
        check_runs.append((wall, cpu))
    save_calibration(ds, run.document)
    report, wall, cpu = timed(check_dataset, Dataset.open(root))      # with the calibration, written
    doc = report.document
    (cw, cc), (kw, kc) = (min(x[0] for x in cal_runs), min(x[1] for x in cal_runs)), \
        (min(x[0] for x in check_runs), min(x[1] for x in check_runs))
    print(f"best of {args.repeat} (the machine is shared; medians: calibrate "
          f"{np.median([x[0] for x in cal_runs]):.2f} s, check {np.median([x[0] for x in check_runs]):.2f} s wall)")
    print(f"calibrate (2 x 3 views, cold):   wall {cw:6.2f} s   CPU {cc:6.2f} s")
    print(f"check ({n} views):               wall {kw:6.2f} s   CPU {kc:6.2f} s   "
          f"-> {1000 * kw / n:.0f} ms wall, {1000 * kc / n:.0f} ms CPU per view at {args.width} px")
    print(f"check / calibrate:              wall {kw / cw:.2f}   CPU {kc / cc:.2f}")
    print(f"check with the calibration and writing the report: wall {wall:.2f} s, CPU {cpu:.2f} s")
    print(f"verdict {doc['verdict']}: {doc['summary']['pass']} pass, {doc['summary']['warn']} warn, "
          f"{doc['summary']['fail']} fail")
    depth = doc["depth_range"]
    print(f"depth range: {depth['near_m']:.3f} – {depth['far_m']:.3f} m measured, planned "
          f"{depth['planned_near_m']:.2f} – {depth['planned_far_m']:.2f} m "
          f"({100 * (depth['near_m'] / depth['planned_near_m'] - 1):+.1f} %, "
          f"{100 * (depth['far_m'] / depth['planned_far_m'] - 1):+.1f} %)")
    rep = doc["repeatability"]
    print(f"position scatter of the clean render (the measurement's own noise): x {rep['x_um']:.1f} µm, "
          f"y {rep['y_um']:.1f} µm")
    d = report.disparity
    truth = true_disparity_px(root, *d.cell, (d.disparity_px.shape[1], d.disparity_px.shape[0]),
                              rectified=doc["calibration"]["used"])
    valid = np.isfinite(d.disparity_px)
    err = np.abs(d.disparity_px[valid] - truth[valid])
    print(f"disparity map of view r{d.cell[0]:02d} c{d.cell[1]:03d} ({d.disparity_px.shape[1]} px wide, "
          f"{', '.join(p['direction'] + ' ' + str(p['steps']) for p in d.partners)} steps): "
          f"median |error| {np.median(err):.3f} px, p90 {np.percentile(err, 90):.3f} px "
          f"(scene {np.percentile(truth, 1):.2f} … {np.percentile(truth, 99):.2f} px between neighbours), "
          f"{valid.mean():.1%} of pixels matched")
    return 0


if __name__ == "__main__":
    sys.exit(main())
