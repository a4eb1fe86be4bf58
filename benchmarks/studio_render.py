"""Virtual-studio render speed: time per view at the default size (2000 px wide) and the projected
time of a full 101 x 21 scan rendered on 2 processes (the issue's target: minutes on two cores).

    ./.venv/bin/python benchmarks/studio_render.py [--width 2000] [--views 12] [--dataset]

Prints: scene build time, render time per view, render + DNG write per view, the projection for
2121 views on 1 and 2 processes, and (with --dataset) a measured make_virtual_dataset run of
``--views`` views on 2 processes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.sim.sensor import SensorModel  # noqa: E402
from lfstudio.sim.studio import demo_studio  # noqa: E402
from lfstudio.sim.virtual_dataset import make_virtual_dataset, write_view_file  # noqa: E402

VIEWS_FULL = 101 * 21


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=2000)
    ap.add_argument("--views", type=int, default=12, help="views to time")
    ap.add_argument("--dataset", action="store_true", help="also time make_virtual_dataset on 2 processes")
    args = ap.parse_args()

    t = time.perf_counter()
    studio = demo_studio(width_px=args.width)
    build_s = time.perf_counter() - t
    print(f"scene build ({studio.width_px} x {studio.height_px} px, {len(studio.layers)} layers): {build_s:.2f} s")

    studio.render(0.0, 0.0)      # warm-up
    render_s, total_s = [], []
    sensor = SensorModel(noise=0.002, flicker=0.01, vignetting=0.2)
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.views):
            x, y = (i % 101) * 4.0, (i // 101) * 6.0 + 3.0 * (i % 2)
            t0 = time.perf_counter()
            rgb = studio.render(x, y)
            t1 = time.perf_counter()
            recorded, _ = sensor.apply(rgb, i)
            write_view_file(Path(tmp) / f"v{i}.dng", recorded, "dng", 0.5)
            t2 = time.perf_counter()
            render_s.append(t1 - t0)
            total_s.append(t2 - t0)
    r, w = statistics.median(render_s), statistics.median(total_s)
    print(f"render per view: {r * 1000:.0f} ms (median of {args.views})")
    print(f"render + sensor + DNG write per view: {w * 1000:.0f} ms")
    print(f"projected 101 x 21 = {VIEWS_FULL} views: {VIEWS_FULL * w / 60:.1f} min on 1 process, "
          f"{VIEWS_FULL * w / 2 / 60:.1f} min on 2 processes (+ {build_s:.1f} s scene build per process)")

    if args.dataset:
        with tempfile.TemporaryDirectory() as tmp:
            cols = max(2, args.views // 2)
            stamps: list[float] = []
            t = time.perf_counter()
            make_virtual_dataset(Path(tmp) / "ds", cols, 2, width_px=args.width, fmt="dng", workers=2,
                                 rotation_deg=(1.0, -1.5, 0.7), noise=0.002,
                                 progress=lambda done, total, msg: stamps.append(time.perf_counter()))
            elapsed = time.perf_counter() - t
            n = cols * 2
            steady = (stamps[-1] - stamps[1]) / max(1, n - 1)       # after the first view: scene built
            print(f"make_virtual_dataset {cols} x 2 on 2 processes: {elapsed:.1f} s in all; steady state "
                  f"{steady * 1000:.0f} ms per view -> projected {VIEWS_FULL * steady / 60:.1f} min for "
                  f"{VIEWS_FULL} views")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
