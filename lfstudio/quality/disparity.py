"""The disparity map of the centre view (the paper's Figure 5) from the rectified neighbouring views.

The centre view is matched with OpenCV's semi-global matcher (``cv2.StereoSGBM``, 3-way mode) against
one partner on each side along its row and column (left, right, up, down), each a few steps away so
that the largest disparity stays near :data:`TARGET_DISPARITY_PX` working pixels (wider baselines:
finer depth steps); views sheared by an amount nobody stated are searched over their signed range
(negative behind the zero plane). Every pair is turned into the matcher's left/right layout (mirrored or
transposed), its disparity is scaled to **one horizontal grid step at full resolution** (the unit
of ``disp_min``/``disp_max`` in the exports) and the estimates are combined per pixel by their
median, which keeps a pixel that one partner sees occluded. Pixels no pair matched are NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


Cell = tuple[int, int]     # a grid cell (row, column); a dataset View is one
TARGET_DISPARITY_PX = 32.0
MAX_STEPS = 4


@dataclass
class DisparityMap:
    cell: Cell
    disparity_px: np.ndarray            # (h, w) float32, full-resolution px per horizontal step, NaN: unknown
    image8: np.ndarray                  # (h, w) uint8 rectified centre view (working size)
    partners: list[dict] = field(default_factory=list)   # cell, baseline_mm, direction

    def valid_fraction(self) -> float:
        return float(np.isfinite(self.disparity_px).mean())


def partner_cells(centre: Cell, available: set[Cell], columns: int, rows: int, steps_h: int, steps_v: int
                  ) -> list[tuple[Cell, str, int]]:
    """(cell, direction, steps) of the farthest available partner within ``steps`` on each side."""
    r, c = centre
    out = []
    for direction, dr, dc, n in (("right", 0, 1, steps_h), ("left", 0, -1, steps_h),
                                 ("down", 1, 0, steps_v), ("up", -1, 0, steps_v)):
        for k in range(max(1, n), 0, -1):
            cell = (r + dr * k, c + dc * k)
            if 0 <= cell[0] < rows and 0 <= cell[1] < columns and cell in available:
                out.append((cell, direction, k))
                break
    return out


def steps_for(max_step_disparity_work_px: float, limit: int = MAX_STEPS) -> int:
    """How many grid steps apart a partner may be so its disparity stays near the target."""
    if not max_step_disparity_work_px > 0:
        return 1
    return int(max(1, min(limit, np.floor(TARGET_DISPARITY_PX / max_step_disparity_work_px))))


def _to_left_right(img: np.ndarray, direction: str) -> np.ndarray:
    if direction == "right":
        return img
    if direction == "left":
        return img[:, ::-1]
    if direction == "down":
        return img.T
    return img.T[:, ::-1]            # up


def _from_left_right(disp: np.ndarray, direction: str) -> np.ndarray:
    if direction == "right":
        return disp
    if direction == "left":
        return disp[:, ::-1]
    if direction == "down":
        return disp.T
    return disp[:, ::-1].T


def search_range(min_disparity_px: float, max_disparity_px: float) -> tuple[int, int]:
    """(minDisparity, numDisparities) of the matcher for disparities in [min, max] working px, with a
    margin (25 % and 4 px) on each side; ``min`` is 0 for parallel views and negative where the views
    are sheared by an amount nobody stated (their disparities run negative behind the zero plane)."""
    lo, hi = min(float(min_disparity_px), 0.0), max(float(max_disparity_px), 0.0)
    first = 0 if lo >= 0 else -int(np.ceil(-lo * 1.25 + 4))
    n = int(np.ceil(max(16.0, hi * 1.25 + 4 - first) / 16.0) * 16)
    return first, n


def sgbm(left: np.ndarray, right: np.ndarray, max_disparity_px: float, min_disparity_px: float = 0.0) -> np.ndarray:
    """Disparity (float32, NaN where unknown) of ``left`` against ``right`` (uint8, rectified),
    searched over [``min_disparity_px``, ``max_disparity_px``] (signed; see :func:`search_range`)."""
    first, n = search_range(min_disparity_px, max_disparity_px)
    block = 5
    if left.shape[1] < n + 2 or left.shape[0] < block:   # narrower than the search: OpenCV asked for exabytes
        return np.full(left.shape[:2], np.nan, np.float32)
    matcher = cv2.StereoSGBM.create(minDisparity=first, numDisparities=n, blockSize=block, P1=8 * block * block,
                                    P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=10,
                                    speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(np.ascontiguousarray(left), np.ascontiguousarray(right)).astype(np.float32) / 16.0
    raw[raw < first] = np.nan           # OpenCV marks unmatched pixels with minDisparity - 1
    raw[:, :max(0, first + n)] = np.nan  # no partner pixels that far left
    if first < 0:
        raw[:, raw.shape[1] + first:] = np.nan   # nor that far right (negative disparities)
    return raw


def disparity_map(centre: Cell, images: dict[Cell, np.ndarray], partners: list[tuple[Cell, str, int]],
                  baselines_mm: dict[Cell, float], spacing_x_mm: float, work_scale: float,
                  max_step_disparity_work_px: dict[str, float], homography: np.ndarray | None,
                  shifts_px: dict[Cell, tuple[float, float]] | None = None,
                  min_step_disparity_work_px: dict[str, float] | None = None) -> DisparityMap:
    """Combine the partners' disparities into one map of ``centre`` (see the module docstring).

    ``images``: rectification-free working images (uint8) by cell; ``baselines_mm``: each partner's
    distance from the centre; ``max_step_disparity_work_px``: the largest disparity of one step
    ("h"/"v"), from the tracks, which sizes the search, and ``min_step_disparity_work_px`` the smallest
    (signed: negative for views sheared by an amount nobody stated; default 0, parallel); ``shifts_px``: working px to move each partner
    by first (sheared views: minus the shear of its offset, so the map is a parallel capture's).
    """
    def rectified(img: np.ndarray) -> np.ndarray:
        if homography is None:
            return img
        h, w = img.shape
        return cv2.warpPerspective(img, homography, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    c_img = rectified(images[centre])
    estimates = []
    used = []
    for cell, direction, steps in partners:
        axis = "h" if direction in ("left", "right") else "v"
        p_img = rectified(images[cell])
        if shifts_px and cell in shifts_px:     # sheared views: the partner moved back by its shear
            dx, dy = shifts_px[cell]
            h, w = p_img.shape
            p_img = cv2.warpAffine(p_img, np.array([[1, 0, dx], [0, 1, dy]], np.float32), (w, h), flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
        d = sgbm(_to_left_right(c_img, direction), _to_left_right(p_img, direction),
                 steps * max_step_disparity_work_px.get(axis, 8.0),
                 steps * (min_step_disparity_work_px or {}).get(axis, 0.0))
        d = _from_left_right(d, direction)
        baseline = float(baselines_mm[cell])
        if baseline <= 0:
            continue
        estimates.append(d * np.float32(work_scale * spacing_x_mm / baseline))
        used.append({"view": list(cell), "direction": direction, "steps": steps, "baseline_mm": baseline})
    out = nan_median(np.stack(estimates)) if estimates else np.full(c_img.shape, np.nan, np.float32)
    return DisparityMap(centre, out, c_img, used)


def nan_median(stack: np.ndarray) -> np.ndarray:
    """Per-pixel median over axis 0 ignoring NaN (NaN where every estimate is NaN); for the few
    estimates here much faster than ``np.nanmedian``."""
    s = np.sort(stack, axis=0)                        # NaN sorts last
    n = np.isfinite(stack).sum(axis=0)
    lo = np.clip((n - 1) // 2, 0, len(stack) - 1)
    hi = np.clip(n // 2, 0, len(stack) - 1)
    a = np.take_along_axis(s, lo[None], axis=0)[0]
    b = np.take_along_axis(s, hi[None], axis=0)[0]
    out = (a + b) * np.float32(0.5)
    out[n == 0] = np.nan
    return out.astype(np.float32)
