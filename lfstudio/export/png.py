"""16-bit PNG export: one ``rRR_cCCC.png`` per view plus ``manifest.json`` (grid, spacing,
positions, calibration, intrinsics), written into a temporary sibling folder and renamed at the end."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress

MANIFEST_NAME = "manifest.json"


def write_views(ds: Dataset, views: Sequence[common.View], source: str, folder: Path, size: tuple[int, int],
                progress: Progress, cancel: CancelToken) -> dict[common.View, str]:
    """Write every view as ``folder/rRR_cCCC.png`` (16-bit RGB; processed 16-bit PNGs copied byte
    for byte). Returns view → file name."""
    names = {v: f"{view_stem(*v)}.png" for v in views}
    common.write_images(ds, views, source, size, folder, names, 16, progress, cancel, label="png ")
    return names


def export_png(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
               overwrite: bool, progress: Progress, cancel: CancelToken) -> list[Path]:
    with common.partial_folder(out, overwrite) as tmp:
        names = write_views(ds, views, source, tmp, size, progress, cancel)
        doc: dict[str, Any] = common.describe(ds, views, source, size, names)
        doc["kind"] = "png"
        doc["bit_depth"] = 16
        (tmp / MANIFEST_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return [out / MANIFEST_NAME] + [out / names[v] for v in views]


def estimate_png_bytes(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int]) -> int:
    """Processed 16-bit PNGs are copied (their sizes are known); otherwise a typical ratio."""
    if source == "processed":
        total = 0
        for v in views:
            p = common.source_path(ds, v, source)
            total += p.stat().st_size if common.is_png16_rgb(p) else common.images_bytes_estimate(1, size, 16)
        return total + 4096
    return common.images_bytes_estimate(len(views), size, 16) + 4096
