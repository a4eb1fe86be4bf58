"""16-bit PNG export: one ``rRR_cCCC.png`` per view plus ``manifest.json`` (grid, spacing,
positions, calibration, intrinsics), written into a temporary sibling folder and renamed at the end."""

from __future__ import annotations

import contextlib
import json
import shutil
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import DatasetError
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress

MANIFEST_NAME = "manifest.json"


def write_views(ds: Dataset, views: Sequence[common.View], source: str, folder: Path, size: tuple[int, int],
                progress: Progress, cancel: CancelToken, *, total: int | None = None,
                label: str = "png") -> dict[common.View, str]:
    """Write every view as ``folder/rRR_cCCC.png`` (16-bit RGB); processed 16-bit PNGs are copied
    byte for byte, everything else decoded and written. Returns view → file name."""
    debayer = common.debayer_step(ds) if source == "raw" else None
    names: dict[common.View, str] = {}
    total = total or len(views)

    def write(v: common.View) -> tuple[common.View, str]:
        src = common.source_path(ds, v, source)
        name = f"{view_stem(*v)}.png"
        dst = folder / name
        if source == "processed" and common.is_png16_rgb(src):
            hdr = common.png_header(src)
            if (hdr[0], hdr[1]) != tuple(size):
                raise DatasetError(f"{src}: {hdr[0]} x {hdr[1]} px, the other views are {size[0]} x {size[1]} px; "
                                   "process the dataset again so that every view has the same size")
            shutil.copyfile(src, dst)
        else:
            rgb = common.read_view(src, debayer)
            if (rgb.shape[1], rgb.shape[0]) != tuple(size):
                raise DatasetError(f"{src}: {rgb.shape[1]} x {rgb.shape[0]} px, the other views are "
                                   f"{size[0]} x {size[1]} px; export views of one camera setting")
            common.write_png16(dst, rgb)
        return v, name

    with contextlib.closing(common.ordered_map(write, views, cancel)) as results:   # threads end before cleanup
        for i, (v, name) in enumerate(results):
            names[v] = name
            progress(i + 1, total, f"{label} {name}")
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
            total += p.stat().st_size if common.is_png16_rgb(p) else int(size[0] * size[1] * 6 * PNG_RATIO)
        return total + 4096
    return int(len(views) * size[0] * size[1] * 6 * PNG_RATIO) + 4096


#: 16-bit linear PNG of a natural scene / uncompressed size (the low bits are noise; measured on
#: virtual-studio views with a little sensor noise: 0.82; noiseless: 0.6)
PNG_RATIO = 0.8


def read_png16(path: Path) -> np.ndarray:
    from lfstudio.processing.steps.debayer import read_image

    return read_image(path)
