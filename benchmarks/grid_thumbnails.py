"""A 101 x 21 = 2121-view dataset without stored thumbnails (as an import or a rendered dataset is)
in the grid: time until every thumbnail tile is in (target < 60 s), then the same after reopening
(the thumbnails made the first time are cached in the dataset's thumbs/generated/).

    ./.venv/bin/python benchmarks/grid_thumbnails.py [--format png|png8|dng|jpg] [--width 2000] [--views 2121]
                                                     [--import-images]

The views are virtual-studio renders at ``--width`` px (6 distinct, hard-linked to 2121 files, cached
in /tmp), laid out as ``lfstudio import-images`` lays them out (raw/r00_c000.png, ..., no thumbs):
16-bit linear PNG (OpenCV's writer: Sub filter), 8-bit PNG, 14-bit DNG or 8-bit JPEG. With
``--import-images`` the same files go through ``import_images`` (which makes the thumbnails while it
reads each file): its wall and CPU time, then the grid of the imported dataset. The grid runs offscreen in this process (the real
GridView and its loader thread). Prints wall and CPU seconds, the cores the run got and the load
average; and the CPU time per view of the thumbnail itself made the former way (8-bit scaling
measured on the full image, then resized) against now, on the same files.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from _measure import Timer, load_text  # noqa: E402
from _qt import spin_until  # noqa: E402

UNIQUE = 6
COLUMNS, ROWS = 101, 21


def sources(folder: Path, fmt: str, width_px: int) -> list[Path]:
    from lfstudio.sim.studio import VirtualStudio
    from lfstudio.sim.virtual_dataset import write_view_file

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    studio = None
    for i in range(UNIQUE):
        path = folder / f"src{i}.{'png' if fmt == 'png8' else fmt}"
        if not path.is_file():
            if studio is None:
                print(f"rendering {UNIQUE} views at {width_px} px (once; cached in {folder}) ...", flush=True)
                studio = VirtualStudio(width_px=width_px, view_region_mm=(0.0, 400.0, 0.0, 120.0))
            rgb = studio.render(i * 4.0, 0.0)
            if fmt == "jpg":
                cv2.imwrite(str(path), cv2.cvtColor((np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8),
                                                    cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])
            elif fmt == "png8":
                path = path.with_suffix(".png")
                cv2.imwrite(str(path), cv2.cvtColor((np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8),
                                                    cv2.COLOR_RGB2BGR))
            else:
                write_view_file(path, rgb, fmt)
        out.append(path)
    return out


def imported_dataset(root: Path, files: list[Path], n_views: int):
    from lfstudio.dataset import Dataset

    shutil.rmtree(root, ignore_errors=True)
    (root / "raw").mkdir(parents=True)
    views = []
    for i in range(n_views):
        r, c = divmod(i, COLUMNS)
        rel = f"raw/r{r:02d}_c{c:03d}{files[0].suffix}"
        os.link(files[i % len(files)], root / rel)
        views.append({"row": r, "column": c, "commanded_mm": [4.0 * c, 6.0 * r], "reported_mm": None,
                      "captured_at": None, "exposure_s": None, "file": rel, "sha256": None, "status": "done"})
    rows = (n_views + COLUMNS - 1) // COLUMNS
    return Dataset.create(root, camera={"name": "imported"}, lens={"name": "unknown"},
                          grid={"columns": COLUMNS, "rows": rows, "spacing_mm": [4.0, 6.0], "order": "raster"},
                          views=views, exist_ok=True)


def former_thumbnail(path: Path, width_px: int = 160) -> np.ndarray | None:
    """The thumbnail as it was made before: 8-bit scaling measured on the full image, then resized."""
    from lfstudio.dataset import images

    if path.suffix.lower() in (".jpg", ".jpeg", ".dng"):
        return images.thumbnail_array(path, width_px)   # not changed for these but the JPEG decode size
    img = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)   # libpng, every pixel
    return images.shrink(images._to_uint8(img), width_px)


def import_with_thumbnails(base: Path, files: list[Path], n_views: int) -> Path:
    """``import_images`` of ``n_views`` files (hard links to ``files``), timed; the dataset root."""
    from lfstudio.export.import_images import ImportOptions, import_images

    folder = base / "to-import"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    for i in range(n_views):
        os.link(files[i % len(files)], folder / f"img{i:05d}{files[0].suffix}")
    out = base / "imported"
    rows = (n_views + COLUMNS - 1) // COLUMNS
    with Timer() as span:
        root = import_images(ImportOptions(folder=folder, out=out, grid=(COLUMNS, rows), spacing_mm=(4.0, 6.0),
                                           overwrite=True))
    print(f"import-images of {n_views} views (hashing, linking, thumbnails): {span.wall_s:6.1f} s wall, "
          f"{span.cpu_s:6.1f} CPU-s ({span.cpu_s / n_views * 1000:.1f} ms CPU per view, cores used "
          f"{span.cores_used:.2f}, load {span.load_1min:.1f})", flush=True)
    return root


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--format", choices=("png", "png8", "dng", "jpg"), default="png")
    ap.add_argument("--width", type=int, default=2000)
    ap.add_argument("--views", type=int, default=COLUMNS * ROWS)
    ap.add_argument("--root", default="/tmp/lfstudio-bench-thumbs")
    ap.add_argument("--import-images", action="store_true",
                    help="import the files with import_images (thumbnails made while importing) and open that")
    args = ap.parse_args()
    if args.import_images and args.views % COLUMNS:
        ap.error(f"--import-images needs a multiple of {COLUMNS} views (whole grid rows)")
    os.environ["LFSTUDIO_CONFIG_DIR"] = tempfile.mkdtemp(prefix="lfstudio-thumbs-bench-config-")
    base = Path(args.root)
    files = sources(base / f"src-{args.format}-{args.width}", args.format, args.width)
    print(f"{args.views} views ({args.format}, {args.width} px wide, "
          f"{'imported with import-images' if args.import_images else 'no stored thumbnails'}); {load_text()}",
          flush=True)
    root = import_with_thumbnails(base, files, args.views) if args.import_images \
        else imported_dataset(base / "dataset", files, args.views).root

    from lfstudio.dataset import images, thumbs

    cv2.setNumThreads(1)
    sample = [root / f"raw/r00_c{c:03d}{files[0].suffix}" for c in range(UNIQUE)]
    per_view = {}
    for name, make in (("former", former_thumbnail), ("now", images.thumbnail_array)):
        make(sample[0], 160)
        with Timer() as span:
            for p in sample * 2:
                make(p, 160)
        per_view[name] = span.cpu_s / (2 * len(sample))
    print(f"one thumbnail, CPU per view: former way {per_view['former'] * 1000:.1f} ms, now "
          f"{per_view['now'] * 1000:.1f} ms ({per_view['former'] / per_view['now']:.1f}x)", flush=True)

    from PySide6.QtWidgets import QApplication

    from lfstudio.dataset import Dataset
    from lfstudio.gui.state import AppState
    from lfstudio.gui.views.grid_view import GridView

    app = QApplication.instance() or QApplication([])

    results = []
    complete = []
    labels = ("opening the imported dataset (thumbnails stored)", "reopened") if args.import_images \
        else ("first opening (thumbnails made from the files)", "reopened (thumbnails from the cache)")
    for label in labels:
        state = AppState()
        view = GridView(state)
        view.resize(1600, 1000)
        view.show()
        app.processEvents()
        canvas = view.canvas
        with Timer() as span:
            state.set_dataset(Dataset.open(root))
            done = spin_until(lambda: canvas._mosaic_has.all(), 1800)
        shot = base / f"grid-{args.format}.png"
        view.grab().save(str(shot))
        results.append(span)
        complete.append(done)
        print(f"{label:50s} {'all' if done else 'NOT all'} {int(canvas._mosaic_has.sum())} tiles in "
              f"{span.wall_s:6.1f} s wall, {span.cpu_s:6.1f} CPU-s (cores used {span.cores_used:.2f}, load "
              f"{span.load_1min:.1f})   target < 60 s: {'OK' if done and span.wall_s < 60 else 'MISSED'}",
              flush=True)
        canvas.loader.stop()
        view.close()
        view.deleteLater()
        app.processEvents()
    if thumbs._filler is not None:
        thumbs._filler.cancel()
    print(f"screenshot: {shot}")
    print(load_text())
    if not all(complete):
        print("FAILED: not every thumbnail tile came in (see the lines above)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
