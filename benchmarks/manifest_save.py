"""The manifest at scale: ``Dataset.save`` and ``Dataset.open`` of scanned datasets of 2121 (101 x 21)
and 8241 (201 x 41) views. Target: a save < 50 ms at 8241 views; open time linear in the views.

    python benchmarks/manifest_save.py [--repeat 5]

Per grid: open (wall and CPU), the first save after opening (every view encoded), saves after 2
views changed and after 400 (the instant-device worst case), the former save (``json.dumps(indent=1)``:
Python's pure-Python encoder) for comparison, in this invocation; and the scan's periodic
``Dataset.checkpoint`` (journal-first: the manifest is rewritten only when the journal has grown
past half of it) after 2 views recorded through ``record_view`` and after 2 changed directly. Saves include the atomic write (temporary file, fsync, rename, folder fsync).
Medians of ``--repeat`` runs; CPU is this thread's.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _measure import load_text  # noqa: E402
from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.atomic import atomic_write_text  # noqa: E402

TARGET_MS = 50.0


def scanned(root: Path, columns: int, rows: int) -> Dataset:
    """A dataset whose every view carries what a scan records (file, checksum, timings, ...)."""
    views = [{"row": r, "column": c, "commanded_mm": [c * 4.0, r * 6.0], "reported_mm": [c * 4.0 + 0.001, r * 6.0],
              "captured_at": "2026-11-22T21:00:00.123+00:00", "exposure_s": 0.5,
              "file": f"raw/r{r:02d}_c{c:03d}.arw", "sha256": f"{r * 1000 + c:064x}", "status": "done",
              "thumb": f"thumbs/r{r:02d}_c{c:03d}.jpg", "attempts": 1,
              "timings_s": {"move": 0.8123, "settle": 0.3, "camera_wait": 0.0012, "expose": 0.5012,
                            "transfer": 2.4511, "store": 0.0123, "period": 3.1234}}
             for r in range(rows) for c in range(columns)]
    return Dataset.create(root, camera={"name": "Sony ILCE-7RM2", "sensor_px": [7952, 5304], "pixel_pitch_um": 4.5},
                          lens={"name": "FE 50mm F1.8", "focal_length_mm": 50.0},
                          grid={"columns": columns, "rows": rows, "spacing_mm": [4.0, 6.0], "order": "row-meander"},
                          views=views)


def timed(fn) -> tuple[float, float]:
    t, c = time.perf_counter(), time.thread_time()
    fn()
    return (time.perf_counter() - t) * 1000, (time.thread_time() - c) * 1000


def median(pairs: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(p[0] for p in pairs), statistics.median(p[1] for p in pairs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--grids", default="101x21,201x41", help="comma-separated COLUMNSxROWS, smallest first")
    args = ap.parse_args()
    grids = [tuple(int(v) for v in g.lower().split("x")) for g in args.grids.split(",")]
    largest = max(c * r for c, r in grids)
    print(load_text(), flush=True)
    opened = {}
    with tempfile.TemporaryDirectory() as tmp:
        for columns, rows in grids:
            n = columns * rows
            root = scanned(Path(tmp) / f"ds{n}", columns, rows).root
            runs = [timed(lambda: Dataset.open(root)) for _ in range(args.repeat)]
            opened[n] = median(runs)
            rows_out = [("open", opened[n])]
            first, two, many, former, scan, direct = [], [], [], [], [], []
            for i in range(args.repeat):
                ds = Dataset.open(root)
                first.append(timed(ds.save))
                for k, out in ((2, two), (400, many)):
                    for j in range(k):
                        v = ds.views[(i * 997 + j * 13) % n]
                        v["timings_s"] = {**v["timings_s"], "store": 0.001 * (i + j)}
                        v["attempts"] = i + 2
                    out.append(timed(ds.save))
                former.append(timed(lambda: atomic_write_text(
                    ds.manifest_path, json.dumps(ds.manifest, indent=1, allow_nan=False) + "\n")))
                ds.save()
                for j in range(2):   # a scan between two checkpoints: views journaled by record_view
                    v = ds.views[(i * 991 + j * 17) % n]
                    ds.record_view(v["row"], v["column"], attempts=i + 3, timings_s={**v["timings_s"], "store": 0.002})
                scan.append(timed(ds.checkpoint))
                for j in range(2):   # views changed directly (not through record_view): journaled whole
                    ds.views[(i * 983 + j * 19) % n]["attempts"] = i + 4
                direct.append(timed(ds.checkpoint))
                ds.save()
                ds.close()
            rows_out += [("save, first after open", median(first)), ("save, 2 views changed", median(two)),
                         ("save, 400 views changed", median(many)), ("former save (indent=1)", median(former)),
                         ("checkpoint, 2 views recorded", median(scan)),
                         ("checkpoint, 2 views changed", median(direct))]
            size_mb = (root / "dataset.json").stat().st_size / 1e6
            print(f"{columns} x {rows} = {n} views ({size_mb:.1f} MB manifest):")
            for label, (wall, cpu) in rows_out:
                mark = ""
                if label.startswith(("save", "checkpoint")) and n == largest:
                    mark = f"   (target < {TARGET_MS:g} ms: {'OK' if wall < TARGET_MS else 'MISSED'})"
                print(f"  {label:26s} {wall:7.1f} ms wall {cpu:7.1f} ms CPU{mark}", flush=True)
    n1, n2 = min(opened), max(opened)
    (w1, c1), (w2, c2) = opened[n1], opened[n2]
    print(f"open per view, {n2} / {n1} views: CPU {(c2 / n2) / (c1 / n1):.2f}x, wall {(w2 / n2) / (w1 / n1):.2f}x "
          "(1.0 = linear)")
    print(load_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
