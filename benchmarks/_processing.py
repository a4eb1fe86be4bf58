"""Virtual-studio DNG datasets for the processing benchmarks (rendered once, cached in /tmp).

``rendered(root, n, width)``: ``n`` distinct views rendered by the virtual studio (noise, flicker,
vignetting, a rotated camera) with its ``calibration.json`` (the true homography) and ground truth.
``linked(root, source, n)``: a dataset of ``n`` views whose RAW files are hard links to the rendered
ones in turn: as much work per view as real views, without rendering hundreds of 4000 px frames.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.profile import Profile  # noqa: E402

VIGNETTING = 0.2


def rendered(root: Path, n_views: int, width_px: int) -> Dataset:
    from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset

    marker = root / "ready.json"
    if marker.is_file() and json.loads(marker.read_text()) == [n_views, width_px]:
        return Dataset.open(root)
    shutil.rmtree(root, ignore_errors=True)
    print(f"rendering {n_views} views at {width_px} px wide (once; cached in {root}) ...", flush=True)
    ds = make_virtual_dataset(root, columns=n_views, rows=1, width_px=width_px, rotation_deg=(1.0, -1.5, 0.7),
                              seed=3, fmt="dng", flicker=0.03, vignetting=VIGNETTING, noise=0.002,
                              workers=min(2, os.cpu_count() or 1))
    truth = load_ground_truth(root)
    (root / "calibration.json").write_text(json.dumps(
        {"homography": truth["H"].tolist(), "image_size_px": truth["image_size_px"]}))
    marker.write_text(json.dumps([n_views, width_px]))
    return ds


def linked(root: Path, source: Dataset, n_views: int) -> Dataset:
    """A fresh ``n_views`` x 1 dataset at ``root`` whose captures are hard links to ``source``'s."""
    shutil.rmtree(root, ignore_errors=True)
    src_views = source.done_views()
    views = []
    (root / "raw").mkdir(parents=True)
    for c in range(n_views):
        src = src_views[c % len(src_views)]
        rel = f"raw/r00_c{c:03d}.dng"
        os.link(source.path_of(src), root / rel)
        views.append({**src, "row": 0, "column": c, "file": rel, "commanded_mm": [4.0 * c, 0.0]})
    grid = {**source.manifest["grid"], "columns": n_views, "rows": 1}
    ds = Dataset.create(root, camera=source.camera, lens=source.lens, grid=grid, views=views, exist_ok=True)
    shutil.copyfile(source.root / "calibration.json", root / "calibration.json")
    return ds


def default_profile() -> Profile:
    """Every default step (debayer, colour, de-flicker, rectify, half resolution) plus the shading
    model of the simulated sensor."""
    profile = Profile()
    profile.shading.enabled = True
    profile.shading.mode = "model"
    profile.shading.coefficients = [-VIGNETTING]
    return profile


def todays_profile() -> Profile:
    """The same steps the way processing did them before demosaicing at the output size: LibRaw's
    AHD at full resolution and zlib's default PNG strategy."""
    profile = default_profile()
    profile.debayer.demosaic = "AHD"
    profile.output.png_strategy = "deflate"
    return profile
