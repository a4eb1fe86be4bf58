"""Epipolar-plane images (EPIs) and rectified previews for inspecting a calibration by eye.

A *horizontal EPI* stacks the same image row ``y`` of consecutive views of one grid row: every
scene point draws a line whose slope is its disparity. After a correct rectification the point
stays on that image row in every view, so the lines are straight and unbroken; with an orientation
error they drift off the row and break up. A *vertical EPI* does the same with one image column
across the views of one grid column.

Images are previews (grey, ``width_px`` wide); the full-resolution homography is scaled to them
(:func:`lfstudio.calibration.model.scale_homography`). Only the needed row/column is resampled.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from lfstudio.calibration.model import homography_for, scale_homography
from lfstudio.dataset import images
from lfstudio.dataset.paths import view_stem
from lfstudio.jobs import CancelToken, Progress, no_progress


def load_preview(path: str | Path, width_px: int = 1000) -> tuple[np.ndarray, tuple[int, int]]:
    """Grey uint8 preview ``width_px`` wide (at most) and the full-resolution size."""
    grey, full, _ = images.read_grey(path, width_px)
    return grey, full


def preview_homography(H_full: np.ndarray | None, full_size_px: Sequence[int], preview: np.ndarray) -> np.ndarray:
    if H_full is None:
        return np.eye(3)
    return scale_homography(H_full, full_size_px, (preview.shape[1], preview.shape[0]))


def _sample(img: np.ndarray, H: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Values of the rectified image (rectified = H · captured) at rectified points (u, v)."""
    Hinv = np.linalg.inv(H)
    p = np.stack([u, v, np.ones_like(u)]) .reshape(3, -1)
    q = Hinv @ p
    mx = (q[0] / q[2]).astype(np.float32).reshape(1, -1)
    my = (q[1] / q[2]).astype(np.float32).reshape(1, -1)
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)[0]


def rectified_row(img: np.ndarray, H: np.ndarray, y: float) -> np.ndarray:
    u = np.arange(img.shape[1], dtype=float)
    return _sample(img, H, u, np.full_like(u, float(y)))


def rectified_column(img: np.ndarray, H: np.ndarray, x: float) -> np.ndarray:
    v = np.arange(img.shape[0], dtype=float)
    return _sample(img, H, np.full_like(v, float(x)), v)


def rectify_image(img: np.ndarray, H: np.ndarray) -> np.ndarray:
    """The whole preview warped with ``H`` (same size)."""
    return cv2.warpPerspective(img, H, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT)


def horizontal_epi(images: Sequence[np.ndarray], Hs: Sequence[np.ndarray], y: float) -> np.ndarray:
    """Row ``y`` of each (rectified) view stacked top to bottom: n_views × width."""
    return np.stack([rectified_row(img, H, y) for img, H in zip(images, Hs)])


def vertical_epi(images: Sequence[np.ndarray], Hs: Sequence[np.ndarray], x: float) -> np.ndarray:
    """Column ``x`` of each (rectified) view side by side: height × n_views."""
    return np.stack([rectified_column(img, H, x) for img, H in zip(images, Hs)], axis=1)


def consecutive(indices: Sequence[int], centre: int, count: int) -> list[int]:
    """Up to ``count`` consecutive available indices around ``centre``."""
    idx = sorted(indices)
    if not idx:
        return []
    k = min(range(len(idx)), key=lambda i: abs(idx[i] - centre))
    lo = max(0, min(k - count // 2, len(idx) - count))
    return idx[lo:lo + count]


def dataset_epis(dataset, calibration: dict | None, *, row: int, column: int, y_frac: float = 0.5,
                 x_frac: float = 0.5, count: int = 24, width_px: int = 800, progress: Progress = no_progress,
                 cancel: CancelToken | None = None) -> dict:
    """Horizontal EPI through grid ``row`` and vertical EPI through grid ``column``, before and after.

    Uses up to ``count`` consecutive captured views around the middle of that row/column; the EPI
    passes through image row ``y_frac`` (0 top … 1 bottom) and image column ``x_frac``.
    Returns ``{"horizontal": {"before", "after", "views"}, "vertical": {...}, "y_px", "x_px"}``.
    """
    done_views = {(int(v["row"]), int(v["column"])): v for v in dataset.done_views()}
    grid = dataset.grid
    cols = consecutive([c for (r, c) in done_views if r == row], grid.columns // 2, count)
    rows = consecutive([r for (r, c) in done_views if c == column], grid.rows // 2, count)
    H_full = None if calibration is None else homography_for(calibration)
    total = len(cols) + len(rows)
    out: dict = {}
    cache: dict[tuple[int, int], tuple[np.ndarray, tuple[int, int]]] = {}
    n = 0

    def get(v):
        nonlocal n
        if v not in cache:
            if cancel is not None:
                cancel.check()
            cache[v] = load_preview(dataset.path_of(done_views[v]), width_px)
            n += 1
            progress(n, total, f"reading {view_stem(*v)}")
        return cache[v]

    for key, views in (("horizontal", [(row, c) for c in cols]), ("vertical", [(r, column) for r in rows])):
        if len(views) < 2:
            out[key] = None
            continue
        imgs = [get(v) for v in views]
        previews = [i for i, _ in imgs]
        full = imgs[0][1]
        ident = [np.eye(3)] * len(previews)
        rect = [preview_homography(H_full, full, p) for p in previews]
        h, w = previews[0].shape
        y, x = y_frac * (h - 1), x_frac * (w - 1)
        if key == "horizontal":
            out[key] = {"before": horizontal_epi(previews, ident, y), "views": views, "y_px": y,
                        "after": horizontal_epi(previews, rect, y) if H_full is not None else None}
        else:
            out[key] = {"before": vertical_epi(previews, ident, x), "views": views, "x_px": x,
                        "after": vertical_epi(previews, rect, x) if H_full is not None else None}
    return out
