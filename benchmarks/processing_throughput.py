"""Processing throughput at 4000 x 2668 px DNG input: the default path against the former one, per
core, and the scaling from one local worker to two.

    ./.venv/bin/python benchmarks/processing_throughput.py [--views 150] [--width 4000]

Three runs in this one invocation, each on a dataset of hard-linked virtual-studio DNGs (6 distinct
renders, cached in /tmp): the former default path (LibRaw AHD, zlib's default PNG strategy: the
profile still selects it) on one worker with views/2 views, the default path on one worker with
``--views`` views and on two workers with twice as many. Per run: wall and CPU seconds (this process
plus its worker processes), views per CPU-second (the per-core speed, robust to other load), and
the time until the first view is finished (start-up plus one view: an upper bound of the start-up,
target < 5 % of the run). Targets: >= 2x the former path's views per CPU-second; two workers
>= 1.8x one worker's views per wall second (only meaningful when the machine gives us two cores:
the line prints how many cores the run got, CPU-s per wall-s, and the load average), and the same
from CPU time, which the load does not decide: each view's CPU in its worker (``timings_s.cpu``),
shared between the workers, plus all the run's other CPU (start-up, the parent's reference
statistics, manifest saves, result handling) counted as serial.
Quality of each path against the ground truth: benchmarks/processing_quality.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _measure import Timer, load_text  # noqa: E402
from _processing import default_profile, linked, rendered, todays_profile  # noqa: E402

UNIQUE_VIEWS = 6


def run(root: Path, source, n_views: int, profile, workers: int, label: str) -> dict:
    from lfstudio.processing.pipeline import process_dataset

    ds = linked(root, source, n_views)
    first: dict[str, float] = {}
    t0 = time.perf_counter()
    with Timer() as span:
        report = process_dataset(ds.root, profile, workers=workers, force=True,
                                 on_view=lambda r: first.setdefault("t", time.perf_counter()))
    assert report.ok and report.processed == n_views, report.failed
    views = json.loads((ds.root / "dataset.json").read_text())["views"]
    steps = {k: sum(v["processed"]["timings_s"][k] for v in views) for k in ("decode", "process", "encode")}
    view_cpu_s = sum(v["processed"]["timings_s"]["cpu"] for v in views)   # in the workers, per task
    start = first["t"] - t0
    # on `workers` free cores: everything but the views' own CPU counted as serial (start-up, the
    # parent's reference statistics and saves, worker imports: a pessimistic bound), the views shared
    free_s = (span.cpu_s - view_cpu_s) + view_cpu_s / workers
    r = {"label": label, "views": n_views, "workers": workers, "wall_s": span.wall_s, "cpu_s": span.cpu_s,
         "per_cpu_s": n_views / span.cpu_s, "per_s": n_views / span.wall_s, "start_share": start / span.wall_s,
         "cores": span.cores_used, "load": span.load_1min, "steps": steps, "view_cpu_s": view_cpu_s / n_views,
         "serial_cpu_s": span.cpu_s - view_cpu_s, "free_per_s": n_views / free_s}
    total_steps = sum(steps.values())
    print(f"{label:44s} {n_views:4d} views {span.wall_s:7.1f} s wall {span.cpu_s:7.1f} CPU-s  "
          f"{r['per_s']:5.2f} views/s  {r['per_cpu_s']:5.3f} views/CPU-s  {1000 * r['view_cpu_s']:4.0f} ms CPU per view "
          f"in a worker + {r['serial_cpu_s']:4.1f} CPU-s besides  cores used {r['cores']:4.2f}  "
          f"first view after {start:4.1f} s = {100 * r['start_share']:4.1f} % of the run  load {span.load_1min:.1f}  "
          f"[in the workers: decode {100 * steps['decode'] / total_steps:.0f} %, steps "
          f"{100 * steps['process'] / total_steps:.0f} %, encode {100 * steps['encode'] / total_steps:.0f} % of wall]",
          flush=True)
    return r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=150, help="views of the one-worker run of the default path")
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--root", default="/tmp/lfstudio-bench-processing")
    args = ap.parse_args()
    root = Path(args.root)
    source = rendered(root / "rendered", UNIQUE_VIEWS, args.width)
    size = json.loads((source.root / "calibration.json").read_text())["image_size_px"]
    print(f"DNG views of {size[0]} x {size[1]} px ({UNIQUE_VIEWS} distinct renders, hard-linked); profile: debayer, "
          f"shading model, colour, de-flicker, rectify, half resolution, 16-bit PNG; {load_text()}", flush=True)
    work = root / "run"
    old = run(work, source, max(10, args.views // 2), todays_profile(), 1, "former path (AHD, zlib default), 1 worker")
    new1 = run(work, source, args.views, default_profile(), 1, "default path, 1 worker")
    new2 = run(work, source, 2 * args.views, default_profile(), 2, "default path, 2 workers")
    print()
    speed = new1["per_cpu_s"] / old["per_cpu_s"]
    scaling = new2["per_s"] / new1["per_s"]
    print(f"per core: default path / former path, views per CPU-second: {speed:5.2f}x   (target >= 2)")
    print(f"scaling: 2 workers / 1 worker, views per wall second:      {scaling:5.2f}x   (target >= 1.8; the "
          f"2-worker run got {new2['cores']:.2f} cores of {2}, load average {new2['load']:.1f})")
    print(f"scaling on two free cores, from CPU time:                  {new2['free_per_s'] / new1['free_per_s']:5.2f}x   "
          f"(target >= 1.8; CPU per view in a worker {1000 * new1['view_cpu_s']:.0f} ms alone, "
          f"{1000 * new2['view_cpu_s']:.0f} ms beside another worker; all other CPU counted as serial: "
          f"{new1['serial_cpu_s']:.1f} and {new2['serial_cpu_s']:.1f} CPU-s)")
    worst = max(r["start_share"] for r in (old, new1, new2))
    print(f"start-up + first view, worst of the runs:                 {100 * worst:5.1f} %  of its run (target < 5 %)")
    print(load_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
